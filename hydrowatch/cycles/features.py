"""Per-cycle statistics of every channel: the plain baseline's features (no plant physics).

For each channel of a cycle on the window grid: mean, standard deviation, minimum, maximum,
the mean of each of ``phases`` equal parts of the cycle, and the least-squares slope over the
cycle. Inputs and outputs are numpy arrays; names say which channel and statistic a column is.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hydrowatch.errors import ParameterError


def cycle_statistics(values: np.ndarray, grid_hz: float, phases: int = 6) -> np.ndarray:
    """Statistics of each channel of each cycle.

    Parameters
    ----------
    values : ndarray, shape (n_cycles, n_channels, n_samples)
        Channel values on a grid of ``grid_hz``.
    grid_hz : float
        Sample rate of the last axis, Hz (the slope is per second).
    phases : int, default 6
        Equal parts of the cycle whose means are features (``n_samples`` must be divisible).

    Returns
    -------
    ndarray, shape (n_cycles, n_channels * (5 + phases))
        Per channel, in order: mean, std, min, max, slope [unit/s], phase means 1..``phases``.
    """
    if values.ndim != 3:
        raise ParameterError(f"values must have shape (cycles, channels, samples). Got shape {values.shape}.")
    n_cycles, n_channels, n = values.shape
    if phases < 1 or n % phases or n < 2:
        raise ParameterError(
            f"phases must divide the {n} samples of a cycle (and a cycle must hold >= 2). Got phases={phases}."
        )
    t = np.arange(n) / grid_hz
    centred = t - t.mean()
    slope = values @ centred / (centred @ centred)
    parts = values.reshape(n_cycles, n_channels, phases, n // phases).mean(axis=3)
    stats = np.stack([values.mean(axis=2), values.std(axis=2), values.min(axis=2), values.max(axis=2), slope], axis=2)
    return np.concatenate([stats, parts], axis=2).reshape(n_cycles, -1)


def statistic_names(channels: Sequence[str], phases: int = 6) -> list[str]:
    """Column names of :func:`cycle_statistics`, e.g. ``"PS1.mean"``, ``"PS1.phase3"``."""
    kinds = ["mean", "std", "min", "max", "slope", *(f"phase{k + 1}" for k in range(phases))]
    return [f"{c}.{k}" for c in channels for k in kinds]
