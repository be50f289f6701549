"""Evidence carried across a machine's consecutive windows: the parity scores of the last n windows, pooled.

One window cannot tell look-alike valve faults apart in a hold near 2 V (their severity levels
are defined by the same speed drop there), and an unseen valve-side fault can look like a known
one in a hold. Over a machine's recent windows the command visits other levels, where they do
differ. The pooled evidence of the last ``n_windows`` valid windows of one machine is

- for the decision, the mean of log F[r, k] (the geometric mean of the ratios): the
  log-likelihood ratios of independent windows add, so the state that explains *all* of them
  best wins (a generalised likelihood ratio over the windows, cf. study Eq. 5.3's sum over samples);
- the level-box half of the rows (a soft prior that the machine sits at its state's trained
  severity, :class:`~hydrowatch.condition.model.ParityRule`) is a prior, not evidence: it enters
  the pooled score once, not once per window, i.e. its pooled value is exp(mean_i log F_level,i / c)
  for c pooled windows. Averaged per window like the band half it would assert n times over that
  a machine's severity *is* the trained level, and machines whose severity lies elsewhere in
  the band lost to a look-alike whose trained level happened to be nearer (13 states, 104
  machines with severities spread in their bands, duty cycle: 90.5 % pooled over 12 windows;
  counted once: 95.9 %, all errors in each machine's first 4 windows). With a sensor missing
  the level half is also evidence (each state's named level fills the missing channel) and is
  averaged like the band half (:attr:`EvidenceLayout.prior_once`);
- for the open-set rule, the arithmetic mean of F[r, k]: a known state must explain every
  window, and one window that no known state explains (F ≫ 1 for all) is enough to reject
  (a pool none of whose windows read ``unknown`` alone is rejected only well beyond the limit:
  :data:`~hydrowatch.condition.model.CLEAR_FACTOR`, :func:`trailing_count`);
- in both, one machine has one severity: with ŝ_i window i's free estimate of state k's own
  fault and w_i its curvature d(MSE)/d(s²) over the relation's free MSE, the windows share
  s̄ = clip(Σ w_i·ŝ_i / Σ w_i, k's box) (the minimiser of the quadratic misfit model
  Σ w_i·(s − ŝ_i)² over the box), and window i's ratio on that relation gains
  w_i·((s̃_i − ŝ_i)² − (clip(ŝ_i, box) − ŝ_i)²) ≥ 0 over holding it in the box alone, s̃_i the
  point of [s̄ − δ, s̄ + δ] ∩ box nearest ŝ_i, δ = 0 for the decision and
  :data:`SEVERITY_TOLERANCE`·|s̄| for the open-set rule. A look-alike
  fault is explained by k in each window alone, but with a severity that moves with the
  operating point; k's own fault keeps one severity up to noise (≈ 1/124 per window) and the
  relations' model error on the unit (δ: without it, on units whose parameters are not the
  defaults, pump_leak machines on duty cycles read ``unknown`` pooled though right per window —
  development population, seed 7, 6 units: worst unit 74.6 % pooled over 12 windows vs 100 %
  per window; with δ = 0.15 100 % both; a commissioned unit needed 0.25, :data:`SEVERITY_TOLERANCE`).
  The gain is capped where the valve relation has another explanation: that relation is the best of the four
  valve-side faults each held in k's box, so window i's pooled ratio is at most the larger of its own ratio and
  what the *other* valve-side faults in k's box explain alone (the last 2 · n_states columns of the rows). A
  window that does not load the valve side (a low hold) estimates ŝ_i far off with a curvature the quadratic
  model extrapolates wrongly; uncapped, it charged k's common severity up to 20 × what the relation itself reads
  there (issue 11, tuning seed 2066, docs/unseen-units.md: a pump leak alert read warning pooled in 6 windows
  that each read alert alone).

A pooled fault must also be *seen* at more than one operating point: it replaces a window's own verdict only where
windows at :data:`SUPPORT_POINTS` distinct operating points of the pool (the windows of one hold are one point,
:func:`operating_points`) each prefer it to ``healthy`` alone by the decision's margin; else the window's own verdict
stands. The windows of one hold share the relations' model error there, so n of them are one piece of evidence.
For the same reason the pooled open-set rule judges only pools that span :data:`SUPPORT_POINTS` operating points
(:func:`trailing_spans`); over one hold the window's own open-set verdict stands (issue 11, seed 2069: a pump leak
alert whose 3.2 V hold misfit by 4–5 in two of its first three windows, each within the rule alone, read ``unknown``
pooled at the clear limit; another's one borderline window was carried to the next window of the same hold).

The price is delay: after a change of state the verdict follows when the new state's windows
outweigh the old ones (about n/2 windows). Invalid windows (NaN rows) are skipped, so a gap does
not flush the history. :class:`EvidenceSmoother` is the streaming form (river style, one machine);
:func:`trailing_evidence` the batch form for the windows of one recording.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrowatch.condition.ring import Ring
from hydrowatch.errors import DataError, ParameterError

SEVERITY_TOLERANCE = 0.25
"""How far (a fraction of the common severity) a window's own-fault severity may sit from the pool's before it
costs the open-set rule: the relations' model error on a unit moves a fault's estimate with the operating point
(measured: pump_leak on duty cycles, units of ±20 % parameters); a look-alike's moves further. 0.15 until
2026-11-26: on a unit commissioned from a duty cycle that never drives the pump to its limit (its capacity left to
the trained unit's, bounded by what the recording drew) a pump_leak_warning's estimate moved 0.45–0.66 with the
command; no window alone was beyond the open-set rule, the pooled excess reached 10 and the pool read ``unknown`` in
15 of 40 windows (tuning population seed 2033, 7 states, worst unit 94.6 % pooled against 98.6 per window). At 0.25:
100 %, each unit's own models unchanged on every condition, the commissioned open set 0.5–2 points lower for the
median unit (docs/unseen-units.md)."""


HOLD_SPAN = 0.05
"""A window whose command moves less than this (V, max − min) is a hold (:func:`operating_points`); two holds whose
levels lie within it of each other (chained) are one operating point. Measured on the simulator's duty cycles (20 of
200 s, 0.5–3.5 V): 421 of 800 windows of 5 s move less than 0.05 V (most not at all, a few by the sliver of a ramp's
end), 40 by 0.05–0.1 V; filtered noise moves by 2–4 V in every window (no holds, the rule never acts)."""

SUPPORT_POINTS = 2
"""A pooled fault replaces a window's own verdict only when windows at this many distinct operating points of the
pool each prefer it to ``healthy`` alone (:func:`supported_states`; 1: no such rule). The windows of one hold share
the relations' model error at that point (the unit's parameters, its commissioning): misfit alike, they are one
piece of evidence, not n, yet the pool's mean log ratio counts them n times and carries a fault over the windows
that did not load the part. Measured (issue 11, tuning seeds 2059, 2060; docs/unseen-units.md): a commissioned
13-state healthy unit whose 3.49 V hold at the pump's limit leaned relief_spring_warning in 4 windows (p 0.19–0.36
alone) read relief_spring_alert pooled in 15 of 40 windows (75.0 %, per window 90 %). With 2 (pool 12, worst unit,
20 units per seed): tuning seed 2060 healthy 75.0 → 93.3 (commissioned) and 93.3 → 99.4 (own models); fresh seed 2061
healthy 93.3 → 100 (own models); fresh 2062 had no such unit. Cost: worst units' faults 0.2–1.8 points, never below
their per-window figure; no median moved by more than 0.2 points (docs/unseen-units.md)."""


STATE_COLUMNS = 4
"""Values per state after the ratios in an evidence row (``ConditionFeatures.transform_evidence``): the free estimate
of its own fault's severity, that estimate's weight, and its valve relation as the other valve-side faults in its band
and in its level box explain it."""


def operating_points(windows: np.ndarray) -> np.ndarray:
    """Each raw window's operating point for :func:`supported_states`, shape (n,): the command's mean [V] in a hold
    (it moves less than :data:`HOLD_SPAN`), NaN in a window that moves it (a point of its own).

    ``windows`` (n, window, ≥ 1), the command in column 0 (:data:`hydrowatch.condition.layout.CHANNELS`).
    """
    w = np.asarray(windows, dtype=np.float64)
    if w.ndim != 3 or w.shape[2] < 1:
        raise DataError(f"windows must have shape (n_windows, window, channels), the command first. Got {w.shape}.")
    command = w[:, :, 0]
    held = np.ptp(command, axis=1) < HOLD_SPAN
    return np.where(held, command.mean(axis=1), np.nan)


def distinct_points(points: np.ndarray) -> int:
    """How many operating points ``points`` (m,) (:func:`operating_points`) span: each NaN (a moving window) one, the
    holds one per group of levels within :data:`HOLD_SPAN` of each other."""
    p = np.asarray(points, dtype=np.float64).reshape(-1)
    held = np.sort(p[np.isfinite(p)])
    return int(np.isnan(p).sum()) + (0 if held.size == 0 else 1 + int(np.sum(np.diff(held) > HOLD_SPAN)))


def supported_states(leads: np.ndarray, points: np.ndarray, needed: int = SUPPORT_POINTS) -> np.ndarray:
    """Whether windows at ``needed`` (:data:`SUPPORT_POINTS`) distinct operating points prefer each state, shape
    (n_states,).

    ``leads`` (m, n_states) bool: whether each pooled window alone prefers the state to ``healthy`` by the decision's
    margin (:meth:`~hydrowatch.condition.model.ConditionModel.alone_leads`); ``points`` (m,) their
    :func:`operating_points`.
    """
    lead = np.asarray(leads, dtype=bool)
    p = np.asarray(points, dtype=np.float64).reshape(-1)
    if lead.ndim != 2 or lead.shape[0] != p.size:
        raise DataError(f"leads must have one row per point. Got leads {lead.shape} and {p.size} points.")
    if needed <= 1:
        return np.ones(lead.shape[1], dtype=bool)
    return np.array([distinct_points(p[lead[:, k]]) >= needed for k in range(lead.shape[1])], dtype=bool)


def trailing_support(leads: np.ndarray, points: np.ndarray, features: np.ndarray, n_windows: int,
                     needed: int = SUPPORT_POINTS) -> np.ndarray:
    """:func:`supported_states` over each row's trailing ``n_windows`` valid windows (the rows :func:`trailing_evidence`
    pools), shape (n, n_states); invalid rows all False."""
    n = _check_n(n_windows)
    f = np.asarray(features, dtype=np.float64)
    lead = np.asarray(leads, dtype=bool)
    p = np.asarray(points, dtype=np.float64).reshape(-1)
    if f.ndim != 2 or lead.ndim != 2 or lead.shape[0] != f.shape[0] or p.size != f.shape[0]:
        raise DataError(f"leads and points must have one row per row of features {f.shape}. Got {lead.shape} and "
                        f"{p.shape}.")
    out = np.zeros(lead.shape, dtype=bool)
    valid = np.flatnonzero(np.all(np.isfinite(f), axis=1))
    for pos, i in enumerate(valid):
        pool = valid[max(0, pos - n + 1):pos + 1]
        out[i] = supported_states(lead[pool], p[pool], needed)
    return out


def trailing_spans(points: np.ndarray, features: np.ndarray, n_windows: int,
                   needed: int = SUPPORT_POINTS) -> np.ndarray:
    """Whether each row's trailing ``n_windows`` valid windows span ``needed`` distinct operating points, shape (n,)
    (invalid rows False): where they do not, the pool's open-set evidence is one hold's, which the window alone has
    judged (:meth:`~hydrowatch.condition.model.ConditionModel.judge_pooled`)."""
    f = np.asarray(features, dtype=np.float64)
    every = np.ones((f.shape[0] if f.ndim == 2 else 0, 1), dtype=bool)
    return trailing_support(every, points, f, n_windows, needed)[:, 0]


def _check_n(n_windows: int) -> int:
    if int(n_windows) != n_windows or n_windows < 1:
        raise ParameterError(f"n_windows must be an integer >= 1. Got {n_windows!r}; 1 means no smoothing.")
    return int(n_windows)


@dataclass(frozen=True)
class EvidenceLayout:
    """Where each state's own fault sits in ``ConditionFeatures.transform_evidence`` rows.

    Attributes
    ----------
    columns : ndarray of int, shape (n_states,)
        Column of the state's own-fault relation in the band half of the ratios (−1: healthy, or
        a relation the sensors cannot test); the level half is the same plus its width.
    bounds : ndarray, shape (2, n_states, 2)
        (low, high) severity of the state's own fault in its band box [0] and level box [1].
    """

    columns: np.ndarray
    bounds: np.ndarray
    prior_once: bool = True
    """Whether the level half is a prior counted once per pool (module docstring); False when a sensor is
    missing: each state's named level then also fills the missing channel, so its level ratios are evidence
    of every window and are averaged like the band half."""

    def check(self, width: int) -> int:
        """Number of ratio columns in rows of ``width`` values; raises if the rows do not fit."""
        k = self.columns.size
        d = width - STATE_COLUMNS * k
        if self.bounds.shape != (2, k, 2) or d <= 0 or d % 2 or np.any(self.columns >= d // 2):
            raise DataError(f"features must be transform_evidence rows (2 · n_features + {STATE_COLUMNS} · {k} values) "
                            f"for this layout. Got {width} values; pass layout=None for plain ratios.")
        return d


def _pool(rows: np.ndarray, layout: EvidenceLayout | None) -> tuple[np.ndarray, np.ndarray]:
    """(geometric mean, arithmetic mean) over axis 0 of the ratios (clipped at 1), with the common-severity term.

    With a layout the geometric mean's level half counts the level prior once (module docstring).
    """
    if layout is None:
        ratios = np.maximum(rows, 1.0)
    else:
        d = layout.check(rows.shape[1])
        k = layout.columns.size
        plain = np.maximum(rows[:, :d], 1.0)
        ratios, tolerant = plain.copy(), plain.copy()
        free = rows[:, d:d + k]
        weight = rows[:, d + k:d + 2 * k]
        centre = np.sum(weight * free, axis=0) / np.maximum(weight.sum(axis=0), 1e-300)
        own = layout.columns >= 0
        for half in (0, 1):
            lo, hi = layout.bounds[half, :, 0], layout.bounds[half, :, 1]
            common = np.clip(centre, lo, hi)  # the minimiser of Σ w·(s − ŝ)² over the box
            alone = np.clip(free, lo, hi)
            for out, tolerance in ((ratios, 0.0), (tolerant, SEVERITY_TOLERANCE)):
                spread = tolerance * np.abs(common)
                near = np.clip(free, np.maximum(common - spread, lo), np.minimum(common + spread, hi))
                extra = weight * ((near - free) ** 2 - (alone - free) ** 2)
                column = half * (d // 2) + layout.columns[own]
                # no dearer than the other valve-side faults in the state's box explain the window without its own
                ceiling = np.maximum(out[:, column], rows[:, d + (2 + half) * k:d + (3 + half) * k][:, own])
                out[:, column] = np.minimum(out[:, column] + extra[:, own], ceiling)
        if layout.prior_once:
            log_mean = np.mean(np.log(ratios), axis=0)
            log_mean[d // 2:] /= rows.shape[0]  # the level prior once over the pool, not once per window
            return np.exp(log_mean), np.mean(tolerant, axis=0)
        return np.exp(np.mean(np.log(ratios), axis=0)), np.mean(tolerant, axis=0)
    return np.exp(np.mean(np.log(ratios), axis=0)), np.mean(ratios, axis=0)


def trailing_evidence(features: np.ndarray, n_windows: int,
                      layout: EvidenceLayout | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pooled scores of each window with the valid windows before it (one machine, windows in time order).

    Parameters
    ----------
    features : ndarray, shape (n, n_features)
        Parity ratios F ≥ 1 per window (``ConditionFeatures.transform_with_levels``); NaN rows are
        invalid windows.
    n_windows : int
        Valid windows pooled, the current one included (1: the window alone).
    layout : EvidenceLayout, optional
        ``ConditionFeatures.evidence_layout()`` when ``features`` are ``transform_evidence`` rows:
        the pooled windows then share one severity of each state's own fault (module docstring).

    Returns
    -------
    (ndarray, ndarray), each shape (n, n_ratios)
        Geometric and arithmetic mean of the ratios over the trailing ``n_windows`` valid windows
        (with ``layout``, the geometric mean's level half carries the level prior once: the mean
        log ratio over the c pooled windows divided by c); invalid rows stay NaN.
    """
    n = _check_n(n_windows)
    f = np.asarray(features, dtype=np.float64)
    if f.ndim != 2:
        raise DataError(f"features must have shape (n_windows, n_features). Got {f.shape}.")
    width = f.shape[1] if layout is None else layout.check(f.shape[1])
    geometric = np.full((f.shape[0], width), np.nan)
    arithmetic = np.full((f.shape[0], width), np.nan)
    valid = np.flatnonzero(np.all(np.isfinite(f), axis=1))
    for pos, i in enumerate(valid):
        geometric[i], arithmetic[i] = _pool(f[valid[max(0, pos - n + 1):pos + 1]], layout)
    return geometric, arithmetic


