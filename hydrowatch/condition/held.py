"""Sensor noise measured from the signals: where the command is held (the plant at rest, a signal's second difference
is its noise alone; the unit's identification weights the valve relation by it, :mod:`hydrowatch.condition.unit`), and
per window where its own differences show white noise (:func:`window_noise`; the health relation's errors-in-variables
share, :func:`hydrowatch.condition.parity.valve_mse`)."""

from __future__ import annotations

from math import comb
from typing import cast

import numpy as np

HOLD_SETTLE = 50
"""Samples (0.25 s) a command must have been held before a sample counts as held (:func:`held_noise`): the shaft's
hydraulic resonance (~28 Hz) has rung out by then."""
MIN_HELD = 2000
"""Held samples (10 s) needed to measure the sensor noise; fewer, and the valve relation is not weighted for
errors in variables (:func:`_valve_relation`)."""


def held_mask(voltage: np.ndarray) -> np.ndarray:
    """Where a signal's second difference (m, n − 2) lies in a held stretch: the command has not moved for
    :data:`HOLD_SETTLE` samples."""
    moved = np.concatenate([np.ones((voltage.shape[0], 1), dtype=bool), np.diff(voltage, axis=-1) != 0.0], axis=-1)
    count = np.cumsum(moved, axis=-1)
    since = count - np.concatenate([np.zeros((voltage.shape[0], HOLD_SETTLE), dtype=count.dtype),
                                    count[:, :-HOLD_SETTLE]], axis=-1)
    held = np.zeros((voltage.shape[0], voltage.shape[1] - 2), dtype=bool)
    held[:, HOLD_SETTLE - 2:] = since[:, HOLD_SETTLE:] == 0
    return held


def _difference_sigma(d: np.ndarray, order: int, axis: int | None = None) -> np.ndarray:
    """White-noise σ from ``order``-th differences ``d``: 1.4826·MAD / √C(2·order, order) (a white sequence's
    ``order``-th differences have variance C(2·order, order)·σ²), over ``axis`` (None: all of ``d``)."""
    mad = np.median(np.abs(d - np.median(d, axis=axis, keepdims=axis is not None)), axis=axis)
    return cast(np.ndarray, 1.4826 * mad / np.sqrt(comb(2 * order, order)))


def noise_where(x: np.ndarray, held: np.ndarray) -> float | None:
    """1.4826·MAD / √6 of the second differences of ``x`` where ``held`` (:func:`held_mask`); None if too few."""
    d = np.diff(x, n=2, axis=-1)[held]
    if d.size < MIN_HELD:
        return None
    return float(_difference_sigma(d, 2))


def held_noise(x: np.ndarray, voltage: np.ndarray) -> float | None:
    """White-noise standard deviation of signals (m, n) measured where the command ``voltage`` (m, n) is held.

    Where the command has not moved for :data:`HOLD_SETTLE` samples the plant is at rest and the signal's second
    difference is its noise alone: σ = 1.4826·MAD / √6 (a white sequence's second difference has variance 6σ²).
    Elsewhere the plant's own fast content (spool, line, resonance) would count as noise: on filtered noise 0–4 V
    the second differences of P̂L read 6.5× its true noise. None with fewer than :data:`MIN_HELD` held samples.
    """
    return noise_where(x, held_mask(voltage))


NOISE_AGREEMENT = 1.2
"""A window measures its own white noise only where the estimates from second and sixth differences agree within this
factor (:func:`window_noise`)."""


def window_noise(x: np.ndarray) -> np.ndarray:
    """White-noise standard deviation of each window of ``x`` (m, n), from its own samples; 0 where it cannot tell.

    A white sequence's k-th differences have variance C(2k, k)·σ², so σ read from the second and from the sixth
    differences agree; the plant's own fast content (the shaft's ~28 Hz resonance, a filtered-noise command through the
    spool) inflates the lower order far more. Where the two agree within :data:`NOISE_AGREEMENT` the second-difference
    value is returned, else 0 (not measured). Measured on P̂L (units of seed 2033, 20 windows of 5 s each): duty cycles
    0.5–3.5 V agree in every window and read 0.90–1.11 × the true noise; filtered noise 0–4 V (8–11 ×) and slow noise
    (3–4 ×) agree in none.
    """
    low, high = (_difference_sigma(np.diff(x, n=k, axis=-1), k, axis=-1) for k in (2, 6))
    return cast(np.ndarray, np.where(low <= NOISE_AGREEMENT * high, low, 0.0))
