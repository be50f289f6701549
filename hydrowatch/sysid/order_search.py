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
3. *Noise model*: with G = q^-K B/F settled, every (nc, nd) is fitted in order of increasing
   nc + nd until ``patience`` sizes in a row bring no lower Akaike criterion
   AIC = N ln(sigma^2) + 2 p. A candidate is admissible when it passes Q and S, the last
   coefficients of C and D are significant and C and D share no near-common factor (a zero and
   a pole closer than the cancellation tolerance: the H of a smaller model). The admissible
   candidate with the lowest AIC is kept, then step 2 runs again for G.

Step 3 exists because several noise models of the same size can pass Q when H has nearly
cancelling pole-zero pairs (the study's Eq. 3.24): the raise/lower walk stops at the first one
it meets, the criterion compares them all.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.log import event, get_logger
from hydrowatch.sysid.boxjenkins import BoxJenkins
from hydrowatch.sysid.preliminary import PreliminaryIdentification, preliminary_identification

__all__ = ["OrderSearch", "akaike", "search_orders"]

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


def akaike(model: BoxJenkins) -> float:
    """Akaike's criterion N ln(sigma^2) + 2 p of a fitted model (sigma^2 of Eq. 3.14).

    p counts the model's parameters and the start-up coefficients fitted with them (initial
    state and output offset, ``n_start_up_``): a larger model also gets more of those, and each
    absorbs about one sample's error at the start of the record.
    """
    p = len(model.parameter_names_) + int(getattr(model, "n_start_up_", 0))
    return float(model.n_samples_ * np.log(model.sigma2_) + 2 * p)


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
    max_fits: int = 80,
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
        Noise-model sizes nc + nd in a row without a lower AIC after which step 3 stops.
    max_fits : int
        Budget of model fits (one fit of N = 10,000 samples takes about 0.1-0.3 s).
    **model_params
        Passed on to :class:`BoxJenkins` (``lags``, ``normalize``, ...).
    """
    if not 0.0 < alpha < 1.0:
        raise ParameterError(f"alpha must be in (0, 1). Got {alpha!r}; use e.g. 0.05.")
    for name, value, low in (("max_noise_order", max_noise_order, 0), ("patience", patience, 1)):
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
            aic = akaike(cache[key])
            history.append({"orders": dict(orders), "action": action, "Q_p": v["Q_p"], "S_p": v["S_p"], "aic": aic})
            event(_log, "order search fit", action=action, **orders, Q_p=v["Q_p"], S_p=v["S_p"], aic=aic)
        return cache[key]

    current = fit({k: int(start[k]) for k in _KEYS}, "start")
    try:
        current = _raise_orders(current, fit, alpha, max_order)
        current = _lower_orders(current, fit, alpha)
        if max_noise_order > 0:
            current = _select_noise_model(current, fit, alpha, max_noise_order, patience)
            current = _lower_orders(current, fit, alpha)
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


def _select_noise_model(current: BoxJenkins, fit: Any, alpha: float, max_noise_order: int, patience: int) -> BoxJenkins:
    """Step 3 of the module docstring: (nc, nd) by the lowest AIC among admissible candidates, G fixed."""
    orders = {k: int(getattr(current, k)) for k in _KEYS}
    chosen = current if _admissible_noise_model(current, alpha) else None
    best_aic, stale = np.inf, 0
    for size in range(2 * max_noise_order + 1):
        size_aic = np.inf
        for nc in range(max(0, size - max_noise_order), min(size, max_noise_order) + 1):
            try:
                model = fit({**orders, "nc": nc, "nd": size - nc}, "noise model by AIC")
            except _Budget:
                return current if chosen is None else chosen
            size_aic = min(size_aic, akaike(model))
            if _admissible_noise_model(model, alpha) and (chosen is None or akaike(model) < akaike(chosen)):
                chosen = model
        stale = 0 if size_aic < best_aic else stale + 1
        best_aic = min(best_aic, size_aic)
        if stale >= patience:
            break
    return current if chosen is None else chosen