def pooled_windows(features: np.ndarray, n_windows: int) -> np.ndarray:
    """How many valid windows each row of :func:`trailing_evidence` pools, shape (n,) (0 for an invalid row)."""
    n = _check_n(n_windows)
    valid = np.all(np.isfinite(np.asarray(features, dtype=np.float64)), axis=1)
    return np.where(valid, np.minimum(np.cumsum(valid), n), 0)


def trailing_count(flags: np.ndarray, features: np.ndarray, n_windows: int) -> np.ndarray:
    """How many of each row's trailing ``n_windows`` valid windows (the rows :func:`trailing_evidence` pools) have
    ``flags`` set, shape (n,) (0 for an invalid row).

    ``flags`` (n,) per window, e.g. whether the window alone read ``unknown``
    (:meth:`~hydrowatch.condition.model.ConditionModel.alone_unknown`); ``features`` the rows, NaN rows invalid.
    """
    n = _check_n(n_windows)
    f = np.asarray(features, dtype=np.float64)
    flag = np.asarray(flags, dtype=bool).reshape(-1)
    if f.ndim != 2 or flag.shape != (f.shape[0],):
        raise DataError(f"flags must have one value per row of features {f.shape}. Got shape {flag.shape}.")
    valid = np.flatnonzero(np.all(np.isfinite(f), axis=1))
    total = np.concatenate([[0], np.cumsum(flag[valid])])
    pos = np.arange(1, valid.size + 1)
    out = np.zeros(f.shape[0], dtype=np.int64)
    out[valid] = total[pos] - total[np.maximum(pos - n, 0)]
    return out


