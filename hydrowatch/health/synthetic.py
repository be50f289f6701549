"""Synthetic prediction errors with realistic traits, for tests, benchmarks and demos without a plant.

Each health state has, per sensor, its own mean, standard deviation and skew of the prediction
error (Eq. 5.1), and the errors are AR(1)-correlated like a real reference model's residual. The
profiles follow the qualitative picture of section 6.1: a heavier load raises torque errors and
lowers flow errors, leaks lower torque, motor leakage lowers speed; alert moves further than
warning. ``valve_leak`` is an extra fault for open-set tests (not one of the study's 7 states).
These are not simulations of the plant: use :mod:`hydrowatch.plant` for that.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from hydrowatch.errors import ParameterError

STUDY_STATES: tuple[str, ...] = (
    "healthy", "load_warning", "load_alert", "pump_leak_warning", "pump_leak_alert",
    "motor_leak_warning", "motor_leak_alert",
)
"""The seven health states of the study (Table 6.4 order)."""

SENSOR_SCALE = np.array([0.05, 0.02, 0.5])
"""Typical healthy error standard deviation per sensor: flow L/min, speed rad/s, torque N·m."""

# (mean, std, skew) per sensor (flow, speed, torque), in units of SENSOR_SCALE.
PROFILES: dict[str, tuple[tuple[float, float, float], ...]] = {
    "healthy": ((0.0, 1.0, 0.0), (0.0, 1.0, 0.0), (0.0, 1.0, 0.0)),
    "load_warning": ((-0.2, 1.0, 0.0), (-0.5, 1.2, 0.1), (0.6, 1.3, 0.2)),
    "load_alert": ((-0.4, 1.0, 0.0), (-1.0, 1.4, 0.2), (1.2, 1.6, 0.3)),
    "pump_leak_warning": ((0.3, 1.1, 0.0), (-0.4, 1.1, 0.1), (-0.5, 1.2, -0.1)),
    "pump_leak_alert": ((0.6, 1.2, 0.0), (-0.8, 1.3, 0.2), (-1.0, 1.5, -0.2)),
    "motor_leak_warning": ((0.5, 1.0, 0.1), (-0.6, 1.1, 0.0), (-0.2, 1.1, 0.0)),
    "motor_leak_alert": ((1.0, 1.1, 0.2), (-1.2, 1.3, 0.0), (-0.4, 1.2, 0.0)),
    "valve_leak": ((-0.3, 1.5, 0.0), (0.4, 0.8, 0.0), (0.3, 0.9, 0.0)),
}


def synthetic_errors(state: str, n: int, *, seed: int = 0, phi: float = 0.5) -> np.ndarray:
    """Prediction errors of one machine in ``state``, shape (n, 3) (flow L/min, speed rad/s, torque N·m).

    Per sensor: ``u`` is a unit-variance AR(1) process with coefficient ``phi``; the error is
    ``scale * (mean + std * (u + a (u^2 - 1)) / sqrt(1 + 2 a^2))``, zero-mean skewed noise for ``a != 0``.
    """
    if state not in PROFILES:
        raise ParameterError(f"state must be one of {sorted(PROFILES)}. Got {state!r}.")
    if not -1.0 < phi < 1.0:
        raise ParameterError(f"phi must be in (-1, 1) for a stationary AR(1). Got {phi}.")
    rng = np.random.default_rng(seed)
    innovations = rng.standard_normal((n, 3)) * np.sqrt(1.0 - phi * phi)
    start = rng.standard_normal((1, 3))  # stationary start: u[-1] ~ N(0, 1)
    u = lfilter([1.0], [1.0, -phi], innovations, axis=0, zi=phi * start)[0]
    profile = np.asarray(PROFILES[state])
    mean, std, skew = profile[:, 0], profile[:, 1], profile[:, 2]
    shaped = (u + skew * (u * u - 1.0)) / np.sqrt(1.0 + 2.0 * skew * skew)
    return SENSOR_SCALE * (mean + std * shaped)
