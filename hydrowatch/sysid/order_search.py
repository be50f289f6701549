"""Automatic Box-Jenkins order selection by the study's validation rules (Sec. 3.2.3, 3.4.3).

Starting from the preliminary identification's orders (GPAC, Sec. 3.2.1) or given ones:

1. *Raise* while a chi-square test fails: S (Eq. 3.18) failing raises nb or nf, Q (Eq. 3.17)
   failing raises nc or nd; of the two candidates whose added coefficient is significant (its
   95 % interval excludes zero) the one with the larger p-value is kept; if neither added
   coefficient is significant, raising stops (the test's failure is then reported as is).
2. *Lower* while the model allows it: an order whose last coefficient's 95 % interval
   (Eq. 3.14) straddles zero loses that coefficient; a pole-zero cancellation in G or H lowers
   both of its orders; b1 straddling zero moves one coefficient into the delay. A lower model is
   kept only if it passes every test that the current one passes.
3. *Noise model*: with G = q^-K B/F fixed, every (nc, nd) is fitted in order of increasing
   nc + nd until ``patience`` sizes in a row bring no lower criterion (AIC = N ln(sigma^2) + 2 p
   by default, p counting the start-up coefficients too). A candidate is admissible for H when
   it passes Q and S, the last coefficients of C and D are significant and C and D share no
   near-common factor (the H of a smaller model); the admissible one with the lowest criterion
   is kept.
4. *Climb*: move to the stable neighbour (each order +-1, or both orders of G or of H
   together) with the lowest criterion, while that lowers it; then step 2 again. Steps 3-4
   repeat (``rounds``) until the orders stop changing.
5. *Smallest G*: lower nb, nf or both while the lower G (same H) still passes Q and S.
6. *Choice*: among all fitted models that are admissible (H as in step 3, and B, F ending in
   significant coefficients without a G cancellation) and within 3.84 (chi-square(1), 95 %) of
   the lowest admissible criterion, those with the smallest nb + nf, and of these the lowest
   criterion, after step 3 has been run once more for the G of step 5.

Step 3 exists because several noise models of the same size can pass Q when H has nearly
cancelling pole-zero pairs (the study's Eq. 3.24): the raise/lower walk stops at the first one
it meets, the criterion compares them all. Steps 4-6 exist because the walk settles G from the
GPAC start (often nb = 7-10 on Eq. 3.24 records) and only lowers an order whose last coefficient
straddles zero: on seeds 11-20 it kept G = (7, 5), (5, 5), (6, 4), (7, 3) or (10, 3), whose extra
pole-zero pair buys 1-3 AIC units by chance, while G = (4, 4) passed S. G's parameters are well
determined (S rejects a G that is too small), H's are not, so G is chosen by parsimony and H by
the criterion.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.log import event, get_logger
from hydrowatch.sysid.boxjenkins import BoxJenkins
from hydrowatch.sysid.preliminary import PreliminaryIdentification, preliminary_identification

__all__ = ["OrderSearch", "admissible", "akaike", "information_criterion", "schwarz", "search_orders"]

_log = get_logger(__name__)
_KEYS = ("nb", "nf", "nc", "nd", "delay")


@dataclass
class OrderSearch:
    """Outcome of :func:`search_orders`: the chosen fitted model and every step taken."""

    model: BoxJenkins
    history: list[dict[str, Any]] = field(default_factory=list)
    preliminary: PreliminaryIdentification | None = None

    @property
    def orders(self) -> dict[str, int]:
        return {k: int(getattr(self.model, k)) for k in _KEYS}


def _passes(model: BoxJenkins, alpha: float) -> tuple[bool, bool]:
    v = model.validation_
    return v["Q_p"] >= alpha, v["S_p"] >= alpha


def information_criterion(model: BoxJenkins, penalty: float) -> float:
    """N ln(sigma^2) + penalty * p of a fitted model (sigma^2 of Eq. 3.14).

    p counts the model's parameters and the start-up coefficients fitted with them (initial
    state and output offset, ``n_start_up_``): a larger model also gets more of those, and each
    absorbs about one sample's error at the start of the record.
    """
    p = len(model.parameter_names_) + int(getattr(model, "n_start_up_", 0))
    return float(model.n_samples_ * np.log(model.sigma2_) + penalty * p)


def akaike(model: BoxJenkins) -> float:
    """Akaike's criterion AIC = N ln(sigma^2) + 2 p (:func:`information_criterion`)."""
    return information_criterion(model, 2.0)


def schwarz(model: BoxJenkins) -> float:
    """Schwarz's Bayesian criterion BIC = N ln(sigma^2) + p ln N (:func:`information_criterion`)."""
    return information_criterion(model, float(np.log(model.n_samples_)))