class EvidenceSmoother:
    """The pooled parity scores of one machine's last ``n_windows`` valid windows (river style).

    Parameters
    ----------
    n_windows : int, default 6
        Valid windows pooled (1: no smoothing). 6 windows (30 s of 5 s windows) span several
        levels of a typical duty cycle.
    layout : EvidenceLayout, optional
        As in :func:`trailing_evidence`.
    """

    def __init__(self, *, n_windows: int = 6, layout: EvidenceLayout | None = None) -> None:
        self.n_windows = _check_n(n_windows)
        self.layout = layout
        self._ring: Ring | None = None
        """The pooled rows (:class:`~hydrowatch.condition.ring.Ring`), made at the first valid row."""

    def update(self, features: np.ndarray) -> None:
        """Add one window's ratios, shape (n_features,); an invalid (non-finite) row is skipped. Returns nothing."""
        row = np.asarray(features, dtype=np.float64).reshape(-1)
        if self._ring is not None and row.shape != self._ring.row_shape:
            raise DataError(f"features must have {self._ring.row_shape[0]} values per window. Got {row.size}.")
        if np.all(np.isfinite(row)):
            if self._ring is None:
                self._ring = Ring(self.n_windows, row.shape)
            self._ring.add(row)

    def get(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(geometric mean, arithmetic mean) of the pooled windows, each (n_features,), or None before any."""
        if self._ring is None or not len(self._ring):
            return None
        return _pool(self._ring.rows(), self.layout)

    def latest(self) -> np.ndarray | None:
        """The last valid window's row as given to :meth:`update` (a copy), or None before any."""
        return self._ring.latest() if self._ring is not None and len(self._ring) else None

    def __len__(self) -> int:
        return 0 if self._ring is None else len(self._ring)
