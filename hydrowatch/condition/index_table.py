"""The degradation index of a severity on one unit (its speed-drop table), and pump_leak's index re-read on the
machine's latest pump capacity (issue 15).

:func:`degradation_index` maps a fault's severity to the index, the speed drop at 2 V it causes on θ0 over the alert
drop (:mod:`hydrowatch.condition.degradation`); :func:`unit_indices` does it for windows each read on θ0 with their
own brake factor and pump capacity.

**Re-read on the latest capacity** (2026-12-04, stop 63). Where commissioning left the pump's capacity undetermined,
each window's pump_leak index is read on the capacity the machine's history gave by then
(:class:`~hydrowatch.condition.capacity.MachineCapacity`), and the first pools that determine it can be off: on
regular unit 2106/3 (capacity +0.080 of θ0's) they read −0.05 to −0.01, the history's index there 0.02–0.04 low,
and the forecast at the warning came 28 % late. A forecast is of the part, not of what the machine knew of its pump
when: so it reads the part's history with every value re-read on the capacity of the latest window that has one
(:class:`LeakReading`, :func:`reread_leak`), from that window's free fit ŝ, its Pc / P̄s and brake factor, exactly
(the map is not linear in the capacity: a first-order correction left 13 % of 2106/3's 28 %). The per-window index
(``score --json``'s windows, the health message) stays as read then: it says what the machine knew in that window.
Measured in docs/degradation.md ("The capacity re-read").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrowatch.condition.brake import with_brake
from hydrowatch.condition.capacity import corrected, with_capacity
from hydrowatch.plant.faults import LEVELS, speed_drop_table
from hydrowatch.plant.parameters import PlantParameters

ALERT_DROP = LEVELS["alert"]
"""Speed drop at 2 V that the index divides by: 1.0 = alert."""
TABLE_DROP = 0.6
"""Largest speed drop tabulated (index 2); beyond it the table is extrapolated linearly."""
LEAK = "pump_leak"
"""The part whose index depends on the pump's capacity."""


def degradation_index(fault: str, severity: np.ndarray | float, nominal: PlantParameters) -> np.ndarray:
    """Index I = speed drop at 2 V / 0.30 of severities ŝ of one fault on one unit
    (:mod:`hydrowatch.condition.degradation`).

    Parameters
    ----------
    fault : str
        One of :data:`~hydrowatch.plant.faults.FAULTS`.
    severity : array_like
        Severity on the fault's scale (:mod:`hydrowatch.plant.faults`), any shape; negative: better than nominal.
    nominal : PlantParameters
        The unit's own healthy parameters.

    Returns
    -------
    ndarray, shape of ``severity``
        Index, dimensionless (NaN where the severity is NaN, and at ±inf beyond a flat end of the table: an
        undetermined fit's interval bound, which :func:`~hydrowatch.condition.degradation.widened` caps).
    """
    drop, sev = speed_drop_table(fault, TABLE_DROP, nominal)
    s = np.asarray(severity, dtype=np.float64)
    value = np.interp(s, sev, drop)
    low_slope = (drop[1] - drop[0]) / (sev[1] - sev[0])
    high_slope = (drop[-1] - drop[-2]) / (sev[-1] - sev[-2])
    with np.errstate(invalid="ignore"):  # ±inf (an undetermined fit's interval bound) on a flat end: NaN, no bound
        value = np.where(s < sev[0], drop[0] + low_slope * (s - sev[0]), value)
        value = np.where(s > sev[-1], drop[-1] + high_slope * (s - sev[-1]), value)
    return np.asarray(value / ALERT_DROP)


def unit_indices(fault: str, severity: np.ndarray, nominal: PlantParameters, brake: np.ndarray,
                 capacity: np.ndarray) -> np.ndarray:
    """:func:`degradation_index` of severities (k, m) whose column i is read on θ0 with TL × ``brake[i]`` and the
    pump's capacity × (1 + ``capacity[i]``): one table look-up per distinct pair."""
    out = np.empty(severity.shape)
    pairs = np.stack([brake, capacity], axis=1)
    for g, q in np.unique(pairs, axis=0):
        at = (brake == g) & (capacity == q)
        out[:, at] = degradation_index(fault, severity[:, at], with_brake(with_capacity(nominal, float(q)), float(g)))
    return out


@dataclass(frozen=True)
class LeakReading:
    """What re-reads a machine's pump_leak index on another capacity, per window, each shape (n,): the window's free
    fit ŝ, its Pc / P̄s (0 where the pump never met its limit: :func:`~hydrowatch.condition.capacity.corrected`
    shifts those by nothing), brake factor g and the machine's q̂ its index was read with; NaN where the window has
    no pump_leak index. ``nominal``: θ0."""

    nominal: PlantParameters
    severity: np.ndarray
    ratio: np.ndarray
    brake: np.ndarray
    capacity: np.ndarray

    def at(self, i: int) -> dict[str, object]:
        """Window ``i``'s reading, as ``score``'s online history receives it: ``{"severity", "limit_ratio", "brake",
        "capacity"}`` (floats) and ``"nominal"`` (θ0)."""
        return {"severity": float(self.severity[i]), "limit_ratio": float(self.ratio[i]),
                "brake": float(self.brake[i]), "capacity": float(self.capacity[i]), "nominal": self.nominal}

    def reread(self, history: np.ndarray) -> np.ndarray:
        """pump_leak's ``history`` (its first m ≤ n windows) re-read on the latest capacity (:func:`reread_leak`)."""
        m = history.size
        return reread_leak(history, self.severity[:m], self.ratio[:m], self.brake[:m], self.capacity[:m],
                           self.nominal)


def reread_leak(history: np.ndarray, severity: np.ndarray, ratio: np.ndarray, brake: np.ndarray,
                capacity: np.ndarray, nominal: PlantParameters) -> np.ndarray:
    """pump_leak's history (n,) with every finite value that was read on another capacity re-read on the capacity of
    the latest window with a value and a reading (module docstring); a value without a reading (NaN q̂) stays.

    Parameters
    ----------
    history : ndarray, shape (n,)
        The part's index per window (NaN: none), as read then.
    severity, ratio, brake, capacity : ndarray, shape (n,)
        The windows' :class:`LeakReading`.
    nominal : PlantParameters
        θ0.
    """
    out = np.array(history, dtype=np.float64)
    has = np.isfinite(out) & np.isfinite(capacity)
    if not has.any():
        return out
    q = float(capacity[np.flatnonzero(has)[-1]])
    again = has & (capacity != q)
    if again.any():
        n = int(again.sum())
        out[again] = unit_indices(LEAK, corrected(severity[again][None], ratio[again], q), nominal, brake[again],
                                  np.full(n, q))[0]
    return out