_CRITERIA = {"aic": akaike, "bic": schwarz}
_PARSIMONY_MARGIN = 3.84
"""Step 6 prefers a smaller G only among models within this criterion distance of the best
admissible one: the 95 % point of chi-square(1), a difference that chance alone rarely makes."""


def _straddles(model: BoxJenkins, name: str) -> bool:
    lo, hi = model.ci95_[model.parameter_names_.index(name)]
    return not (np.isfinite(lo) and np.isfinite(hi)) or lo <= 0.0 <= hi


def _relative_size(model: BoxJenkins, name: str) -> float:
    i = model.parameter_names_.index(name)
    se = np.sqrt(model.covariance_[i, i])
    return float(abs(np.concatenate([model.b_, model.f_, model.c_, model.d_])[i]) / se) if se > 0 else np.inf


def _reductions(model: BoxJenkins) -> list[dict[str, int]]:
    """Lower-order candidates, most promising first (smallest |last coefficient| / standard error)."""
    orders = {k: int(getattr(model, k)) for k in _KEYS}
    ranked: list[tuple[float, dict[str, int]]] = []
    for key, prefix, low in (("nb", "b", 1), ("nf", "f", 0), ("nc", "c", 0), ("nd", "d", 0)):
        name = f"{prefix}{orders[key]}"
        if orders[key] > low and _straddles(model, name):
            ranked.append((_relative_size(model, name), {**orders, key: orders[key] - 1}))
    if orders["nb"] > 1 and _straddles(model, "b1"):
        ranked.append((_relative_size(model, "b1"), {**orders, "nb": orders["nb"] - 1, "delay": orders["delay"] + 1}))
    for pair in model.validation_["cancellations"]:
        n_key, d_key = ("nb", "nf") if pair["model"] == "G" else ("nc", "nd")
        if orders[n_key] > (1 if n_key == "nb" else 0) and orders[d_key] > 0:
            candidate = {**orders, n_key: orders[n_key] - 1, d_key: orders[d_key] - 1}
            ranked.append((-1.0, candidate))  # a cancellation is the clearest case
    ranked.sort(key=lambda item: item[0])
    return [c for _, c in ranked]


def search_orders(
    u: np.ndarray,
    y: np.ndarray,
    start: dict[str, int] | None = None,
    *,
    alpha: float = 0.05,
    max_order: int = 8,
    max_noise_order: int = 6,
    patience: int = 2,
    criterion: str = "aic",
    rounds: int = 3,
    max_fits: int = 200,
    **model_params: Any,
) -> OrderSearch:
    """Box-Jenkins orders and delay chosen by the study's rules, with the fitted model.

    Parameters
    ----------
    u, y : ndarray, shape (N,)
        Input and output.
    start : dict, optional
        Starting ``{"nb", "nf", "nc", "nd", "delay"}``; by default the preliminary
        identification's suggestion (:func:`preliminary_identification`).
    alpha : float
        Significance level of the Q and S tests.
    max_order : int
        Largest order any polynomial may be raised to.
    max_noise_order : int
        Largest nc and nd tried by the noise-model step (step 3); 0 skips that step.
    patience : int
        Noise-model sizes nc + nd in a row without a lower criterion after which step 3 stops.
    criterion : {"aic", "bic"}, default "aic"
        Information criterion that ranks candidates in steps 3, 4 and 6 (:func:`akaike`,
        :func:`schwarz`). On Eq. 3.24 records of 10,000 samples (seeds 11-20) BIC found the true
        orders in 0 of 10: its ln N = 9.2 per parameter drops H's weakly determined pair.
    rounds : int, default 3
        Largest number of alternations of steps 3 and 4.
    max_fits : int
        Budget of model fits (one fit of N = 10,000 samples takes about 0.1-0.4 s).
    **model_params
        Passed on to :class:`BoxJenkins` (``lags``, ``normalize``, ...).
    """
    if not 0.0 < alpha < 1.0:
        raise ParameterError(f"alpha must be in (0, 1). Got {alpha!r}; use e.g. 0.05.")
    if criterion not in _CRITERIA:
        raise ParameterError(f"criterion must be one of {', '.join(_CRITERIA)}. Got {criterion!r}; use 'aic'.")
    score = _CRITERIA[criterion]
    for name, value, low in (("max_noise_order", max_noise_order, 0), ("patience", patience, 1), ("rounds", rounds, 0)):
        if not isinstance(value, int) or value < low:
            raise ParameterError(f"{name} must be an integer >= {low}. Got {value!r}.")
    preliminary = None
    if start is None:
        preliminary = preliminary_identification(u, y)
        start = {**preliminary.orders, "delay": preliminary.delay}
    missing = set(_KEYS) - set(start)
    if missing:
        raise ParameterError(f"start must give {', '.join(_KEYS)}. Got no {', '.join(sorted(missing))}.")
    cache: dict[tuple[int, ...], BoxJenkins] = {}
    history: list[dict[str, Any]] = []

    def fit(orders: dict[str, int], action: str) -> BoxJenkins:
        key = tuple(int(orders[k]) for k in _KEYS)
        if key not in cache:
            if len(cache) >= max_fits:
                raise _Budget
            params: dict[str, Any] = {k: int(orders[k]) for k in _KEYS}
            cache[key] = BoxJenkins(**params, **model_params).fit(u, y)
            v = cache[key].validation_
            aic, bic = akaike(cache[key]), schwarz(cache[key])
            n_parameters = len(cache[key].parameter_names_) + int(cache[key].n_start_up_)
            history.append(
                {"orders": dict(orders), "action": action, "Q_p": v["Q_p"], "S_p": v["S_p"], "aic": aic, "bic": bic,
                 "n_parameters": n_parameters, "admissible": admissible(cache[key], alpha)}
            )  # fmt: skip
            event(_log, "order search fit", action=action, **orders, Q_p=v["Q_p"], S_p=v["S_p"], aic=aic, bic=bic)
        return cache[key]

    current = fit({k: int(start[k]) for k in _KEYS}, "start")
    try:
        current = _raise_orders(current, fit, alpha, max_order)
        current = _lower_orders(current, fit, alpha)
        for _ in range(rounds):
            before = {k: int(getattr(current, k)) for k in _KEYS}
            if max_noise_order > 0:
                current = _select_noise_model(current, fit, alpha, max_noise_order, patience, score)
            current = _climb(current, fit, alpha, max_order, score)
            current = _lower_orders(current, fit, alpha)
            if {k: int(getattr(current, k)) for k in _KEYS} == before:
                break
        if rounds > 0:
            current = _smallest_dynamics(current, fit, alpha, score)
            if max_noise_order > 0:
                current = _select_noise_model(current, fit, alpha, max_noise_order, patience, score)
            accepted = [m for m in cache.values() if admissible(m, alpha)]
            if accepted:
                best = min(score(m) for m in accepted)
                near = [m for m in accepted if score(m) <= best + _PARSIMONY_MARGIN]
                smallest = min(int(m.nb) + int(m.nf) for m in near)
                current = min((m for m in near if int(m.nb) + int(m.nf) == smallest), key=score)
    except _Budget:
        event(_log, "order search stopped: fit budget spent", max_fits=max_fits)
    return OrderSearch(current, history, preliminary)


