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

**One oil wets every path** (:func:`motor_factors`). That warning against alert is not a limit of the sensors: the
motor's own leakage Ctm scales with the same viscosity, and the motor relation reads it in every window whose motor
is healthy, so f̂ = 1 + ŝ_motor / c₀ (c₀ = Ctm / Cref). Each state whose own fault is not a motor leak now widens its
leak ranges per window by f̂ within ``FACTOR_SPREAD`` (and the estimate's noise) instead of the whole ±5 K; the
motor_leak states keep the whole range (their motor path is the fault). Measured on tuning seed 2045 (units 1, 3, 5,
7: identified Ctm 0.87–0.98 × the truth, day drift ±3–5 %): f̂ / f median 0.91–1.06 per unit, 5–95 % of windows
0.80–1.15. The 7-state oil condition without the channel (duty cycle, oil 5 K warm or cold), per window / pooled over
12, six units of 2045: median 87.5 / 87.3 → 100 / 100, worst 85.7 / 85.7 → 99.6 / 100; eight units of 2044: 100 /
100 for all; 13 states (2045 units 1, 3, 5): median 76.7 / 92.3 → 87.3 / 100, worst 74.8 / 91.5 → 84.6 / 98.7.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hydrowatch.plant.parameters import PlantParameters

OIL_RANGE = 5.0
"""Default half-range of the oil temperature around 40 °C, K, that a window without the temperature channel may
have: a circuit with a cooler held at its set point. A wider range widens every leak box further (more of the
pump leak's warning and alert overlap)."""

FACTOR_SPREAD = 0.10
"""Relative error of the oil's leakage factor read from one window's motor leakage (:func:`motor_factors`) besides
its noise: the unit's identified Ctm and its drift since (measured below)."""

LEAK_BASELINE: dict[str, Callable[[PlantParameters], float]] = {
    "pump_leak": lambda p: p.Cp + p.Cpl + p.Cvl,
    "motor_leak": lambda p: p.Ctm,
    "valve_leak": lambda p: p.Cvx,
}
"""Healthy leakage, m³/(s·Pa), of the path each leak fault adds to (``fault_parameters`` of plant.faults)."""


def _reference_conductance(p: PlantParameters) -> float:
    """Cref = Dp·ωp/Pc, m³/(s·Pa) (as ``parity.reference_conductance``; not imported from there: importing any
    module of ``hydrowatch.condition`` loads the package, which imports this one)."""
    return p.Dp * p.omega_p / p.Pc


def leakage_range(viscosity_coefficient: float, oil_range: float) -> tuple[float, float]:
    """Leakage factors (f_lo, f_hi) of oil ``oil_range`` K colder and warmer than 40 °C (k in 1/K)."""
    return float(np.exp(-viscosity_coefficient * oil_range)), float(np.exp(viscosity_coefficient * oil_range))


def oil_box(box: Mapping[str, tuple[float, float]], p: PlantParameters,
            factors: tuple[Any, Any]) -> dict[str, tuple[Any, Any]]:
    """A severity box widened on every leak fault by the leakage factors ``factors`` (module docstring).

    Parameters
    ----------
    box : mapping of fault to (lo, hi)
        Severities on each fault's scale (:func:`hydrowatch.plant.faults.fault_parameters`).
    p : PlantParameters
        The unit's nominal parameters (its healthy leakages and Cref = Dp·ωp/Pc).
    factors : (float, float) or (ndarray, ndarray)
        (f_lo, f_hi), :func:`leakage_range`; or per window, shape (m,) each (:func:`motor_factors`).
    """
    c_ref = _reference_conductance(p)
    out: dict[str, tuple[Any, Any]] = dict(box)
    for fault, baseline in LEAK_BASELINE.items():
        if fault in out:
            c0 = baseline(p) / c_ref
            lo, hi = out[fault]
            ends = [f * (s + c0) for s in (lo, hi) for f in factors]
            out[fault] = (np.minimum.reduce(ends) - c0, np.maximum.reduce(ends) - c0)
    return out


def motor_factors(motor_leak: np.ndarray, standard_error: np.ndarray, p: PlantParameters,
                  factors: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Per window, the leakage factors (low, high) the motor's own leakage allows, inside ``factors``.

    One oil wets every leakage path, so a window whose motor is healthy tells the oil's factor f
    from the motor relation: its severity read at f = 1 is ŝ = (f − 1)·c₀, c₀ = Ctm / Cref, so
    f̂ = 1 + ŝ / c₀. The range is f̂ within ``FACTOR_SPREAD`` in ratio, widened by the estimate's
    standard error se / c₀ (added in quadrature), clipped to ``factors``; a window whose motor
    relation determines nothing (an infinite error: no flow or speed sensor) or a unit without
    motor leakage keeps all of ``factors``.

    Parameters
    ----------
    motor_leak, standard_error : ndarray, shape (m,)
        The windows' free motor_leak severity and its standard error
        (:func:`~hydrowatch.condition.estimates.severity_standard_error`).
    p : PlantParameters
        The unit's nominal parameters.
    factors : (float, float)
        (f_lo, f_hi) of :func:`leakage_range`.
    """
    lo, hi = factors
    c0 = LEAK_BASELINE["motor_leak"](p) / _reference_conductance(p)
    m = np.asarray(motor_leak).shape[0]
    if c0 <= 0.0:
        return np.full(m, lo), np.full(m, hi)
    ok = np.isfinite(motor_leak) & np.isfinite(standard_error)
    f = np.clip(1.0 + np.where(ok, motor_leak, 0.0) / c0, lo, hi)
    spread = 1.0 + np.hypot(FACTOR_SPREAD, np.where(ok, standard_error, 0.0) / c0)
    return (np.where(ok, np.maximum(lo, f / spread), lo), np.where(ok, np.minimum(hi, f * spread), hi))


def motor_oil_box(box: Mapping[str, tuple[float, float]], p: PlantParameters, motor_leak: np.ndarray,
                  standard_error: np.ndarray, factors: tuple[float, float]) -> dict[str, tuple[Any, Any]]:
    """:func:`oil_box` widened per window by :func:`motor_factors` (a state whose motor is healthy)."""
    return oil_box(box, p, motor_factors(motor_leak, standard_error, p, factors))


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

