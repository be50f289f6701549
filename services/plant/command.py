"""Streaming valve commands for a fleet: the study's filtered white noise (Eq. 3.21), chunk by chunk.

The same filter as :func:`hydrowatch.plant.excitation.filtered_noise`, y(t) = pole·y(t−1) +
(1 − pole)·w(t), scaled onto the voltage range and clipped, but with the filter state kept per
machine between chunks so an endless command has no seams.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from hydrowatch.plant.excitation import NOISE_POLE, NOISE_SIGMAS, check_volts


class FilteredNoiseCommand:
    """Endless filtered-noise commands for M machines.

    Parameters
    ----------
    n_machines : int
        M.
    volts : (float, float)
        Voltage range (lo, hi), V.
    seed : int or None
        Seed of the white noise (one generator for the whole fleet).
    """

    def __init__(self, n_machines: int, volts: tuple[float, float] = (0.0, 4.0), *, seed: int | None = None) -> None:
        self.n_machines = n_machines
        self.volts = check_volts(volts)
        self.seed = seed
        self._rng = np.random.default_rng(seed)
        self._sigma_y = (1.0 - NOISE_POLE) / math.sqrt(1.0 - NOISE_POLE**2)
        # filter state as if y(−1) were drawn from the stationary distribution (no transient)
        self._zi = NOISE_POLE * self._rng.standard_normal((n_machines, 1)) * self._sigma_y

    def next(self, n: int) -> np.ndarray:
        """The next ``n`` samples of every machine's command, shape (M, n), V."""
        w = self._rng.standard_normal((self.n_machines, n))
        y, self._zi = lfilter([1.0 - NOISE_POLE], [1.0, -NOISE_POLE], w, axis=1, zi=self._zi)
        lo, hi = self.volts
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        return np.clip(mid + half * y / (NOISE_SIGMAS * self._sigma_y), lo, hi)
