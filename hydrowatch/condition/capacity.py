"""The pump's capacity from the machine's own history: what commissioning cannot give of a pump that outdelivers the
valve (issue 15).

Commissioning identifies the pump's geometric flow Dp·ωp only where the recording drove the pump to its limit
(:func:`~hydrowatch.condition.unit_checks.pump_at_limit_share`). A pump that delivers more than the valve passes at
full stroke never gets there while healthy: its capacity trades with the relief's cracking pressure along a ridge
(with the relief open, Ps settles where Dp·ωp + Kr·Pc − |QL| is spent; Kr·Pc is ~17× Dp·ωp), and the fit leaves it
anywhere on it (0.75–1.14× the unit's on 10 such units of 32, docs/degradation.md). Once a pump leak has grown enough
for the pump to reach its limit, a window's pump_leak fit reads what θ0's capacity leaves for the leak: at the limit
(Eq. 1 with Eq. 5 at rest) Dp·ωp − (Cp + Cpl)·Ps = |QL| + Cvl·Ps, so a capacity (1 + q)× θ0's shifts the window's
fitted severity by

    ŝ_w = s − q · Pc / P̄s_w        (on the severity scale Cpl = Cpl0 + s·Dp·ωp/Pc, :mod:`hydrowatch.plant.faults`)

where P̄s_w is the mean supply pressure of the window's samples at the limit. The windows of a duty cycle meet the
limit at different pressures (their commands differ), while the leak wears slowly: over the pool of the machine's
last valid windows, ŝ_w = a + b·k + β·Pc/P̄s_w (k the window's place) separates the two, q̂ = −β
(:func:`capacity_error`). The index of pump_leak is then read on θ0 with the capacity (1 + q̂)·Dp·ωp and the severity
ŝ_w + q̂·Pc/P̄s_w (:func:`corrected`). Measured on the two pump_leak paths of fresh seed 2055 whose pumps were never at
their limit in commissioning (capacity 1.33×, 1.28× θ0's): q̂'s median +0.330, +0.283 (10–90 %: 0.31–0.41,
0.27–0.29); on two tuning units of seed 2054 whose capacity commissioning determined (truth +0.002, −0.022): −0.004,
−0.019 (docs/degradation.md).
"""

from __future__ import annotations

import numpy as np

from hydrowatch.condition.parity import supply_under
from hydrowatch.plant.parameters import PlantParameters

PUMP_LIMIT = "pump_limit"
"""Key, in :class:`~hydrowatch.condition.estimates.ParityEstimates`' severities, of Pc / P̄s_w: the cracking
pressure over the mean supply pressure of the window's samples at the pump's limit, under the window's own
pump_leak fit (:func:`limit_ratio`; NaN where the pump never reaches its limit in the window)."""
PUMP_LIMITED = "pump_limited"
"""Key, in :class:`~hydrowatch.condition.estimates.ParityEstimates`' severities, of each window's share of samples
with θ0's pump at its limit (relief shut, Ps < Pc) with every valve-side part at nominal (:func:`limited_share`):
what lessens a window's say in which valve-side part wears (:func:`~hydrowatch.condition.attribution.say_of`)."""
MIN_LIMITED = 20
"""Pool windows that determine pump_leak and meet the pump's limit, fewest for :func:`capacity_error` to answer."""
MAX_STANDARD_ERROR = 0.03
"""Largest standard error of q̂ (a fraction of the capacity) for :func:`capacity_error` to answer: a pool whose
windows meet the limit at nearly one pressure cannot tell a capacity from a leak."""
CAPACITY_BOUND = 0.5
"""|q̂| is clipped to this: a pump half again (or half) θ0's is past the ±20 % build spread of Dp and ωp."""
CAPACITY_STEP = 0.01
"""q̂ is rounded to this step, so that one speed-drop table serves many windows (1 % of capacity: an index change of
≤ 0.01 at alert on the tuning paths)."""


def limit_ratio(spool: np.ndarray, pl: np.ndarray, p: PlantParameters, severity: np.ndarray,
                leak: float | np.ndarray = 1.0) -> np.ndarray:
    """Pc / P̄s per window, shape (m,): P̄s [Pa] the mean supply pressure over the samples where the pump is at its
    limit (relief shut, Ps < Pc) under each window's pump_leak severity; NaN where no sample is.

    Parameters
    ----------
    spool, pl : ndarray, shape (m, n)
        Nominal spool position x̂ and load pressure P̂L [Pa] (:func:`~hydrowatch.condition.parity.valve_fit`'s).
    severity : ndarray, shape (m,)
        Each window's pump_leak severity (its free fit).
    leak : float or ndarray, shape (m, 1)
        The oil's leakage factor per window.
    """
    ps, _ = supply_under(spool, pl, p, "pump_leak", severity, leak)  # as the window's own fit integrated it
    limited = ps < p.Pc
    count = limited.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(limited, ps, 0.0).sum(axis=1) / count
        return np.where((count > 0) & (mean > 0.0), p.Pc / mean, np.nan)


