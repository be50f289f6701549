"""The parity method's state decision: the health state whose physics explains the window best (:class:`ParityRule`).

Its scores are :meth:`hydrowatch.condition.features.ConditionFeatures.transform_with_levels` rows (band-box
ratios, then level-box ratios); :class:`hydrowatch.condition.model.ConditionModel` fits and stores it with
the features and the open-set rule.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, cast

import numpy as np

from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.health.classifier import fit_temperature


class ParityRule:
    """Nearest health state by parity scores: argmax_k log π_k − (Σ_r (log F + w·log F_level)[r, k] − [healthy]·m) / T.

    ``X`` is :meth:`ConditionFeatures.transform_with_levels`: band-box ratios then level-box
    ratios, each relation-major.

    Why the two calibration terms (docs/command-invariance.md, "Calibration"):

    - ``min_temperature``: the filtered noise of the identification experiment separates the
      states perfectly, so the fitted T falls to its floor (0.02), where a score difference of
      0.1 reads as 150:1 odds; in holds the true state's relations carry 5–15 % of model error in
      MSE (log F ≈ 0.05–0.15) and look-alikes differ by as little, so wrong verdicts came with
      p > 0.99. T stays at or above this floor: a ratio difference inside the model error is
      not strong evidence. On units that are not the defaults the model error is larger: on the
      development population (seed 7, 6 units, every condition of benchmarks/bench_unseen_units.py)
      the 13-state per-window ECE / wrong verdicts with p > 0.99 were 0.149 / 41 % at 0.1, 0.096 /
      3 % at 0.5 and 0.091 / 0 % at 0.8; with pooled rows weighted by their windows
      (:meth:`predict_proba`) the pooled ones 0.079 / 13 % at 0.1 (unweighted) and 0.074 / 7 % at
      0.5, so 0.5. The 7-state ECE (≈ 0.10, healthy ties and oil without temperature) does not move.
    - ``healthy_prior`` (off by default): in a window that does not load a part (pump
      saturation, a low-demand stretch), the faults that only show under load explain it exactly
      as well as ``healthy``: equal scores, so with a uniform prior a healthy window gets
      p = 1/(1 + tied faults) (the decision is ``healthy``: it comes first in the states, and
      argmax keeps the first of equal scores). π(healthy) = ``healthy_prior``, the rest spread
      evenly over the faults, makes those probabilities honest (ECE 0.07–0.10 → 0.03–0.04) but
      also tips near-ties: weak faults such as a pump leak in low holds then read healthy (7
      states, flow sensor only: 80 → 60 % on a duty cycle), so the default keeps the uniform prior.
    - ``healthy_margin`` m: a fault is the decision only when it explains the evidence better than
      ``healthy`` by at least m (summed log MSE ratios; for pooled rows, over the pooled windows).
      In a window that does not load a part, that part's fault ties with ``healthy`` exactly, and
      argmax keeps the first of equal scores (``healthy``); but a window that loads it a little tips
      the tie by noise and the unit's model error, and a pool of otherwise tied windows then follows
      that one window (report population, seed 2026, unit 7, 13 states, healthy machine on cold oil:
      one window tipped by 0.052 to ``pump_leak_warning`` made all 12 pooled verdicts that held it
      ``pump_leak_warning``). On the development population (seed 7, 10 units, every condition of
      benchmarks/bench_unseen_units.py) no fault ever beat ``healthy`` on a healthy machine, and
      faults read right by a smaller advantage than 0.1 were 2 of 30,154 windows alone and 0 of
      31,845 pooled over 12, so m = 0.1: far above the tie noise seen there (median 0.001 where
      ``healthy`` led), costing one window of one unit (duty cycle, 7 states, per window 100 → 99.6 %).
      It is the same as a prior exp(m / T) : 1 for ``healthy``, but a fixed amount of evidence
      rather than a belief about the fleet.

    Parameters
    ----------
    level_weight : float, default 1.0
        w, the weight of the level-box ratios (0: band boxes only).
    min_temperature : float, default 0.5
        Floor of the fitted softmax temperature T (units of summed log MSE ratios).
    healthy_prior : float or None, default None
        Prior probability of ``healthy`` (the faults share the rest evenly); None, or no
        ``healthy`` among the states: a uniform prior.
    healthy_margin : float, default 0.1
        m, the evidence (summed log MSE ratios) by which a fault must beat ``healthy`` (0: none).

    Attributes
    ----------
    classes_ : ndarray of str, shape (n_states,)
    temperature_ : float
        Softmax temperature of the probabilities: fitted on the training windows, at least ``min_temperature``.
    """

    def __init__(self, *, level_weight: float = 1.0, min_temperature: float = 0.5,
                 healthy_prior: float | None = None, healthy_margin: float = 0.1) -> None:
        if not min_temperature > 0.0:
            raise ParameterError(f"min_temperature must be > 0. Got {min_temperature!r}; 0.5 is the default.")
        if healthy_prior is not None and not 0.0 < healthy_prior < 1.0:
            raise ParameterError(f"healthy_prior must be in (0, 1) or None. Got {healthy_prior!r}; "
                                 "None (uniform) is the default.")
        if not healthy_margin >= 0.0:
            raise ParameterError(f"healthy_margin must be >= 0. Got {healthy_margin!r}; 0.1 is the default.")
        self.level_weight = level_weight
        self.min_temperature = min_temperature
        self.healthy_prior = healthy_prior
        self.healthy_margin = healthy_margin

    def get_params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {"level_weight": self.level_weight, "min_temperature": self.min_temperature,
                "healthy_prior": self.healthy_prior, "healthy_margin": self.healthy_margin}

    def _logits(self, X: np.ndarray) -> np.ndarray:
        x = np.asarray(X, dtype=np.float64)
        n = len(self.classes_)
        if x.ndim != 2 or x.shape[1] % (2 * n):
            raise DataError(f"X must have shape (n, 2 * n_relations * {n}) (band then level ratios). Got {x.shape}.")
        band, level = np.split(-np.log(np.maximum(x, 1.0)).reshape(x.shape[0], -1, n), 2, axis=1)
        return band.sum(axis=1) + self.level_weight * level.sum(axis=1)

    def log_prior(self) -> np.ndarray:
        """log π per state, shape (n_states,) (class docstring)."""
        n = len(self.classes_)
        healthy = self.classes_ == "healthy"
        if self.healthy_prior is None or not healthy.any() or n == 1:
            return np.full(n, -np.log(n))
        prior = np.where(healthy, self.healthy_prior, (1.0 - self.healthy_prior) / (n - 1))
        return cast(np.ndarray, np.log(prior))

    def fit(self, X: np.ndarray, y: Sequence[str] | np.ndarray, classes: Sequence[str]) -> ParityRule:
        """Fit the temperature on windows ``X`` (n, n_relations * n_states) of states ``y``; returns self."""
        self.classes_ = np.asarray(list(classes), dtype=str)
        index = {c: i for i, c in enumerate(self.classes_.tolist())}
        labels = np.asarray(y).astype(str)
        unknown = sorted(set(labels.tolist()) - set(index))
        if unknown:
            raise DataError(f"every label in y must be one of classes. Got unknown labels {unknown}.")
        target = np.array([index[v] for v in labels.tolist()], dtype=np.int64)
        self.temperature_ = max(fit_temperature(self._logits(X), target), float(self.min_temperature))
        return self

    def predict_proba(self, X: np.ndarray, windows: np.ndarray | None = None) -> np.ndarray:
        """Probabilities, shape (n, n_states); NaN rows stay NaN.

        ``windows`` (n,), for rows that pool several windows' evidence (:mod:`hydrowatch.condition.evidence`):
        how many each pools. A pooled row holds the *mean* log ratio over its c windows (the level prior once);
        the evidence of c windows is their sum, so its logits are c times the row's, and ``healthy_margin`` is
        weighed against that sum.
        """
        if not hasattr(self, "temperature_"):
            raise NotFittedError("ParityRule must be fitted before use. Call fit(X, y, classes) first.")
        logits = self._logits(X)
        if windows is not None:
            logits = logits * np.asarray(windows, dtype=np.float64).reshape(-1, 1)
        margin = np.where(self.classes_ == "healthy", self.healthy_margin, 0.0)
        z = (logits + margin) / self.temperature_ + self.log_prior()
        z = z - np.max(np.nan_to_num(z, nan=0.0), axis=1, keepdims=True)
        e = np.exp(z)
        return e / e.sum(axis=1, keepdims=True)

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Most probable state per row, shape (n,)."""
        return self.classes_[np.nan_to_num(self.predict_proba(X), nan=-1.0).argmax(axis=1)]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"params": self.get_params(), "classes": self.classes_.tolist(), "temperature": self.temperature_}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ParityRule:
        """Inverse of :meth:`to_dict` (a rule saved before ``min_temperature`` existed keeps its saved temperature)."""
        try:
            rule = cls(**data.get("params", {}))
            rule.classes_ = np.asarray(data["classes"], dtype=str)
            rule.temperature_ = float(data["temperature"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"parity rule must have classes and temperature. Missing/bad: {exc}.") from None
        return rule
