"""Windows near standstill on a unit whose brake smoothing speed was left to its prior: the load relation is not judged.

The load relation (Eq. 7) holds the brake as TL·tanh(ω/ωs). Within a few ωs of standstill the sign term depends on
ωs, which only a recording that comes near standstill identifies (:mod:`hydrowatch.condition.determinacy`): a
healthy duty cycle of 0.5–3.5 V never does, and commissioning from one keeps the trained unit's ωs, ±20 % and more
from the unit's own. A machine that nearly stalls in a low hold (a motor leak at its alert level at 0.5 V) then
misfits the load relation by the same factor for every state, healthy included (fresh seed 2065, unit 8, a
duty-commissioned motor_leak_alert at 0.23 rad/s: load ratio 10–11 for every state, ωs 0.278 kept against the unit's
0.176; motor and valve relations 1.0 for the right state). Each such window read ``unknown`` alone and the pool
carried it over the next nine windows, which alone read the motor leak right (98.6 % per window, 96.1 % pooled).

Such a window is one the model cannot judge through the load relation, not evidence of an unseen fault: on a unit
whose ωs was left to its prior (``ConditionFeatures.brake_open_``), its load-relation ratios are set to 1 for every
state (no evidence either way) and the load fault's severity estimate carries no weight in a pool
(:mod:`hydrowatch.condition.evidence`). The motor and valve relations judge it as before.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from hydrowatch.condition.determinacy import STANDSTILL

if TYPE_CHECKING:  # estimates is in the features' import cycle (tests/test_layers.py)
    from hydrowatch.condition.ratios import FillGroup

MIN_SHARE = 0.05
"""Smallest share of a window's samples within :data:`~hydrowatch.condition.determinacy.STANDSTILL` × ωs of standstill
(|ω| < 3 ωs) for which its load relation is not judged: 50 samples (0.25 s) of a 5 s window. A duty cycle's
healthy windows never come there (its slowest sample 0.1–5 rad/s against 3 ωs ≈ 0.6 rad/s)."""


def near_standstill(speed: np.ndarray, omega_s: float) -> np.ndarray:
    """Windows with at least :data:`MIN_SHARE` of their gearbox speed samples ``speed`` (n, window) [rad/s] within
    3 ωs of standstill, shape (n,)."""
    s = np.atleast_2d(np.asarray(speed, dtype=np.float64))
    return np.asarray(np.mean(np.abs(s) < STANDSTILL * omega_s, axis=1) >= MIN_SHARE, dtype=bool)


def stalled(groups: Sequence[FillGroup], omega_s: float, brake_open: bool) -> np.ndarray:
    """The valid windows of ``groups`` (:meth:`ConditionFeatures._estimates`) whose load relation is not judged,
    shape (m,): none unless the unit's ωs was left to its prior (``brake_open``), else :func:`near_standstill`."""
    speed = groups[0].signals.speed
    if not brake_open:
        return np.zeros(speed.shape[0], dtype=bool)
    return near_standstill(speed, omega_s)


def without_load_relation(ratios: np.ndarray, names: Sequence[str], windows: np.ndarray) -> None:
    """The load relation's ratios (columns named ``load|…`` of ``names``) set to 1, in place, in ``windows`` (m,)
    bool of ``ratios`` (m, n_features): no evidence either way."""
    rows = np.asarray(windows, dtype=bool)
    if rows.any():
        ratios[np.ix_(rows, np.array([n.startswith("load|") for n in names], dtype=bool))] = 1.0
