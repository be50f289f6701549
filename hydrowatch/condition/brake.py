"""The brake torque a degradation index is read at: the machine's own, as its load relation finds it now.

The index of a part (:mod:`hydrowatch.condition.degradation`) is the speed drop at 2 V that its estimated
condition would cause on the unit. A leak passes a flow ∝ the load pressure, which the brake torque TL sets
(plant-model.md Eq. 7), so the same worn part drops the speed more under a heavier brake. The brake drifts
from day to day (the unseen-units issue: load and damping ±3–5 %), and the load relation measures it in every
window (its ``load`` severity ŝ_L, TL·(1 + ŝ_L), :mod:`hydrowatch.condition.parity`). So every part but the load
itself is read on θ0 with TL·g, g = 1 + the median of ŝ_L over the machine's last ``pool`` valid windows
(:func:`brake_factors`); the load's own index stays on θ0 (it *is* the brake's change).

g is rounded to :data:`STEP` in log so that a few tables serve a run (one per fault and step, cached by
:func:`hydrowatch.plant.faults.speed_drop_table`; 20–40 ms each): at most 0.5 % of the index.

Measured (issue 15's degradation benchmark, tuning seed 2053, unit 1 re-run with the day's brake torque given to
θ0: docs/degradation.md "The brake of the day"): index MAE of motor_leak 0.029 → 0.007 and valve_leak 0.022 →
0.006; the damping Bm given instead changed nothing (0.029). Over seed 2053 the forecast errors of motor_leak and
valve_leak had the sign of the day's brake drift on all eight units.
"""

from __future__ import annotations

import numpy as np

from hydrowatch.plant.parameters import PlantParameters

STEP = 0.01
"""Rounding of the brake factor g in log (1 %): tables at g = e^(k·STEP)."""
LIMITS = (0.5, 4.0)
"""Range of g: a load severity beyond is a broken window, not a brake (the alert brake is about 2–3 × TL)."""


def brake_factors(load: np.ndarray, pool: int) -> np.ndarray:
    """g per window, shape (m,): :func:`brake_factor` of the window's load severity and the ``pool`` − 1 before it.

    Parameters
    ----------
    load : ndarray, shape (m,)
        The consecutive valid windows' free ``load`` severity (NaN: the sensors do not test the load relation).
    pool : int
        Windows in the trailing median.
    """
    s = np.asarray(load, dtype=np.float64)
    return np.array([brake_factor(s[max(0, i - pool + 1): i + 1]) for i in range(s.size)])


def brake_factor(load: np.ndarray) -> float:
    """g of one window from its trailing windows' load severities (m,): 1 + their median (NaN skipped; 1 when none
    is finite), clipped to :data:`LIMITS` and rounded to :data:`STEP` in log."""
    s = np.asarray(load, dtype=np.float64)
    median = float(np.median(s[np.isfinite(s)])) if np.isfinite(s).any() else 0.0
    return float(rounded(np.array(1.0 + median)))


def rounded(g: np.ndarray) -> np.ndarray:
    """Brake factors clipped to :data:`LIMITS` and rounded to :data:`STEP` in log."""
    g = np.clip(np.asarray(g, dtype=np.float64), *LIMITS)
    return np.asarray(np.exp(np.round(np.log(g) / STEP) * STEP))


def with_brake(nominal: PlantParameters, g: float) -> PlantParameters:
    """θ0 with its brake torque TL × ``g`` (one of :func:`brake_factors`' values)."""
    return nominal if g == 1.0 else nominal.replace(TL=nominal.TL * g)
