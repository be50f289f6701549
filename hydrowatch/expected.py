"""What a model expected a window's sensors to read, beside what they read, thinned to what a chart needs.

A health method that predicts the sensors (the parity method's component relations, the study's reference
models) gives, per judged window, each sensor's measured and expected signal; :func:`expected_windows`
averages both over consecutive blocks of :data:`POINT_SAMPLES` samples (0.1 s at 200 Hz: 50 points per 5 s
window), which a chart draws as two lines, and which keeps the bus message small (``expected_window``,
schemas/README.md). Block means, not every n-th sample: the mean over a block is what both lines mean at that
point, and the sensor noise drops by √20 on both alike.

A neutral module (beside :mod:`hydrowatch.verdict`): methods make these, the scorer's messages and the web page
read them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from hydrowatch.errors import ParameterError

POINT_SAMPLES = 20
"""Samples averaged into one point of a chart (0.1 s at 200 Hz)."""


@dataclass(frozen=True)
class ExpectedSensor:
    """One sensor of one window: measured and expected, one value per point.

    Attributes
    ----------
    measured, expected : ndarray, shape (n_points,)
        Means over consecutive blocks of ``step`` samples from the window's first sample, in the sensor's unit
        (flow L/min, speed rad/s, torque N·m); point i covers [start + i·step, start + (i + 1)·step).
    source : str
        What expected it: ``"valve relation"``, ``"load relation"``, ``"motor relation"`` (parity method, the
        unit's nominal parameters), ``"bj reference model"`` or ``"narx reference model"`` (one-step predictions).
    step : int
        Samples per point.
    """

    measured: np.ndarray
    expected: np.ndarray
    source: str
    step: int = POINT_SAMPLES


ExpectedWindow = dict[str, ExpectedSensor]
"""The sensors a model expected of one window, by name."""


def block_means(x: np.ndarray, step: int = POINT_SAMPLES) -> np.ndarray:
    """Means of x (m, n) over consecutive blocks of ``step`` samples, shape (m, n // step) (a last partial block is
    left out)."""
    if int(step) != step or step < 1:
        raise ParameterError(f"step must be an integer >= 1 sample. Got {step!r}; {POINT_SAMPLES} is the default.")
    m, n = x.shape
    k = n // step
    return x[:, : k * step].reshape(m, k, step).mean(axis=2)


def expected_windows(measured: Mapping[str, np.ndarray], expected: Mapping[str, np.ndarray],
                     sources: Mapping[str, str], step: int = POINT_SAMPLES) -> list[ExpectedWindow]:
    """Per window, each sensor's measured and expected block means (:class:`ExpectedSensor`).

    Parameters
    ----------
    measured, expected : mapping of sensor to ndarray, shape (m, n)
        The m windows' signals per sensor, in the sensor's unit; ``expected`` may hold fewer sensors (those the
        model could predict).
    sources : mapping of sensor to str
        What expected each sensor of ``expected``.

    Returns
    -------
    list of dict, length m
        A window's sensors whose points are all finite (a window with NaN in a sensor leaves that sensor out).
    """
    points = {s: (block_means(measured[s], step), block_means(e, step)) for s, e in expected.items()}
    out: list[ExpectedWindow] = []
    m = next(iter(measured.values())).shape[0] if measured else 0
    for i in range(m):
        window: ExpectedWindow = {}
        for s, (a, b) in points.items():
            if np.all(np.isfinite(a[i])) and np.all(np.isfinite(b[i])):
                window[s] = ExpectedSensor(a[i].copy(), b[i].copy(), sources[s], int(step))
        out.append(window)
    return out
