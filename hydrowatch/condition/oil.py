"""What the relations may assume about the oil when a window has no temperature channel.

Every laminar leakage scales with 1/viscosity, viscosity ∝ exp(−k·(T − 40 °C)) (plant-model.md's
thermal drift, :func:`hydrowatch.condition.parity.leakage_factor`). With the temperature channel the
relations refer each window's leakages to 40 °C. Without it the oil's temperature is unknown, and a
leakage L read from a window is only known to be (L₀ + s·Cref)·f with f ∈ [exp(−k·ΔT), exp(k·ΔT)],
ΔT the oil's spread around 40 °C (:data:`OIL_RANGE`). Read at f = 1, a state's severity box
[lo, hi] on a leak fault therefore covers the severities

    [(c₀ + lo)·f_lo − c₀, (c₀ + hi)·f_hi − c₀],    c₀ = L₀ / Cref

(:func:`oil_box`): the box widened by the viscosity range on the *total* leakage of that path
(pump_leak: Cp + Cpl + Cvl, the supply; motor_leak: Ctm; valve_leak: Cvx).

Measured (development population seed 7, 3 units, 7 states, duty cycle 0.5–3.5 V on a later day,
oil 5 °C warm and 5 °C cold, scored without the temperature channel): % of windows right, per
window / pooled over 12, 75.7 / 67.1 at f = 1 (the boxes of a 40 °C oil) → 93.9 / 92.4 with the
band and level boxes widened for ΔT = 5 K (91.5 / 90.8 widening the band boxes only). Before, a warm
motor_leak_alert read `unknown` (its leakage 22 % past the alert band) and pump leaks at either level
read `unknown`; what is left is the pump leak's warning against its alert: ±22 % on the supply's
total leakage makes a warning on warm oil and an alert on cold oil the same leakage (the two ranges
meet), which no relation can tell without the temperature. The cost is on unseen faults read
without temperature: 62.5 → 44.9 % `unknown` per window, 98.3 → 95.8 % pooled.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from hydrowatch.plant.parameters import PlantParameters

OIL_RANGE = 5.0
"""Default half-range of the oil temperature around 40 °C, K, that a window without the temperature channel may
have: a circuit with a cooler held at its set point. A wider range widens every leak box further (more of the
pump leak's warning and alert overlap)."""

LEAK_BASELINE: dict[str, Callable[[PlantParameters], float]] = {
    "pump_leak": lambda p: p.Cp + p.Cpl + p.Cvl,
    "motor_leak": lambda p: p.Ctm,
    "valve_leak": lambda p: p.Cvx,
}
"""Healthy leakage, m³/(s·Pa), of the path each leak fault adds to (``fault_parameters`` of plant.faults)."""


def leakage_range(viscosity_coefficient: float, oil_range: float) -> tuple[float, float]:
    """Leakage factors (f_lo, f_hi) of oil ``oil_range`` K colder and warmer than 40 °C (k in 1/K)."""
    return float(np.exp(-viscosity_coefficient * oil_range)), float(np.exp(viscosity_coefficient * oil_range))


def oil_box(box: Mapping[str, tuple[float, float]], p: PlantParameters,
            factors: tuple[float, float]) -> dict[str, tuple[float, float]]:
    """A severity box widened on every leak fault by the leakage factors ``factors`` (module docstring).

    Parameters
    ----------
    box : mapping of fault to (lo, hi)
        Severities on each fault's scale (:func:`hydrowatch.plant.faults.fault_parameters`).
    p : PlantParameters
        The unit's nominal parameters (its healthy leakages and Cref = Dp·ωp/Pc).
    factors : (float, float)
        (f_lo, f_hi), :func:`leakage_range`.
    """
    c_ref = p.Dp * p.omega_p / p.Pc
    out = dict(box)
    for fault, baseline in LEAK_BASELINE.items():
        if fault in out:
            c0 = baseline(p) / c_ref
            lo, hi = out[fault]
            ends = [f * (s + c0) for s in (lo, hi) for f in factors]
            out[fault] = (min(ends) - c0, max(ends) - c0)
    return out


def temperature_known(windows: np.ndarray, width: int) -> np.ndarray:
    """Whether each window (m, n, width or width + 1) carries the oil temperature: a 5th channel not all NaN."""
    if windows.shape[2] <= width:
        return np.zeros(windows.shape[0], dtype=bool)
    return ~np.all(np.isnan(windows[:, :, width]), axis=1)


def oil_parts(windows: np.ndarray, width: int) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """Windows (m, n, width or width + 1) split by :func:`temperature_known`: (mask, windows, known) per part
    present, the windows without the oil temperature given as ``width`` channels."""
    known = temperature_known(windows, width)
    return [(mask, windows[mask] if flag else windows[mask][:, :, :width], flag)
            for flag, mask in ((True, known), (False, ~known)) if mask.any()]