class _Budget(Exception):
    """Internal: the fit budget is spent."""


def _raise_orders(current: BoxJenkins, fit: Any, alpha: float, max_order: int) -> BoxJenkins:
    while True:
        q_ok, s_ok = _passes(current, alpha)
        orders = {k: int(getattr(current, k)) for k in _KEYS}
        keys, stat = (("nb", "nf"), "S_p") if not s_ok else (("nc", "nd"), "Q_p") if not q_ok else ((), "")
        candidates = [{**orders, k: orders[k] + 1} for k in keys if orders[k] < max_order]
        if not candidates:
            return current
        models = [fit(c, f"raise {k} ({stat} < {alpha})") for c, k in zip(candidates, keys)]
        # a raise is kept only if the added coefficient is significant; otherwise the lowering
        # rule would take it straight back and the failed test is a chance rejection or a
        # misfit more orders do not cure
        useful = [m for m, k in zip(models, keys) if not _straddles(m, f"{k[1]}{getattr(m, k)}")]
        if not useful:
            return current
        current = max(useful, key=lambda m: (m.validation_[stat], -m.sigma2_))


def _lower_orders(current: BoxJenkins, fit: Any, alpha: float) -> BoxJenkins:
    while True:
        q_ok, s_ok = _passes(current, alpha)
        for candidate in _reductions(current):
            model = fit(candidate, "lower (interval straddles zero or cancellation)")
            q_new, s_new = _passes(model, alpha)
            if (q_new or not q_ok) and (s_new or not s_ok):
                current = model
                break
        else:
            return current


def _admissible_noise_model(model: BoxJenkins, alpha: float) -> bool:
    """Passes Q and S, C and D end in significant coefficients, no near-common factor of C and D."""
    last = [f"{p}{n}" for p, n in (("c", int(model.nc)), ("d", int(model.nd))) if n > 0]
    v = model.validation_
    return (
        all(_passes(model, alpha))
        and not any(_straddles(model, name) for name in last)
        and not any(pair["model"] == "H" for pair in v["cancellations"])
        and bool(v["stable"] and v["invertible"])
    )


