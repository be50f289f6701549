"""The load relation (plant-model.md Eq. 7) run forwards: the torque a gearbox speed asks of the brake and load, and
the speed a measured torque drives them to. What fills a missing speed or torque sensor
(:func:`~hydrowatch.condition.estimates.window_signals`) and what the model expects a sensor to read
(:mod:`hydrowatch.condition.predictions`); the relations themselves, which regress on these signals, are
:mod:`hydrowatch.condition.parity`'s.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hydrowatch.condition.parity import derivative
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SAMPLE_RATE_HZ


def load_torque(speed: np.ndarray, p: PlantParameters, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """Torque the load relation asks of a gearbox speed, N·m: JL·ω̇ + BL·ω + TL·tanh(ω/ωs) (Eq. 7)."""
    return p.JL * derivative(speed, sample_rate) + p.BL * speed + p.TL * np.tanh(speed / p.omega_s)


def speed_from_torque(torque: np.ndarray, p: PlantParameters, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """Gearbox speed that the load relation (Eq. 7) turns a measured torque into, rad/s, shape like ``torque``.

    JL·ω̇ = T − BL·ω − TL·tanh(ω/ωs) integrated through each window (the torque averaged over each
    sample interval, semi-implicit in the damping: stable, the load's time constant JL/BL = 0.25 s
    ≫ one sample), from the speed at which the first sample's torque is in balance. The
    integration low-passes the torque noise.
    """
    t = np.atleast_2d(np.asarray(torque, dtype=np.float64))
    out = np.empty(t.shape)
    _integrate_load(np.ascontiguousarray(t), p.JL, p.BL, p.TL, p.omega_s, 1.0 / sample_rate, out)
    return out.reshape(np.shape(torque))


@njit(cache=True)
def _integrate_load(torque: np.ndarray, jl: float, bl: float, tl: float, ws: float, dt: float,
                    out: np.ndarray) -> None:
    m, n = torque.shape
    for i in range(m):
        lo, hi = -1e4, 1e4  # balance T = BL·ω + TL·tanh(ω/ωs) rises with ω: bisection
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if bl * mid + tl * np.tanh(mid / ws) < torque[i, 0]:
                lo = mid
            else:
                hi = mid
        w = 0.5 * (lo + hi)
        out[i, 0] = w
        for k in range(1, n):
            w = (w + dt / jl * (0.5 * (torque[i, k - 1] + torque[i, k]) - tl * np.tanh(w / ws))) / (1.0 + dt * bl / jl)
            out[i, k] = w
