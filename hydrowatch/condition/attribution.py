"""Which valve-side part wears: the hypothesis whose fits over the machine's last windows share one severity trend
(issue 15; :mod:`hydrowatch.condition.degradation`'s "Which valve-side part").

The four valve-side faults (pump_leak, relief_spring, valve_coil, valve_leak) are separate one-parameter hypotheses
of one relation; window by window a look-alike often explains a worn part's windows as well or better, but a part
wears slowly: over a pool of consecutive valid windows the worn part's fits agree on one severity trend, while a
look-alike needs a severity that moves with the command (docs/degradation.md).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

# the module, not the package: its __init__ imports estimates, which imports this (tests/test_layers.py)
import hydrowatch.condition.parity as parity

ATTRIBUTION_WINDOWS = 60
"""Valid windows (300 s) whose valve-relation fits decide which valve-side part wears. Wear is slow against five
minutes; the verdicts' 12-window pool left a third of a duty cycle's windows of a valve_leak or relief_spring unit
blamed on a look-alike, 60 windows none on two of three tuning units (docs/degradation.md)."""
ATTRIBUTION_MARGIN = 3.0
"""Pool misfit (nats, over the pool's windows) by which the blamed valve-side part must beat the runner-up for the
pool to tell them apart. While a relief spring barely cracks (true index 0.1–0.25) it and the coil explain the duty
cycle equally: the blame flipped between them with gaps of about 1 (pool of 60 windows), so a third to all of such
windows of a worn relief spring blamed the coil (and of a worn coil, the relief), reading the right value on the
wrong part. Where the worn part lost its pool on the tuning units (seeds 7 and 2042, 6 units) the gap's median /
90th percentile was 0.5 / 1.5 on valve_coil paths, 0.4 / 1.3 on relief_spring, 0.2 / 0.8 on valve_leak and 0.8 /
2.3 on pump_leak (early wear); past true index 0.3 the own part won by more than 3 in 97–100 % of the windows. A
worn part blamed on a look-alike by more than the margin stays blamed (seed 2027, unit 4: a relief spring, 9 % of
its windows)."""

EARLY_MARGIN = 7.0
"""Pool misfit (nats) by which the blamed valve-side part must beat the runner-up while its wear is early (its index
at :func:`pool_median` below :data:`EARLY_LEVEL`). On tuning seeds 2086–2089 (32 units, 192 paths) the windows whose
pool told a wrong part reading above 0.15 told it by 3.0–6.2 (56 windows, 8 paths), those reading 0.1 or more by
3.1–7.6 (5–95 %), the right part by 7.5–292 (5–95 %). At 7, 1 of those 8 paths kept a wrong window (beyond the
alert, not early wear), every forecast the same; windows of a wearing relief spring or coil with a true index of
0.1–0.5 have an index less often (median path 41–54 % / 59–64 % instead of 55–79 % / 80–85 %). A flat margin of 6
lost three relief forecasts (docs/degradation.md, "Early wear is told apart only by a wider margin")."""

HELD_MARGIN = 7.0
"""Pool misfit (nats) by which another valve-side part must beat the held one (the part a pool last told apart
while worn, at :data:`EARLY_LEVEL` or more) to be told apart from it, at any level. A worn part's pool keeps the
same windows for 60 windows; a look-alike that overtakes it by 3–5 nats for a few windows beyond the alert read
the coil 1.33–1.36 on a relief spring blamed for the 200 windows before (tuning seeds 2089 unit 3 and 2093 unit 3)."""

BARELY_SEEN_LEVEL = 0.5
"""On a unit whose commissioning barely saw the relief, the index (blamed part, pool median) below which the pool
must tell it apart by :data:`BARELY_SEEN_MARGIN`: up to the warning, not :data:`EARLY_LEVEL`. There the relief
spring and the coil stay look-alikes past 0.25: on the 32 such units of seeds 3001–3008 the coil was told apart on 4
relief paths at 0.31–0.49 by 3–7 nats (up to 2.4 % of a path's windows, one false forecast); with 7 up to 0.5 none,
and 10 of 32 relief forecasts at the warning say "or valve_coil" (3 before; docs/degradation.md, "A relief barely
seen")."""
BARELY_SEEN_MARGIN = 10.0
"""Pool misfit (nats) by which the blamed valve-side part must beat the runner-up below :data:`BARELY_SEEN_LEVEL` on
a unit whose commissioning barely saw the relief: wider than :data:`EARLY_MARGIN` (7 until stop 61). On the stored
window fits of the 64 such units of seeds 3001–3018 (tuning since) the pools that told the coil apart on a wearing
relief below the warning did so by 7.0–8.9 nats (3017 unit 79 at 0.44, the coil read 0.50–0.53; 3018 unit 641 at
0.28, 0.32), the right part by 7–10 in 11 % of the windows that blamed it at 0.25–0.5. At 10: paths with another part
above 0.15 on 3017/3018's 16 units 3 → 1 (the one left pump_leak at the path's start), every forecast the same and
every index MAE within 0.001 on all 64 units and on the regular units 2100–2103; fewer indexed early windows of the
relief and the coil (median path 18 → 12 % and 27 → 23 % on 3017/3018), more forecasts naming both
(docs/degradation.md)."""
LOOK_ALIKE_MARGIN = 10.0
"""Pool misfit (nats) by which the relief spring and the coil (:data:`LOOK_ALIKES`) must beat each other to be told
apart while the blamed one's wear is early (below :data:`EARLY_LEVEL`), on every unit; any other runner-up:
:data:`EARLY_MARGIN`. On fresh regular unit 2119/0 (stop 63; its commissioning at the pump's limit in 27 % of its
samples, Kr identified at 0.84 ×) the coil beat a wearing relief by 7.0–8.3 nats at pool levels 0.12–0.17 and read
0.15–0.20 in 2.3 % of the relief path's windows. :data:`BARELY_SEEN_MARGIN`'s value, not one fitted to that unit. On
the stored fits of 16 regular units (seeds 2117–2120, tuning since): paths with another part above 0.15 1 → 0 of 96,
every forecast within 0.5 point but one (1.1 points), fewer early indexed windows of the coil (median path 53.5 →
45.5 %) and the relief (47.9 → 46.1 %; docs/degradation.md, "The look-alike pair in early wear")."""
EARLY_LEVEL = 0.25
"""Index (of the blamed valve-side part at its pool's median severity) below which the pool must tell it from the
runner-up by :data:`EARLY_MARGIN` rather than :data:`ATTRIBUTION_MARGIN`. A wear this early moves the valve relation
by about as much as θ0's own commissioning error does, and the misfit gap that error makes between look-alikes is no
evidence: on tuning seeds 2086–2089 every window that read a wrong part above 0.15 had the blamed part's pool below
0.25 but one, beyond the alert. The pool's median, not the window's own index: single windows whose fit spiked to
0.30–0.46 in a pool at 0.08 escaped a window-level rule (2088 unit 7)."""

LIMITED_SAY = 0.3
"""Say, in a pool's misfit, of a window's samples with θ0's pump at its limit (1 for the others; :func:`say_of`).
There the valve relation's residual is θ0's capacity error (commissioning's leakages compensate each other along its
ridges) as much as wear, and a look-alike explains it: on tuning seed 2081's unit 4 the coil at severity 0.05
halved those windows' MSE on a healthy machine, and took a wearing relief spring's pool from true index 0.06 to
0.29 (11.0 % of the path's windows read the coil above 0.15). Without a say (0) the relief and the coil were not
told apart until the relief's warning, and its forecast had no history ("too short"). Chosen offline on the stored
window fits of tuning seeds 2074 and 2081 (16 units, 96 paths; docs/degradation.md): paths with another part above
0.15 at 1 (before) 9, at 0.5 6, at 0.3 3, at 0.2 3 with one forecast 53 % late."""
TREND_DEGREE = 2
"""Degree of the severity trend a pool's windows must share (:func:`pool_misfit`): a parabola, so that wear whose
rate changes inside the pool's 300 s (accelerating, or stopping) costs the worn part little. With a straight line
(before stop 59) a relief spring whose wear stopped at 1.30 lost its pool to the coil by up to 17.7 nats, its
better free fits (Σ log MSE 8.3 nats below the coil's) outweighed by the kink's trend cost (68.7 against the
noisier coil's 42.6), and the coil read 1.28–1.31 (flagged unit 3007/19); with the parabola the coil beat it by
7.0 at most, within :data:`HELD_MARGIN`. On the stored window fits of 40 flagged units (3001–3010, where it was
found: tuning) paths with another part above 0.15 2 → 0 of 240; on 8 regular units (2098/2099) every figure within
a point; a steady worn part is told apart after 8 windows instead of 5 (docs/degradation.md, "A wear that stops
inside the pool")."""
NOMINAL_VALVE = "valve_nominal"
"""Key, in :class:`~hydrowatch.condition.estimates.ParityEstimates`' MSEs, of the valve relation's MSE with every
valve-side part at nominal (severity 0, the P̂L noise's share taken out as in the fits): the same model for all four
hypotheses, and what :func:`pool_misfit` bounds a window's cost by between nominal and its fit."""


def pool_misfit(severity: np.ndarray, mse: np.ndarray, curvature: np.ndarray,
                nominal: np.ndarray | None = None, say: np.ndarray | None = None, *,
                degree: int | None = None) -> np.ndarray:
    """Σ log MSE of one valve-side hypothesis over a pool of consecutive valid windows that share one severity trend.

    Each window's free fit gives MSE(s) ≈ MSE_min + c·(s − ŝ)² (:class:`~hydrowatch.condition.estimates.
    ParityEstimates`). A part wears slowly against the pool's 300 s, so the pool's windows should agree on one
    severity trend (a polynomial of :data:`TREND_DEGREE` in the window's place x, weighted least squares of the ŝ
    with weights c / MSE_min); the misfit is Σ log(MSE_min + c·(ŝ − trend)²). A look-alike hypothesis explains
    each window on its own, as well as the worn part or better, but only with a severity that moves with the
    command (docs/degradation.md).

    With ``nominal`` (each window's MSE at severity 0, :data:`NOMINAL_VALVE`), a window whose trend lies between 0
    and its fit costs at most that: a cost with one valley at ŝ is nowhere between nominal and ŝ above its value at
    nominal, while the parabola, whose c is measured at ŝ, is far above it where the cost is flat and then drops
    into a narrow valley (a relief that the model's pump at its limit keeps shut until its spring is weak enough to
    open it: docs/degradation.md, "Which valve-side part").

    Parameters
    ----------
    severity, mse, curvature : ndarray, shape (..., L)
        ŝ, MSE_min [(L/min)²] and c of L consecutive valid windows in time order (last axis).
    nominal : ndarray, shape (..., L), optional
        The windows' MSE at severity 0 [(L/min)²]; NaN or None: unbounded.
    say : ndarray, shape (..., L), optional
        Each window's say in [0, 1] (:func:`say_of`): its log cost and its weight in the trend are scaled by it
        (None: 1 for every window).
    degree : int, optional
        Degree of the pool's severity trend in the window's place (None: :data:`TREND_DEGREE`).

    Returns
    -------
    ndarray, shape (...,)
    """
    s, m, c = np.asarray(severity, dtype=np.float64), np.maximum(mse, 1e-300), np.maximum(curvature, 0.0)
    weight = np.ones_like(s) if say is None else np.nan_to_num(np.asarray(say, dtype=np.float64), nan=1.0)
    w = weight * c / m + 1e-12  # a window that does not determine the part hardly moves the trend
    trend = _trend(s, w, TREND_DEGREE if degree is None else degree)
    cost = m + c * (s - trend) ** 2
    if nominal is not None:
        between = (trend * s >= 0.0) & (np.abs(trend) <= np.abs(s))
        bound = np.maximum(np.nan_to_num(np.asarray(nominal, dtype=np.float64), nan=np.inf), m)
        cost = np.where(between, np.minimum(cost, bound), cost)
    return (weight * np.log(cost)).sum(axis=-1)


def _trend(severity: np.ndarray, weight: np.ndarray, degree: int) -> np.ndarray:
    """Weighted least-squares polynomial of ``degree`` (at most L − 1) through each pool's severities in the
    window's place, evaluated there, shape (..., L)."""
    n = severity.shape[-1]
    u = (np.arange(n, dtype=np.float64) - (n - 1) / 2.0) / max((n - 1) / 2.0, 1.0)  # place in [-1, 1]
    basis = u[:, None] ** np.arange(min(degree, n - 1) + 1)  # (L, k)
    weight = weight / np.max(weight, axis=-1, keepdims=True)  # weights 1e-12 to 1e300 apart: scaled, and a ridge
    normal = np.einsum("...l,lk,lj->...kj", weight, basis, basis) + 1e-12 * np.eye(basis.shape[1])
    moment = np.einsum("...l,lk,...l->...k", weight, basis, severity)
    return np.einsum("...k,lk->...l", np.linalg.solve(normal, moment[..., None])[..., 0], basis)


def pool_median(severity: np.ndarray, pool: int = ATTRIBUTION_WINDOWS) -> np.ndarray:
    """Median of each valid window's severity and the ``pool − 1`` valid windows before it (fewer at the start),
    shape (m,): a hypothesis's wear so far as its pool sees it, robust to one window's spike."""
    padded = np.concatenate([np.full(pool - 1, np.nan), np.asarray(severity, dtype=np.float64)])  # the first pools
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN pool: NaN
        return np.asarray(np.nanmedian(sliding_window_view(padded, pool), axis=-1))


def contenders(excess: np.ndarray | None, level: np.ndarray, held: int = -1,
               relief_barely_seen: bool = False, blamed: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Which valve-side parts each window's pool cannot rule out, shape (n, 4), and the part held after the last
    window.

    A contender's pool misfit is within the margin of the blamed part's (``excess`` below it; the blamed part itself
    included). The margin is :data:`EARLY_MARGIN` where the blamed part's ``level`` (its index at
    :func:`pool_median`, shape (n,); inf or NaN: none) is below :data:`EARLY_LEVEL`, else :data:`ATTRIBUTION_MARGIN`;
    and :data:`HELD_MARGIN` for the held part: the one the last pool told apart (the only contender) at a level of
    :data:`EARLY_LEVEL` or more, before this window (``held`` before the first, −1: none). The relief spring and the
    coil (:data:`LOOK_ALIKES`) need :data:`LOOK_ALIKE_MARGIN` from each other in early wear. Windows in time order; no
    ``excess``: no contenders (every window told apart) and ``held`` unchanged.

    With ``relief_barely_seen`` (the unit's commissioning had the pump at its limit in
    :data:`~hydrowatch.condition.unit_checks.RELIEF_SHUT_SHARE` of its samples or more: its relief gain Kr is
    uncertain) the relief spring and the coil are each other's contenders while the blamed one of them is below
    :data:`EARLY_LEVEL`, whatever the excess: the relief hypothesis, fitted with a wrong Kr, explains the relief's own
    early wear worse than the coil does (docs/degradation.md, "A relief barely seen"); and the margin is
    :data:`BARELY_SEEN_MARGIN` up to :data:`BARELY_SEEN_LEVEL`, below which a held part of the pair stays a contender
    of the other whatever the excess: strong evidence for one and then for the other is no evidence (flagged unit
    3029/36: the relief told apart by 10–11 nats at 0.29, then the coil by 10–18 at 0.43–0.47; docs/degradation.md,
    "The look-alike pair in early wear"); ``blamed`` (shape (n,), −1: invalid) is the part with no excess, found from
    ``excess`` when not given.
    """
    lv = np.asarray(level, dtype=np.float64)
    if excess is None:
        return np.zeros((lv.size, len(parity.VALVE_HYPOTHESES)), dtype=bool), held
    with np.errstate(invalid="ignore"):
        worn = lv >= EARLY_LEVEL
    margin = np.where(worn, ATTRIBUTION_MARGIN, EARLY_MARGIN)
    if relief_barely_seen:
        with np.errstate(invalid="ignore"):
            margin = np.where(lv >= BARELY_SEEN_LEVEL, margin, BARELY_SEEN_MARGIN)
    near = np.asarray(excess) < margin[:, None]
    if blamed is None:
        blamed = np.where(np.isfinite(excess).all(axis=1), np.argmin(excess, axis=1), -1)
    for a, b in (LOOK_ALIKES, LOOK_ALIKES[::-1]):
        early = ~worn & (blamed == a)
        near[early, b] |= np.asarray(excess)[early, b] < LOOK_ALIKE_MARGIN
        if relief_barely_seen:
            near[early, b] = True
    with np.errstate(invalid="ignore"):
        below_warning = lv < BARELY_SEEN_LEVEL
    for i in range(near.shape[0]):  # sequential: each window's held part is the last one told apart before it
        if held >= 0 and excess[i, held] < HELD_MARGIN:
            near[i, held] = True
        if (relief_barely_seen and below_warning[i] and held in LOOK_ALIKES and blamed[i] in LOOK_ALIKES
                and blamed[i] != held):  # the look-alike of the held part: not told from it before the warning
            near[i, held] = True
        if worn[i] and near[i].sum() == 1:
            held = int(np.argmax(near[i]))
    return near, held


LOOK_ALIKES = (parity.VALVE_HYPOTHESES.index("relief_spring"), parity.VALVE_HYPOTHESES.index("valve_coil"))
"""The pair of valve-side parts a unit whose relief was barely seen cannot tell apart in early wear
(:func:`contenders`)."""


def say_of(limited: np.ndarray) -> np.ndarray:
    """Each window's say in the pool (:func:`pool_misfit`), shape as ``limited`` (its share of samples with θ0's
    pump at its limit, :data:`~hydrowatch.condition.capacity.PUMP_LIMITED`; NaN: none): a sample at the limit
    counts :data:`LIMITED_SAY`, the rest 1."""
    share = np.clip(np.nan_to_num(np.asarray(limited, dtype=np.float64), nan=0.0), 0.0, 1.0)
    return 1.0 - (1.0 - LIMITED_SAY) * share


def attributed_valve_fault(severity: Mapping[str, np.ndarray], mse: Mapping[str, np.ndarray],
                           curvature: Mapping[str, np.ndarray], valid: np.ndarray,
                           pool: int = ATTRIBUTION_WINDOWS, with_excess: bool = False,
                           nominal: np.ndarray | None = None, limited: np.ndarray | None = None) -> Any:
    """Index into :data:`~hydrowatch.condition.parity.VALVE_HYPOTHESES` of the valve-side part each window blames.

    The hypothesis with the smallest :func:`pool_misfit` over the window and the ``pool − 1`` valid windows before
    it (one machine's consecutive windows; fewer at the start); −1 for invalid windows.

    Parameters
    ----------
    severity, mse, curvature : mapping of fault to ndarray, shape (n,)
        Each valve hypothesis's free fit per window: ŝ, minimum MSE [(L/min)²], c (NaN where invalid).
    valid : ndarray of bool, shape (n,)
    pool : int, default :data:`ATTRIBUTION_WINDOWS`
    with_excess : bool, default False
        Also return each hypothesis's pool misfit minus the best's, shape (n, 4) (0 for the blamed part, inf
        where invalid): ``(blamed, excess)``; the runner-up's excess is what :data:`ATTRIBUTION_MARGIN` (and
        :data:`EARLY_MARGIN` while the wear is early) tests.
    nominal : ndarray, shape (n,), optional
        Each window's valve MSE at nominal (:data:`NOMINAL_VALVE`; :func:`pool_misfit`'s bound).
    limited : ndarray, shape (n,), optional
        Each window's share of samples with θ0's pump at its limit (:data:`PUMP_LIMITED`; :func:`say_of`).
    """
    m = int(valid.sum())
    misfit = np.empty((m, len(parity.VALVE_HYPOTHESES)))
    bound = np.full(m, np.nan) if nominal is None else np.asarray(nominal, dtype=np.float64)[valid]
    say = say_of(np.full(m, np.nan) if limited is None else np.asarray(limited, dtype=np.float64)[valid])
    for j, fault in enumerate(parity.VALVE_HYPOTHESES):
        fit = [np.asarray(a[fault], dtype=np.float64)[valid] for a in (severity, mse, curvature)] + [bound, say]
        for k in range(min(pool - 1, m)):  # the first windows: the pool so far
            misfit[k, j] = pool_misfit(*(a[:k + 1] for a in fit))
        if m >= pool:
            misfit[pool - 1:, j] = pool_misfit(*(sliding_window_view(a, pool) for a in fit))
    out, excess = np.full(valid.size, -1, dtype=np.int64), np.full((valid.size, misfit.shape[1]), np.inf)
    out[valid] = np.argmin(misfit, axis=1)
    excess[valid] = misfit - misfit.min(axis=1, keepdims=True)
    return (out, excess) if with_excess else out


def confirmed(measured: np.ndarray, provisional: np.ndarray, pool: int = ATTRIBUTION_WINDOWS) -> np.ndarray:
    """One part's history for a forecast, shape (n,): its own estimates (``measured``), and its provisional values
    where a pool within ``pool`` valid windows later told the part apart (a finite ``measured`` in the next
    ``pool − 1`` windows): that pool held the provisional window's fit and chose this part by the margin.

    A part blamed while the pool could not yet tell it from a look-alike (:data:`ATTRIBUTION_MARGIN`) has no index
    there (``score --json`` leaves it out); but a fast wear spends minutes so (a coil wearing from new to its warning
    in 12.5 minutes: 60 windows from true index 0.1 untold even on the unit's true parameters), and a forecast from
    the told windows alone came too late (docs/degradation.md, "The forecast").

    Parameters
    ----------
    measured, provisional : ndarray, shape (n,)
        Per valid window, in order: the part's own index (NaN where it has none) and its index where it was blamed
        but not told apart (NaN elsewhere).
    pool : int, default :data:`ATTRIBUTION_WINDOWS`
    """
    out = np.array(measured, dtype=np.float64, copy=True)
    p = np.asarray(provisional, dtype=np.float64)
    has = np.flatnonzero(np.isfinite(out))
    waiting = np.flatnonzero(np.isfinite(p))
    if has.size == 0 or waiting.size == 0:
        return out
    following = np.searchsorted(has, waiting, side="right")  # the next told window after each provisional one
    ok = following < has.size
    ok[ok] = has[following[ok]] - waiting[ok] < pool
    out[waiting[ok]] = p[waiting[ok]]
    return out
