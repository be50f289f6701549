"""When will a part reach the alert: a trend of its degradation index over its own history (issue 15).

Input: one component's index per window (:mod:`hydrowatch.condition.degradation`; 0 as commissioned, 1.0 alert)
with the windows' times. Not specific to the parity method: any index series on that scale works.

1. **Clean.** Windows without an index (``invalid``, ``unknown``, a relation the sensors cannot test: NaN) are left
   out. The time axis is the machine's *operating* time (:func:`~.forecast_segment.operating_time`): a backward
   clock jump, or a forward one longer than ``max_gap_s``, counts as one window hop, since wear advances while the
   machine runs and a clock that jumps says nothing about how long it ran; shorter gaps count as they are.
2. **Reset.** A part replaced shows as the index falling back near 0. The last point where the median of the next
   :data:`~.forecast_segment.RESET_AFTER` indices is below ``RESET_NEAR_ZERO`` and at least ``RESET_DROP`` below
   the median of the previous ``RESET_BEFORE``, and the medians of the ``RESET_SETTLED`` windows on either side say
   the same, starts a new trend (:func:`~.forecast_segment.reset_start`); nothing before it is used.
3. **Robust points.** The segment is cut into at most :data:`BINS` bins of consecutive windows (and a bin again where
   it spans a gap in the history, :data:`GAP_BINS`), each reduced to its mean time and *median* index, so isolated
   outliers do not move the fit.
4. **Trend.** Weighted least squares of I(t) = α + β·(e^{γ·(max(t, h) − t_now)} − 1)/γ over a grid of growth rates γ
   (γ = 0 is the straight line α + β·(max(t, h) − t_now); γ·span in :data:`GROWTH_GRID`) and onsets h
   (:data:`ONSETS`: the trend may be flat before the part starts wearing); the candidate with the smallest Bayesian
   information criterion wins (a growth rate and an onset cost one parameter each). α is the level now, β the rate
   now. Linear wear, exponential (accelerating) wear, and either starting after a quiet stretch are members of
   the family; slowing wear is not (:data:`GROWTH_GRID`). The bins' weights are Tukey's biweight of their
   residuals, refitted :data:`ROBUST_ITERATIONS` times (:func:`_robust_fit`): a run of outlier windows as long as a
   bin, which its median does not reject, weighs 0.
5. **Alert time and interval.** Every candidate is solved for I = 1 after the last window with an index, and the
   operating time from there to the last window given (the machine's now) is taken off; the forecast is the
   median of these crossings, each weighted by its posterior weight e^{−ΔBIC/2} (:func:`_averaged_crossing`), not
   the crossing of the single best candidate: where a straight line with an onset and an accelerating curve
   explain a noisy index equally (ΔBIC 0.5 on an accelerating pump leak of seed 2042), picking one forecast the
   alert 140 % late. The 95 % interval comes from a moving-block bootstrap of the bin residuals, each with its
   weight (:data:`BOOTSTRAP` resamples, blocks keep the residuals' correlation), each resample refitted with the
   same model selection and solved for an alert level drawn with the index's systematic error
   (:data:`ALERT_SD`): the index's own scale is known to a few percent only; it is widened to the weighted 2.5 %
   and 97.5 % crossings of the candidates, so that it spans the models the history cannot tell apart.
6. **When not to forecast** (``alert_in_s`` None with a ``reason``): fewer than :data:`MIN_POINTS` windows or less
   than ``min_span_s`` of operating time since the reset ("too short"); a fitted rise over the segment below
   :data:`MIN_RISE` (decided from the fit, before the bootstrap: no interval, ``ci95`` (None, None); the
   healthy parts of most machines cost a fit, not 200), a rate whose 95 % interval reaches 0, or a crossing further
   away than :data:`HORIZON_FACTOR` × the history it rests on ("too flat").
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from hydrowatch.condition.degradation import SYSTEMATIC
from hydrowatch.condition.degradation_series import Degradation
from hydrowatch.condition.forecast_segment import operating_time, reset_start
from hydrowatch.errors import DataError

ALERT = 1.0
"""Index at the alert level."""
BINS = 60
"""Most bins the segment is reduced to."""
GAP_BINS = 4.0
"""A bin is cut where two of its consecutive windows lie further apart than this many bins' share of the operating
time: its median would read neither side's level (fresh seed 2090 unit 0: a bin of a 0 and a 0.19 across 300 s
without an index read 0.10, an exponential won, a linear coil forecast 28 % early; cut, 0.6 % late). Bins of equal
operating time mended it too but moved 130 of the 192 forecasts of tuning seeds 2086–2089, four by 8–18 points;
these cuts moved 61, by at most 2.6 (docs/degradation.md, "The forecast")."""
MIN_POINTS = 8
"""Fewest valid windows since the reset for a forecast."""
ONSETS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)
"""Onsets of wear tried, as fractions of the segment's operating time (0: wearing from the first window). Fractions of
time, not quantiles of the bins: a history with a gap (windows without an index while a worn part was not told from
a look-alike, docs/degradation.md) put every quantile onset after it, so a part flat before the gap and wearing
after it was explained by exponential wear instead; one more index of 0 before the gap then turned a straight line
into an exponential and its forecast 30 % early (tuning seed 2042, unit 0, valve_coil, on the valve relation without
the torque noise's share: 792 s for a true 1134; with these onsets 1140 s). Every 0.05 up to 0.2 since stop 62: a
linear relief path whose history held one reading before its wear began (5 % into the history) and then a gap chose
the accelerating model at its warning, 33.9 % early (fresh flagged 3026 unit 56; tests/data/
forecast_lone_early_point.json); with 0.05 and 0.15 it is 0.3 % off. Replayed on the stored fits of 49 units, that
one among them (294 paths of every kind: fresh regular 2106–2109 and flagged 3023–3026, relief-shut 3021/3022, 3018/314
and /597): within ±20 % 288 → 290 and covered 286 → 288 of 294 (2107/2's relief too, 29.6 → 0.3 %, and 2106/3's pump
leak now covered), none lost, 82 forecasts moved by
more than half a point, the largest loss 2.7 points (3025/90's pump leak 0.1 → 2.8 %), no false or healthy forecast
either way (docs/degradation.md, "The forecast")."""
GROWTH_GRID = (0.0, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0)
"""γ·span values tried (0: straight line); span = operating time covered by the segment. No slowing (γ < 0)
shapes: on the tuning units a valve_coil wearing linearly, with a kink in its index, was fitted as slowing wear
and pushed beyond the horizon; a forecast of an alert should not bet on wear levelling off. Steps of 0.25 where
accelerating paths of 30–120 minutes land (before 2026-11-26: 0, 0.5, 1, 1.5, 2, 3, 4, 6: an accelerating pump
leak with γ·span ≈ 1.35 was fitted at 1.0 and forecast 23 % late, its interval [619, 824] s missing the truth
594 s, seed 2042); not below 0.5: steps of 0.25 from 0 read two linear load paths as accelerating (22–26 % early)."""
ROBUST_C = 4.685
"""Tukey biweight constant, in residual scales (95 % efficiency for normal noise): bins further off weigh 0."""
ROBUST_ITERATIONS = 3
"""Reweighting passes of the robust fit."""
ROBUST_FLOOR = 0.01
"""Smallest residual scale of the robust fit, index: a clean series' scale may be ~0, which would weigh every bin
off its first fit to 0."""
BOOTSTRAP = 200
"""Bootstrap resamples of the interval."""
MIN_RISE = 0.1
"""Smallest rise of the fitted index over the segment that counts as wear (a fifth of the warning; the index's
systematic error is 0.02 + 3 %): below it an exponential fitted to noise would extrapolate a healthy part to an
alert (measured: a healthy valve_coil, level 0.001, forecast to alert in 2.2 h)."""
HORIZON_FACTOR = 10.0
"""A crossing further than this × the segment's span is not forecast (extrapolation beyond what the data show)."""
ALERT_SD = SYSTEMATIC[0] + SYSTEMATIC[1] * ALERT
"""Standard deviation of the index's systematic error at the alert (:data:`~hydrowatch.condition.degradation.
SYSTEMATIC`): where the measured index reads 1.0 the part may be at 0.95 or 1.05, so each bootstrap resample
solves for its own alert level drawn with it."""
NEVER = 1e300
"""Stands for a crossing that never comes (a flat or falling resample) inside the quantiles."""


@dataclass(frozen=True)
class Forecast:
    """Time until a component's index reaches 1.0 (alert), from its own history.

    Attributes
    ----------
    alert_in_s : float or None
        Operating seconds from the last window given (the machine's last window with an index: a part's own last
        index may be older) to the alert crossing (0 when already beyond); None when the history does not support a
        forecast (``reason``).
    ci95 : (float or None, float or None)
        95 % interval of ``alert_in_s``, s; None for an unbounded end.
    rate_per_h : float
        Current wear rate dI/dt, index per operating hour (NaN with too few windows).
    model : str
        ``"linear"``, ``"exp"`` or ``"none"``.
    level : float
        Fitted index now.
    points : int
        Windows with an index since the last reset.
    reset_at_s : float or None
        Time of the window that started the current trend after a reset, s (None without a reset).
    reason : str or None
        Why there is no forecast.
    untold_from : str or None
        The part whose index this one's latest windows share (:meth:`~.degradation_series.Degradation.untold_from`):
        the forecast is of this part *or* that one; None: told apart.
    """

    alert_in_s: float | None
    ci95: tuple[float | None, float | None]
    rate_per_h: float
    model: str = "none"
    level: float = float("nan")
    points: int = 0
    reset_at_s: float | None = None
    reason: str | None = field(default=None)
    untold_from: str | None = None

    def to_dict(self) -> dict[str, object]:
        """``score --json``'s summary entry: alert_in_s, ci95, rate_per_h (+ model, level, points, reset_at_s,
        reason); floats rounded, non-finite as None."""

        def num(x: float | None, digits: int = 1) -> float | None:
            return None if x is None or not np.isfinite(x) else round(float(x), digits)

        out: dict[str, object] = {"alert_in_s": num(self.alert_in_s), "ci95": [num(self.ci95[0]), num(self.ci95[1])],
                                  "rate_per_h": num(self.rate_per_h, 5), "model": self.model,
                                  "level": num(self.level, 4), "points": self.points,
                                  "reset_at_s": num(self.reset_at_s, 3)}
        if self.reason is not None:
            out["reason"] = self.reason
        if self.untold_from is not None:
            out["untold_from"] = self.untold_from
        return out


def ruled_out_forecast() -> Forecast:
    """No forecast for a valve-side part that the machine's latest window rules out (another part blamed by the
    margin: it reads 0 there). Its older values were a look-alike's share of another part's wear, and a forecast
    from them contradicted the index shown (docs/degradation.md, "The forecast")."""
    return Forecast(None, (None, None), float("nan"),
                    reason="ruled out: another valve-side part explains the latest windows")


def part_forecast(t: np.ndarray, degradation: Degradation, fault: str, upto: int | None = None) -> Forecast:
    """The forecast of one part from a machine's windows 0..``upto`` (start times ``t``, s), as the machine knew
    them then: none where the latest window rules it out (:func:`ruled_out_forecast`), else
    :func:`forecast_alert` of its history (:meth:`~.degradation_series.Degradation.history`), naming the part it
    shares its index with there (``untold_from``)."""
    if degradation.ruled_out(fault, upto):
        return ruled_out_forecast()
    end = t.size if upto is None else upto + 1
    if degradation.valid is not None and degradation.valid[:end].any():  # counted from the last valid window
        end = int(np.flatnonzero(degradation.valid[:end])[-1]) + 1
    return replace(forecast_alert(np.asarray(t)[:end], degradation.history(fault, upto)[:end]),
                   untold_from=degradation.untold_from(fault, upto))


def _binned(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean time, median index) of at most :data:`BINS` bins of consecutive points, each cut where it spans a gap
    longer than :data:`GAP_BINS` bins' share of the operating time (so a few more bins)."""
    groups = np.array_split(np.arange(t.size), min(BINS, t.size))
    gap = GAP_BINS * (t[-1] - t[0]) / min(BINS, t.size)
    groups = [part for g in groups for part in np.split(g, np.flatnonzero(np.diff(t[g]) > gap) + 1)]
    return np.array([t[g].mean() for g in groups]), np.array([np.median(v[g]) for g in groups])


def _bases(x: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate trend shapes at bin times x ≤ 0 (0 = now), s: bases (J, n), their γ (J,) and parameter counts (J,).

    Basis (e^{γ·max(x, h)} − 1)/γ (γ = 0: max(x, h)) for every γ of :data:`GROWTH_GRID` and onset h of
    :data:`ONSETS`: 0 now, slope 1 now, so that α is the level now and β the rate now; before an onset h the trend
    is flat (a part that starts wearing after a quiet stretch).
    """
    onsets = x[0] + np.asarray(ONSETS) * (x[-1] - x[0])
    bases, gammas, counts = [], [], []
    for h_i, h in enumerate(onsets):
        z = np.maximum(x, h)
        for g_span in GROWTH_GRID:
            g = g_span / span
            bases.append(z if g == 0.0 else np.expm1(g * z) / g)
            gammas.append(g)
            counts.append(2 + (g != 0.0) + (h_i > 0))
    return np.array(bases), np.array(gammas), np.array(counts)


def _candidates(bases: np.ndarray, counts: np.ndarray, y: np.ndarray,
                weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(α, β, Bayesian information criterion) of every candidate y ≈ α + β·basis, each (J,): closed-form weighted
    least squares of every candidate at once; ``weight`` (n,) in [0, 1], default 1: a bin's robust weight, the
    criterion counts Σ weight bins."""
    w = np.ones(y.size) if weight is None else weight
    total = float(w.sum())
    b_mean, y_mean = bases @ w / total, float(w @ y) / total
    bc, yc = bases - b_mean[:, None], y - y_mean
    sbb = np.einsum("jn,jn,n->j", bc, bc, w)
    beta = np.where(sbb > 0, bc @ (w * yc) / np.maximum(sbb, 1e-300), 0.0)
    rss = np.maximum(float(w @ yc**2) - beta**2 * sbb, 1e-300)
    return y_mean - beta * b_mean, beta, total * np.log(rss / total) + counts * np.log(total)


def _crossings(alpha: np.ndarray, beta: np.ndarray, gamma: np.ndarray,
               alert: float | np.ndarray = ALERT) -> np.ndarray:
    """Time after now, s, at which each candidate α + β·(e^{γx} − 1)/γ (γ = 0: α + β·x) reaches ``alert`` (a number
    or one per candidate), each (J,): 0 if already there, inf never."""
    need = alert - alpha
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        g = np.where(gamma > 0, gamma, 1.0)
        arg = 1.0 + gamma * need / np.where(beta != 0, beta, np.nan)
        exp_t = np.where((beta > 0) & (arg > 0), np.log(arg) / g, np.inf)
        lin_t = np.where(beta > 0, need / beta, np.inf)
        out = np.where(gamma > 0, exp_t, lin_t)
    return np.where(alpha >= alert, 0.0, np.nan_to_num(out, nan=np.inf))


def resampled_interval(crossings: np.ndarray) -> tuple[float, float]:
    """2.5 % and 97.5 % of the resamples' crossings, s (inf: never, as :data:`NEVER`), not interpolated towards
    "never" (a machine at its alert in ``make demo`` read ``"alert_ci95": [0, 2.5e298]``)."""
    x = np.minimum(np.asarray(crossings, dtype=np.float64), NEVER)  # order statistics; interpolated in between
    lower, higher, mid = (np.quantile(x, [0.025, 0.975], method=m) for m in ("lower", "higher", "linear"))
    straddles = (higher >= NEVER) & (lower < NEVER)
    return float(lower[0] if straddles[0] else mid[0]), float(higher[1] if straddles[1] else mid[1])


def _averaged_crossing(bases: np.ndarray, gammas: np.ndarray, counts: np.ndarray, y: np.ndarray,
                       weight: np.ndarray | None = None, alert: float = ALERT) -> tuple[float, float, float]:
    """Median, 2.5 % and 97.5 % quantiles of the crossing over every candidate, each weighted by its BIC's
    posterior weight e^{−ΔBIC/2}."""
    alpha, beta, bic = _candidates(bases, counts, y, weight)
    p = np.exp(-(bic - bic.min()) / 2.0)
    cross = _crossings(alpha, beta, gammas, alert)
    order = np.argsort(cross)
    cum = np.cumsum(p[order]) / p.sum()
    q = cross[order][np.minimum(np.searchsorted(cum, [0.5, 0.025, 0.975]), cum.size - 1)]
    return float(q[0]), float(q[1]), float(q[2])


def _fit(bases: np.ndarray, gammas: np.ndarray, counts: np.ndarray, y: np.ndarray,
         weight: np.ndarray | None = None) -> tuple[float, float, float, int]:
    """(α, β, γ, which) of the candidate with the smallest Bayesian information criterion (:func:`_candidates`)."""
    alpha, beta, bic = _candidates(bases, counts, y, weight)
    j = int(np.argmin(bic))
    return float(alpha[j]), float(beta[j]), float(gammas[j]), j


def _robust_fit(bases: np.ndarray, gammas: np.ndarray, counts: np.ndarray,
                y: np.ndarray) -> tuple[float, float, float, int, np.ndarray]:
    """:func:`_fit` with Tukey-biweight weights of the bins, re-estimated :data:`ROBUST_ITERATIONS` times from the
    residuals about their median and their scale (1.4826 · median absolute deviation, at least
    :data:`ROBUST_FLOOR`); also returns the weights.

    A bin median is robust to isolated outlier windows, not to a run of them as long as a bin (an index that
    reads high through one phase of the duty cycle); such bins get weight 0. The weights stop where fewer than
    half the bins would keep any."""
    weight = np.ones(y.size)
    found = _fit(bases, gammas, counts, y)
    for _ in range(ROBUST_ITERATIONS):
        residual = y - (found[0] + found[1] * bases[found[3]])
        residual -= np.median(residual)  # the least-squares start is pulled by the outliers; α is refitted anyway
        scale = max(1.4826 * float(np.median(np.abs(residual))), ROBUST_FLOOR)
        u = residual / (ROBUST_C * scale)
        new = np.where(np.abs(u) < 1.0, (1.0 - u**2) ** 2, 0.0)
        if np.count_nonzero(new) < max(y.size / 2, counts.max() + 2):
            break
        weight, found = new, _fit(bases, gammas, counts, y, new)
    return (*found, weight)


def forecast_alert(t: np.ndarray, index: np.ndarray, *, max_gap_s: float = 3600.0, min_span_s: float = 300.0,
                   seed: int = 0) -> Forecast:
    """Forecast one component's alert crossing from its index history (module docstring).

    Parameters
    ----------
    t : array_like, shape (n,)
        Window times, s, in arrival order; ``alert_in_s`` counts from the last (the machine's now: give the times of
        the windows with an index of any part, such as :class:`~.forecast_stream.ForecastStream` holds).
    index : array_like, shape (n,)
        Degradation index per window; NaN where the window has none (invalid, unknown).
    max_gap_s : float, default 3600
        Longest forward step of the clock counted as operating time, s.
    min_span_s : float, default 300
        Shortest operating time since the last reset that is forecast from, s.
    seed : int, default 0
        Bootstrap seed.

    Raises
    ------
    DataError
        When ``t`` and ``index`` differ in length.
    """
    t = np.asarray(t, dtype=np.float64)
    v = np.asarray(index, dtype=np.float64)
    if t.shape != v.shape or t.ndim != 1:
        raise DataError(f"times and index must be 1-D of one length. Got shapes {t.shape} and {v.shape}.")
    clock = np.isfinite(t)
    t, v = t[clock], v[clock]
    keep = np.isfinite(v)
    since = _since_last(t, keep, max_gap_s)
    t, v = t[keep], v[keep]
    start = reset_start(v)
    reset_at = float(t[start]) if start > 0 else None
    op = operating_time(t[start:], max_gap_s)
    v = v[start:]
    if v.size < MIN_POINTS or op[-1] < min_span_s:
        return Forecast(None, (None, None), float("nan"), points=int(v.size), reset_at_s=reset_at,
                        reason=f"too short: {v.size} windows over {op[-1] if op.size else 0.0:.0f} s since "
                               f"{'the reset' if reset_at is not None else 'the start'}; a forecast needs "
                               f"{MIN_POINTS} windows over {min_span_s:g} s")
    x, y = _binned(op - op[-1], v)
    span = float(op[-1])
    bases, gammas, counts = _bases(x, span)
    alpha, beta, gamma, j, weight = _robust_fit(bases, gammas, counts, y)
    fitted = alpha + beta * bases[j]
    model = "linear" if gamma == 0.0 else "exp"
    rise = alpha - float(np.min(fitted))
    if rise < MIN_RISE and alpha < ALERT:  # decided by the fit alone: no bootstrap (most parts of most machines)
        return Forecast(None, (None, None), beta * 3600.0, model, alpha, int(v.size), reset_at,
                        reason=f"too flat: the index rose {rise:.3f} < {MIN_RISE:g} over the history")
    residual = y - fitted
    rng = np.random.default_rng(seed)
    block = max(1, int(round(np.sqrt(x.size))))
    found = np.empty((3, BOOTSTRAP))  # α, β, γ of each resample
    levels = ALERT + ALERT_SD * rng.standard_normal(BOOTSTRAP)  # the index's own systematic error at the alert
    for b in range(BOOTSTRAP):
        starts = rng.integers(0, x.size - block + 1, size=int(np.ceil(x.size / block)))
        picked = np.concatenate([np.arange(s, s + block) for s in starts])[: x.size]
        # each resampled residual keeps its robust weight: an outlier bin stays an outlier wherever it lands
        found[:, b] = _fit(bases, gammas, counts, fitted + residual[picked], np.maximum(weight[picked], 1e-9))[:3]
    rates, crossings = found[1], _crossings(found[0], found[1], found[2], levels)
    rate_h = beta * 3600.0
    lo, hi = resampled_interval(crossings)
    point, model_lo, model_hi = _averaged_crossing(bases, gammas, counts, y, weight)
    lo, hi = min(lo, model_lo), max(hi, min(model_hi, NEVER))
    ci = (max(lo - since, 0.0) if lo < NEVER else None, max(hi - since, 0.0) if hi < NEVER else None)
    fitted_now = Forecast(None, ci, rate_h, model, alpha, int(v.size), reset_at)
    if point <= since:  # beyond the alert at the part's last index, or by the last window given
        return replace(fitted_now, alert_in_s=0.0, ci95=(0.0, ci[1] if ci[1] is not None else 0.0))
    low_rate = float(np.quantile(rates, 0.025))
    if low_rate <= 0.0 or not point <= HORIZON_FACTOR * span:
        why = ("the wear rate's 95 % interval reaches 0" if low_rate <= 0.0
               else f"the alert is further than {HORIZON_FACTOR:g}× the {span:.0f} s of history")
        return replace(fitted_now, reason=f"too flat: {why}")
    return replace(fitted_now, alert_in_s=float(point - since))


def _since_last(t: np.ndarray, indexed: np.ndarray, max_gap_s: float) -> float:
    """Operating time from the last window with an index (``indexed``) to the last window given, s (0 when it is
    the last, or when none has one): the forecast counts from the last window given, the machine's now, not from
    the part's last index (windows without one at the end: a part not told from a look-alike)."""
    if not indexed.any():
        return 0.0
    op = operating_time(t, max_gap_s)
    return float(op[-1] - op[np.flatnonzero(indexed)[-1]])
