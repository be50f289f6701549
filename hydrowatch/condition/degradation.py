"""Degradation index per component and window: how far each part has worn, in units of the alert (issue 15).

The index of fault ``f`` in a window is the fractional drop of the steady gearbox speed at 2 V that the
component's estimated condition would cause on its own, on this unit, divided by the alert drop:

    I_f = (1 − ωg(θ0 with f at ŝ_f) / ωg(θ0)) / 0.30        (study Sections 5.3, 6.1: warning 15 %, alert 30 %)

θ0 is the unit's own nominal parameters (identified at training or commissioning,
:mod:`hydrowatch.condition.unit`), ŝ_f the window's parity estimate of the fault's severity
(:mod:`hydrowatch.condition.estimates`; study Eqs. 2.1–2.5 as relations). So 0 = as commissioned, 0.5 = warning,
1.0 = alert, above 1 beyond it; slightly negative values are noise around a part as good as new (kept, so that
averages stay unbiased). The map ŝ → I is a monotone table per (fault, unit)
(:func:`hydrowatch.plant.faults.speed_drop_table`), linearly extrapolated beyond it. Every part but the load is read
on θ0 with the brake torque the machine's load relation finds now (:mod:`hydrowatch.condition.brake`): a leak's
flow, and so its speed drop, grows with the load pressure the brake sets.

**Interval.** Each relation's fit gives MSE(s) = MSE_min + c·(s − ŝ)² (``ParityEstimates.curvature``), so for N
residual blocks the least-squares standard error is se(ŝ) = √(MSE_min / ((N − 1)·c)) (the Gauss-Newton covariance;
exact for the linear relations). The block residuals are not independent (the misfit of a unit whose parameters
drifted since commissioning is slow), so se is multiplied by :data:`~hydrowatch.condition.estimates.SE_INFLATION`.
The 95 % interval ŝ ± 1.96·se is mapped through the same monotone table (which keeps its coverage), then widened by
the systematic error of the unit's own nominal parameters (:data:`SYSTEMATIC`, :func:`widened`): on simulated units
the statistical part alone is 10× too narrow for load and motor_leak, whose fits are precise but biased by a few
percent (docs/degradation.md).

**Which valve-side part.** The four valve-side faults (pump_leak, relief_spring, valve_coil, valve_leak) are
separate one-parameter hypotheses of one relation; in a hold at one command several explain a window equally
(docs/command-invariance.md), and window by window a look-alike often explains a worn part's windows as well or
better (a valve_coil hypothesis for a weak relief spring). But a part wears slowly: over the machine's last
:data:`ATTRIBUTION_WINDOWS` valid windows the worn part's fits agree on one severity trend, while a look-alike needs
a severity that moves with the command. The hypothesis with the smallest :func:`pool_misfit` (Σ log MSE when the
pool shares one severity trend, a parabola in time) is the worn part and gets its index; the others read 0 with an
interval that spans 0 and their own one-hypothesis interval (what they would be if they were the cause). When the
runner-up is within :data:`ATTRIBUTION_MARGIN` of it, the pool does not tell which part wears: from
:data:`UNTOLD_LEVEL` on, every part the pool cannot rule out (its misfit within the margin of the best) then has no
index (NaN) rather than a value on what may be the wrong part, or a 0 on what may be the worn one. While the blamed
part's wear is early (its index at the median of its pool's severities below
:data:`~hydrowatch.condition.attribution.EARLY_LEVEL`) the margin is
:data:`~hydrowatch.condition.attribution.EARLY_MARGIN`: there θ0's own error makes gaps as large as early wear does.
load and motor_leak have their own relations and are always estimated.

**The pump's capacity.** pump_leak is read on θ0 with the pump's capacity its own history gives
(:mod:`hydrowatch.condition.capacity`): a pump that outdelivers the valve never reaches its limit in commissioning,
which then leaves Dp·ωp anywhere along the relief's ridge; once a leak takes the pump to its limit, the pool's windows
meeting it at different pressures separate the capacity from the leak. Until they have, a unit whose commissioning
left the capacity undetermined has no pump_leak index (:class:`~hydrowatch.condition.capacity.MachineCapacity`).
A forecast reads the part's history re-read on the latest capacity (:mod:`hydrowatch.condition.index_table`).

**Determined or not.** A window whose fit barely depends on a part's severity (a severity :data:`DETERMINED_STEP`
off would not double its MSE) has no index for that part (NaN), whatever its interval says: the severity search
stops anywhere in a flat valley (pump_leak where the pump is far from its limit).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from hydrowatch.condition import parity
from hydrowatch.condition.attribution import ATTRIBUTION_MARGIN as ATTRIBUTION_MARGIN  # the public names stay here
from hydrowatch.condition.attribution import ATTRIBUTION_WINDOWS as ATTRIBUTION_WINDOWS
from hydrowatch.condition.attribution import LOOK_ALIKES, NOMINAL_VALVE, contenders, pool_median
from hydrowatch.condition.attribution import attributed_valve_fault as attributed_valve_fault
from hydrowatch.condition.attribution import pool_misfit as pool_misfit
from hydrowatch.condition.brake import brake_factors
from hydrowatch.condition.capacity import PUMP_LIMIT, PUMP_LIMITED, capacity_errors, corrected
from hydrowatch.condition.degradation_series import SHARED_PAIR
from hydrowatch.condition.degradation_series import Degradation as Degradation  # the public name stays here
from hydrowatch.condition.estimates import MOVING_LOAD, ParityEstimates, severity_standard_error
from hydrowatch.condition.features import ConditionFeatures
from hydrowatch.condition.features_evidence import RELATION_OF
from hydrowatch.condition.index_table import ALERT_DROP as ALERT_DROP  # the public names stay here
from hydrowatch.condition.index_table import LEAK, LeakReading, unit_indices
from hydrowatch.condition.index_table import TABLE_DROP as TABLE_DROP
from hydrowatch.condition.index_table import degradation_index as degradation_index
from hydrowatch.condition.unit_checks import relief_barely_seen
from hydrowatch.plant.faults import FAULTS
from hydrowatch.plant.parameters import PlantParameters

Z95 = 1.959963984540054
"""Two-sided 95 % normal quantile."""
SYSTEMATIC = (0.02, 0.03)
"""Standard deviation of the index's systematic error, absolute + relative to the index: the commissioned nominal
parameters are themselves estimates and a later day drifts leakages, load and damping by ±3–5 % (on tuning units,
healthy load indices of −0.02 to −0.03 and index errors of 3–5 % at alert). Added in quadrature to the interval."""
DETERMINED_STEP = 0.1
"""Severity step (on the fault's scale) by which a window's fit must tell its estimate from a wrong one: a window
*determines* a part when a severity this far off would at least double its MSE (c·step² ≥ MSE_min). Elsewhere the
window has no index for the part (NaN: absent from ``score --json``'s window, left out of the forecast). On the
duty cycle only pump_leak has such windows (where the pump is far from its limit, 6–28 % of a wearing pump's
windows): their index was off by 0.15–0.32 on average (the severity search stops in a flat valley), against
0.005–0.07 for the windows that determine it (seeds 7 and 2027); load, motor_leak, valve_leak, valve_coil and
relief_spring fits passed the test ≥ 10 times over in every window looked at."""
UNTOLD_LEVEL = 0.1
"""Index from which a valve-side part blamed without :data:`ATTRIBUTION_MARGIN` has no index (NaN, "which part
wears is not told"); below it the blamed part keeps its value: which part wears does not matter to a plan there (a
fifth of the warning, the forecast's ``MIN_RISE``), and the valve-side look-alikes of a healthy machine are never
told apart."""
INDEX_CAP = 10.0
"""Interval bounds are clipped to ±INDEX_CAP: a bound there means the window does not determine the part (a flat
fit, such as relief_spring while the relief never cracks)."""


COIL_AT_LIMIT = 0.99
"""Share of a window's samples with θ0's pump at its limit (:data:`~hydrowatch.condition.capacity.PUMP_LIMITED`) from
which its fit does not determine the coil's index. With the pump at its limit throughout, the valve passes what the
pump delivers less the leaks, and the coil's severity moves only the supply pressure: its fit reads θ0's capacity and
supply errors as much as the coil. Measured on the stored window fits (index − truth on coil paths, true 0.1–0.9): in
such windows median +0.13, +0.10, −0.05 and −0.06 on 2093 unit 3, 3001 units 114 and 36 and 2088 unit 2, against
medians of −0.01 to +0.02 in the same paths' windows below it (shares 0–0.99 alike). Without them: on tuning
2086–2093 the worst coil MAE 0.043 → 0.020; on 8 units whose commissioning barely saw the relief (3001/3002) coil
forecasts within ±20 % 5 → 8 of 8 (docs/degradation.md, "The coil at the pump's limit")."""


AT_LIMIT_PARTS: tuple[str, ...] = ("valve_coil", "relief_spring")
"""Parts a window with θ0's pump at its limit throughout (:data:`COIL_AT_LIMIT`) does not determine: the coil (above),
and since stop 59 the relief spring. With θ0's pump at its limit the relief of θ0 is shut, and its fit finds a
narrow valley where cracking explains θ0's capacity error instead (as the coil's reads it): on flagged unit 3011/51
(fresh for stop 59's other changes, where this was found) all 111 relief windows off by more than 0.2 were such
windows (true 0.1–0.5: median error +0.37), every other window within 0.06; on the 40 flagged units 3001–3010 such
windows of a relief at true 0.1–1.0 had a mean error above 0.05 in a band on 24 units (medians −0.40 to +0.62), the
other windows' medians −0.10 to +0.04. Beyond the alert (true 1.0–1.4) they read within 0.02 in median, and are
dropped too: one rule, not one that reads the window's own index. Stored fits replayed (tuning: 3001–3012, 48
flagged units; 2098–2101, 16 regular): relief MAE worst 0.067 → 0.026 (3011/3012) and 0.037 → 0.029 (3001–3010),
relief forecasts within ±20 % and covered the same (39 and 38 of 40; worst 25.4 → 22.2 %), no false forecast (with
:meth:`~.degradation_series.Degradation.ruled_out` deciding the pair on the latest window that reads either); the
cost, fewer indexed relief windows: 49 → 30 % of a flagged relief path's windows, 66 → 52 % on regular 2100/2101
(worst relief forecast there 3.9 → 9.3 %) (docs/degradation.md, "The relief at the pump's limit")."""


def widened(value: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A statistical 95 % interval of the index widened by :data:`SYSTEMATIC` in quadrature and clipped to
    ±:data:`INDEX_CAP`, each shape (m,)."""
    sys = Z95 * (SYSTEMATIC[0] + SYSTEMATIC[1] * np.abs(value))
    with np.errstate(invalid="ignore"):
        lo = value - np.sqrt((value - low) ** 2 + sys**2)
        hi = value + np.sqrt((high - value) ** 2 + sys**2)
    return np.clip(np.nan_to_num(lo, nan=-INDEX_CAP), -INDEX_CAP, INDEX_CAP), np.clip(
        np.nan_to_num(hi, nan=INDEX_CAP), -INDEX_CAP, INDEX_CAP)


def window_degradation(estimates: ParityEstimates, valid: np.ndarray, nominal: PlantParameters, blocks: int,
                       relations: Sequence[str], pool: int = ATTRIBUTION_WINDOWS,
                       blamed: np.ndarray | None = None, excess: np.ndarray | None = None,
                       brake: np.ndarray | None = None, capacity: np.ndarray | None = None,
                       capacity_known: bool = True,
                       pool_severity: Mapping[str, np.ndarray] | None = None, held: int = -1,
                       relief_barely_seen: bool = False) -> Degradation:
    """Index and interval of every fault the ``relations`` test, per window (module docstring).

    Parameters
    ----------
    estimates : ParityEstimates
        Free fits of the valid windows (``valve_search`` on), each array shape (m,), m = ``valid.sum()``.
    valid : ndarray of bool, shape (n,)
        Which of the machine's consecutive windows the estimates belong to.
    nominal : PlantParameters
        The unit's own healthy parameters (those the estimates were made with).
    blocks : int
        Residual blocks per window.
    relations : sequence of str
        Relations the sensors test (``ConditionFeatures.relations_``).
    pool : int, default :data:`ATTRIBUTION_WINDOWS`
        Valid windows deciding the valve-side part (:func:`attributed_valve_fault`).
    blamed : ndarray of int, shape (n,), optional
        The valve-side part of each window when the caller has chosen it
        (:class:`~.degradation_stream.DegradationStream`).
    excess : ndarray, shape (n, 4), optional
        With ``blamed``: each valve hypothesis's pool misfit minus the blamed part's (None: every window told
        apart).
    brake : ndarray, shape (m,), optional
        Brake factor g of each valid window (:func:`~hydrowatch.condition.brake.brake_factors`; None: from the
        estimates' load severities over ``pool`` windows, 1 where the sensors do not test the load relation). Every
        part but the load is read on θ0 with TL·g (:mod:`hydrowatch.condition.brake`).
    capacity : ndarray, shape (m,), optional
        The machine's q̂ at each valid window: its pump's capacity over θ0's, minus 1, NaN while its history has
        not determined it (:func:`~hydrowatch.condition.capacity.capacity_errors`, which None calls with ``pool``).
        pump_leak is read on θ0 with that capacity, and has no index where it is NaN.
    capacity_known : bool, default True
        Whether θ0's capacity is determined (``ConditionFeatures.capacity_known_``): q̂ = 0 throughout; else (and
        ``capacity`` None) from the history, and the result keeps what re-reads pump_leak's history on the latest
        q̂ (:class:`~hydrowatch.condition.index_table.LeakReading`).
    pool_severity : mapping of valve hypothesis to ndarray, shape (m,), optional
        Each valve hypothesis's median free-fit severity over the window's pool (None: from the estimates with
        ``pool``); the blamed part's index there chooses the margin (:func:`~.attribution.contenders`).
    held : int, default -1
        Index into :data:`~hydrowatch.condition.parity.VALVE_HYPOTHESES` of the part held before the first window
        (the last told apart while worn, :data:`~.attribution.HELD_MARGIN`; −1: none); the result's ``held`` is the
        one after the last.
    relief_barely_seen : bool, default False
        The unit's commissioning barely saw the relief's gain
        (:func:`~hydrowatch.condition.unit_checks.relief_barely_seen`): the relief spring's and the coil's early wear
        are not told apart (:func:`~.attribution.contenders`).
    """
    n = valid.size
    value, low, high, provisional = ({f: np.full(n, np.nan) for f in FAULTS} for _ in range(4))
    measured = {f: np.zeros(n, dtype=bool) for f in FAULTS}
    own = _load_away_from_standstill(estimates)
    mse = {f: own.mse[RELATION_OF[f] if f in ("load", "motor_leak") else f] for f in FAULTS}
    if blamed is None:
        severity, misfit, curvature = ({f: _spread(a[f], valid) for f in parity.VALVE_HYPOTHESES}
                                       for a in (estimates.severity, mse, estimates.curvature))
        at_nominal, limited = own.mse.get(NOMINAL_VALVE), own.severity.get(PUMP_LIMITED)
        blamed, excess = (attributed_valve_fault(severity, misfit, curvature, valid, pool, with_excess=True,
                                                 nominal=None if at_nominal is None else _spread(at_nominal, valid),
                                                 limited=None if limited is None else _spread(limited, valid))
                          if "valve" in relations and valid.any() else (np.full(n, -1), None))
    if brake is None:
        brake = (brake_factors(own.severity["load"], pool) if "load" in relations
                 else np.ones(int(valid.sum())))
    ratio = own.severity.get(PUMP_LIMIT, np.full(int(valid.sum()), np.nan))
    if capacity is None:
        capacity = (np.zeros(ratio.size) if capacity_known or "valve" not in relations
                    else capacity_errors(own.severity["pump_leak"], ratio, _determines(own, "pump_leak"), pool))
    read = {}  # fault → index, low, high, determined of its own fit, per valid window
    pooled = {}  # valve hypothesis → its index at the pool's median severity (its wear so far), per valid window
    for fault in FAULTS:
        if RELATION_OF[fault] not in relations or not valid.any():
            continue
        s = own.severity[fault]
        se = severity_standard_error(mse[fault], own.curvature[fault], blocks)
        determined = own.curvature[fault] * DETERMINED_STEP**2 >= mse[fault]
        if fault in AT_LIMIT_PARTS and PUMP_LIMITED in own.severity:  # it trades with θ0's capacity there
            determined &= ~(own.severity[PUMP_LIMITED] >= COIL_AT_LIMIT)
        stack, q = np.stack([s, s - Z95 * se, s + Z95 * se]), np.zeros_like(s)
        if fault == "pump_leak":  # on θ0 with the capacity the machine's history gives; none yet: not determined
            q = np.asarray(capacity, dtype=np.float64)
            determined &= np.isfinite(q)
            q = np.nan_to_num(q)
            stack = corrected(stack, ratio, q)
        if fault in parity.VALVE_HYPOTHESES:  # and the index at the pool's median severity (its wear so far)
            med = pool_median(s, pool) if pool_severity is None else np.asarray(pool_severity[fault], dtype=float)
            stack = np.concatenate([stack, corrected(med[None], ratio, q) if fault == "pump_leak" else med[None]])
        v, lo, hi, *at_pool = unit_indices(fault, stack, nominal, np.ones_like(s) if fault == "load" else brake, q)
        read[fault] = (v, *widened(v, lo, hi), determined)
        if at_pool:
            pooled[fault] = at_pool[0]
    level = np.full(n, np.inf)  # the blamed part's index at its pool's median severity
    for fault, at_pool in pooled.items():
        level = np.where(blamed == parity.VALVE_HYPOTHESES.index(fault), _spread(at_pool, valid), level)
    contender, held = contenders(excess, level, held, relief_barely_seen, blamed)
    untold = contender.sum(axis=1) > 1
    for fault, (v, lo, hi, determined) in read.items():
        if fault in parity.VALVE_HYPOTHESES:
            j = parity.VALVE_HYPOTHESES.index(fault)
            mine = blamed[valid] == j
            # worn (by its own fit), but the pool cannot tell this part from another: no index, blamed or not
            not_told = untold[valid] & contender[valid, j] & (v >= UNTOLD_LEVEL)
            lo, hi = np.where(mine, lo, np.minimum(0.0, lo)), np.where(mine, hi, np.maximum(0.0, hi))
            v = np.where(mine, v, 0.0)
        else:
            mine, not_told = np.ones(v.size, dtype=bool), np.zeros(v.size, dtype=bool)
        unknown = mine & ~determined | not_told  # the part's own fit does not determine it: no index
        measured[fault][valid] = mine & ~unknown
        value[fault][valid], low[fault][valid], high[fault][valid] = (np.where(unknown, np.nan, x) for x in (v, lo, hi))
        provisional[fault][valid] = np.where(mine & determined & not_told, v, np.nan)
    pair = np.zeros(untold.shape, dtype=bool)
    if relief_barely_seen:  # exactly the look-alike pair untold: it shares one index (degradation_series)
        others = [j for j in range(len(parity.VALVE_HYPOTHESES)) if j not in LOOK_ALIKES]
        pair = untold & contender[:, list(LOOK_ALIKES)].all(axis=1) & ~contender[:, others].any(axis=1)
    shared = pair & np.isfinite(np.fmax(*(provisional[parity.VALVE_HYPOTHESES[j]] for j in LOOK_ALIKES)))
    shared_index = None
    if shared.any():  # one reading of the pair: the mean of both parts' own where determined (degradation_series)
        own_reads = np.stack([np.where(read[f][3], read[f][0], np.nan) for f in SHARED_PAIR])
        with np.errstate(invalid="ignore"):  # a window that determines neither: NaN (never a shared one)
            mean = np.nansum(own_reads, axis=0) / np.isfinite(own_reads).sum(axis=0)
        shared_index = np.where(shared, _spread(mean, valid), np.nan)
    leak = None
    if not capacity_known and LEAK in read:  # the capacity is the history's: a forecast re-reads on its latest
        has = measured[LEAK] | np.isfinite(provisional[LEAK])
        leak = LeakReading(nominal, *(np.where(has, _spread(x, valid), np.nan) for x in (
            own.severity[LEAK], np.nan_to_num(ratio, nan=0.0), brake, np.asarray(capacity, dtype=np.float64))))
    return Degradation(value, low, high, measured, provisional, valid, held, shared if shared.any() else None,
                       shared_index, leak)


def _load_away_from_standstill(estimates: ParityEstimates) -> ParityEstimates:
    """``estimates`` with the load's fit replaced by its fit away from standstill
    (:func:`~hydrowatch.condition.estimates.moving_load_fit`) where they carry it: the index does not depend on the
    brake's low-speed shape, which commissioning gives to ±25 %. A window with no block away from standstill has no
    load index (its curvature is 0: not determined)."""
    if MOVING_LOAD not in estimates.severity:
        return estimates
    return ParityEstimates(*({**part, "load": part[MOVING_LOAD]}
                             for part in (estimates.severity, estimates.mse, estimates.curvature)))


def _determines(estimates: ParityEstimates, fault: str) -> np.ndarray:
    """Whether each window's fit determines ``fault`` (:data:`DETERMINED_STEP`), shape (m,)."""
    return np.asarray(estimates.curvature[fault] * DETERMINED_STEP**2 >= estimates.mse[fault])


def _spread(x: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Values of the valid windows (m,) spread over all windows (n,), NaN elsewhere."""
    out = np.full(valid.size, np.nan)
    out[valid] = x
    return out


def features_degradation(features: ConditionFeatures, windows: np.ndarray, pool: int = ATTRIBUTION_WINDOWS,
                         estimated: tuple[np.ndarray, ParityEstimates | None] | None = None) -> Degradation:
    """:func:`window_degradation` of one machine's consecutive raw windows, shape (n, window, 4 or 5), on the unit
    that fitted (or was commissioned into) ``features``: its nominal parameters, sensors and oil coefficient.

    The estimates are those of :meth:`ConditionFeatures.evidence_and_estimates`; ``estimated`` (its valid-window mask
    and estimates) when the caller has them already, so that one fit serves the verdicts and the index."""
    valid, estimates = features.evidence_and_estimates(windows)[1:] if estimated is None else estimated
    if estimates is None or not valid.any():
        empty = {f: np.full(valid.size, np.nan) for f in FAULTS}
        return Degradation(empty, empty, empty, {f: np.zeros(valid.size, dtype=bool) for f in FAULTS})
    blocks = (features.window - 1) // parity.BLOCK
    return window_degradation(estimates, valid, features.nominal_, blocks, features.relations_, pool,
                              capacity_known=getattr(features, "capacity_known_", True),
                              relief_barely_seen=relief_barely_seen(getattr(features, "pump_at_limit_", None)))