def _select_noise_model(
    current: BoxJenkins, fit: Any, alpha: float, max_noise_order: int, patience: int, score: Any
) -> BoxJenkins:
    """Step 3 of the module docstring: (nc, nd) by the lowest criterion among admissible candidates, G fixed."""
    orders = {k: int(getattr(current, k)) for k in _KEYS}
    chosen = current if _admissible_noise_model(current, alpha) else None
    lowest = current  # returned when no candidate is admissible (e.g. G still fails S)
    best_score, stale = np.inf, 0
    for size in range(2 * max_noise_order + 1):
        size_score = np.inf
        for nc in range(max(0, size - max_noise_order), min(size, max_noise_order) + 1):
            try:
                model = fit({**orders, "nc": nc, "nd": size - nc}, "noise model by criterion")
            except _Budget:
                return lowest if chosen is None else chosen
            lowest = model if score(model) < score(lowest) else lowest
            if _admissible_noise_model(model, alpha):
                size_score = min(size_score, score(model))
                if chosen is None or score(model) < score(chosen):
                    chosen = model
        # patience counts sizes that bring no better *admissible* H: a lower criterion of a model
        # that fails a test says nothing about the next size
        stale = 0 if size_score < best_score or best_score == np.inf else stale + 1
        best_score = min(best_score, size_score)
        if stale >= patience:
            break
    return lowest if chosen is None else chosen


def admissible(model: BoxJenkins, alpha: float = 0.05) -> bool:
    """Passes Q and S at ``alpha``; B, F, C and D end in significant coefficients (Eq. 3.14); no
    near pole-zero cancellation in G or H; stable and invertible (steps 3 and 6)."""
    last = [f"b{int(model.nb)}"] + ([f"f{int(model.nf)}"] if int(model.nf) > 0 else [])
    return (
        _admissible_noise_model(model, alpha)
        and not any(_straddles(model, name) for name in last)
        and not any(pair["model"] == "G" for pair in model.validation_["cancellations"])
    )


def _neighbours(orders: dict[str, int], max_order: int) -> list[dict[str, int]]:
    """Orders one step away: each of nb, nf, nc, nd by +-1, and (nb, nf) or (nc, nd) together by +-1.

    Raises stop at ``max_order``; an order already above it may still be lowered.
    """
    moves = [{key: step} for key in ("nb", "nf", "nc", "nd") for step in (-1, 1)]
    moves += [{a: step, b: step} for a, b in (("nb", "nf"), ("nc", "nd")) for step in (-1, 1)]
    found = []
    for move in moves:
        candidate = {**orders, **{k: orders[k] + step for k, step in move.items()}}
        allowed = all(0 <= candidate[k] <= max(max_order, orders[k]) for k in ("nb", "nf", "nc", "nd"))
        if candidate["nb"] >= 1 and allowed:
            found.append(candidate)
    return found


def _climb(current: BoxJenkins, fit: Any, alpha: float, max_order: int, score: Any) -> BoxJenkins:
    """Step 4: move to the stable neighbour with the lowest criterion while that lowers it.

    The path may cross models that fail a test or are not admissible (a last coefficient that
    straddles zero is the hint to lower that order next); the search returns the admissible model
    chosen in step 6 among all it fitted.
    """
    while True:
        orders = {k: int(getattr(current, k)) for k in _KEYS}
        best = _best_passing(_neighbours(orders, max_order), fit, None, score, "neighbour by criterion")
        if best is None or score(best) >= score(current):
            return current
        current = best


def _best_passing(candidates: list[dict[str, int]], fit: Any, alpha: float | None, score: Any, action: str) -> Any:
    """The fitted candidate with the lowest criterion among the stable ones passing Q and S at ``alpha``.

    ``alpha=None`` skips the tests. None when none qualifies or the fit budget is spent.
    """
    try:
        models = [fit(candidate, action) for candidate in candidates]
    except _Budget:
        return None
    passing = [m for m in models if (alpha is None or all(_passes(m, alpha))) and m.validation_["stable"]]
    return min(passing, key=score) if passing else None


def _smallest_dynamics(current: BoxJenkins, fit: Any, alpha: float, score: Any) -> BoxJenkins:
    """Step 5: lower nb, nf or both while a lower G, H unchanged, still passes Q and S.

    G's parameters are well determined (S has power against a G that is too small), while an
    extra pole-zero pair in G can lower the criterion by a few units by chance; so G is taken as
    the smallest that the tests accept, and H is then chosen by the criterion for that G.
    """
    while True:
        orders = {k: int(getattr(current, k)) for k in _KEYS}
        lower = [{**orders, "nb": orders["nb"] - db, "nf": orders["nf"] - df} for db, df in ((1, 1), (1, 0), (0, 1))]
        valid = [o for o in lower if o["nb"] >= 1 and o["nf"] >= 0]
        best = _best_passing(valid, fit, alpha, score, "smaller G passing the tests")
        if best is None:
            return current
        current = best