def limited_share(spool: np.ndarray, pl: np.ndarray, p: PlantParameters,
                  leak: float | np.ndarray = 1.0) -> np.ndarray:
    """Share of each window's samples with the pump at its limit under ``p`` (the supply pressure integrated with
    every valve-side part at nominal below the relief's cracking pressure), shape (m,); arguments as
    :func:`limit_ratio`'s."""
    ps, _ = supply_under(spool, pl, p, None, np.zeros(spool.shape[0]), leak)
    return np.asarray(np.mean(ps < p.Pc, axis=1), dtype=np.float64)


def capacity_error(severity: np.ndarray, ratio: np.ndarray, usable: np.ndarray) -> float:
    """q̂: the pump's capacity over θ0's, minus 1, from one pool of consecutive valid windows (module docstring); NaN
    when the pool does not determine it (under :data:`MIN_LIMITED` usable windows, or a standard error over
    :data:`MAX_STANDARD_ERROR`); the machine's q̂ is the median of those it gets (:class:`MachineCapacity`).

    Parameters
    ----------
    severity, ratio : ndarray, shape (L,)
        Each window's pump_leak fit ŝ_w and Pc / P̄s_w (:func:`limit_ratio`), in time order.
    usable : ndarray of bool, shape (L,)
        Windows whose fit determines pump_leak.
    """
    ok = usable & np.isfinite(severity) & np.isfinite(ratio)
    n = int(ok.sum())
    if n < MIN_LIMITED:
        return float("nan")
    k = np.flatnonzero(ok).astype(np.float64)
    x = np.column_stack([np.ones(n), k - k.mean(), ratio[ok]])
    y = severity[ok]
    coef, _, rank, _ = np.linalg.lstsq(x, y, rcond=None)
    if rank < 3:
        return float("nan")
    residual = y - x @ coef
    variance = float(residual @ residual) / max(n - 3, 1)
    se = float(np.sqrt(variance * np.linalg.inv(x.T @ x)[2, 2]))
    if not np.isfinite(se) or se > MAX_STANDARD_ERROR:
        return float("nan")
    q = float(np.clip(-coef[2], -CAPACITY_BOUND, CAPACITY_BOUND))
    return round(q / CAPACITY_STEP) * CAPACITY_STEP


def capacity_errors(severity: np.ndarray, ratio: np.ndarray, usable: np.ndarray, pool: int) -> np.ndarray:
    """The machine's q̂ at each of m consecutive valid windows, shape (m,): :class:`MachineCapacity` fed with
    :func:`capacity_error` of each window's pool (the window and the ``pool − 1`` before it; fewer at the start);
    NaN until a pool has determined it."""
    machine = MachineCapacity()
    out = np.empty(severity.size)
    for i in range(severity.size):
        at = slice(max(0, i - pool + 1), i + 1)
        out[i] = machine.add(capacity_error(severity[at], ratio[at], usable[at]))
    return out


class MachineCapacity:
    """The machine's q̂: the median of every pool's q̂ so far (a pump's capacity is the machine's, not the window's;
    one pool's q̂ overshoots by up to 0.1 while the leak's trend bends). A histogram of :data:`CAPACITY_STEP` bins
    over ±:data:`CAPACITY_BOUND`, so the memory is fixed however long the machine runs.

    Measured on fresh seed 2055's unit 0 (capacity 1.33× θ0's): with each pool's own q̂ the forecast at index 0.5
    was 686 s for a true 1389 s (an exponential trend chosen on the overshoot), with this median 1271 s.

    Before any pool has determined it, q̂ is NaN: pump_leak has no index, since read on a capacity off by a third a
    wearing pump's first windows read half the true index (and the forecast came 35 % early).
    """

    def __init__(self) -> None:
        self._counts = np.zeros(2 * round(CAPACITY_BOUND / CAPACITY_STEP) + 1, dtype=np.int64)

    def add(self, found: float) -> float:
        """Count one pool's q̂ (NaN: the pool did not determine it; clipped to ±:data:`CAPACITY_BOUND`) and return
        the machine's: the lower median of those counted, NaN while none is."""
        if np.isfinite(found):
            q = min(max(found, -CAPACITY_BOUND), CAPACITY_BOUND)
            self._counts[round((q + CAPACITY_BOUND) / CAPACITY_STEP)] += 1
        n = int(self._counts.sum())
        if n == 0:
            return float("nan")
        k = int(np.searchsorted(np.cumsum(self._counts), (n + 1) // 2))
        return round(k * CAPACITY_STEP - CAPACITY_BOUND, 6)


def with_capacity(nominal: PlantParameters, q: float) -> PlantParameters:
    """θ0 with the pump's capacity (1 + q)·Dp·ωp (Dp scaled; the relief as commissioned)."""
    return nominal if q == 0.0 else nominal.replace(Dp=nominal.Dp * (1.0 + q))


def corrected(severity: np.ndarray, ratio: np.ndarray, q: float | np.ndarray) -> np.ndarray:
    """pump_leak severities (any shape, last axis the m windows) for θ0 with the capacity of :func:`with_capacity`:
    ŝ + q·Pc/P̄s on θ0's scale, converted to the scale of θ0 with the new capacity (Cref grows with Dp); ``ratio``
    and ``q`` scalars or shape (m,). Windows without a ratio (never at the limit) are shifted by nothing."""
    shift = q * np.nan_to_num(ratio, nan=0.0)
    return (np.asarray(severity) + shift) / (1.0 + q)
