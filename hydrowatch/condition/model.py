"""The condition model: parity features + a state decision + the open-set rule, fitted and stored together.

Analogue of :class:`hydrowatch.health.model.HealthModel` working from raw windows instead of
reference-model prediction errors. The decision is either

- :class:`ParityRule` (default): the state whose physics explains the window best, the smallest
  sum over relations of log F[r, k] + w·log F_level[r, k] (a generalised likelihood ratio for
  Gaussian residuals, the level-box term a soft prior on the trained severity that breaks ties
  of look-alike states in holds); probabilities are softmax(−score / T) with T fitted on the
  training windows (temperature scaling, as the health classifier does); or
- a :class:`hydrowatch.health.classifier.HealthClassifier` (the study's network, section 6.5) on
  the same features: it fits the training command perfectly but learns the pattern of the
  identification experiment's scores, which the bench shows does not carry to holds and ramps.

``save``/``load`` use one directory: ``condition_features.json``, ``decision.json`` or
``classifier.npz``, ``open_set.json`` (no pickle).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np

from hydrowatch.condition.features import ConditionFeatures
from hydrowatch.errors import DataError, NotFittedError
from hydrowatch.health.classifier import HealthClassifier, fit_temperature
from hydrowatch.health.openset import OpenSetRule
from hydrowatch.health.verdict import Verdict, judge

FILES = {"features": "condition_features.json", "rule": "decision.json", "classifier": "classifier.npz",
         "open_set": "open_set.json"}


class ParityRule:
    """Nearest health state by parity scores: argmin_k Σ_r (log F[r, k] + w·log F_level[r, k]).

    ``X`` is :meth:`ConditionFeatures.transform_with_levels`: band-box ratios then level-box
    ratios, each relation-major.

    Parameters
    ----------
    level_weight : float, default 1.0
        w, the weight of the level-box ratios (0: band boxes only).

    Attributes
    ----------
    classes_ : ndarray of str, shape (n_states,)
    temperature_ : float
        Softmax temperature of the probabilities, fitted on the training windows.
    """

    def __init__(self, *, level_weight: float = 1.0) -> None:
        self.level_weight = level_weight

    def get_params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {"level_weight": self.level_weight}

    def _logits(self, X: np.ndarray) -> np.ndarray:
        x = np.asarray(X, dtype=np.float64)
        n = len(self.classes_)
        if x.ndim != 2 or x.shape[1] % (2 * n):
            raise DataError(f"X must have shape (n, 2 * n_relations * {n}) (band then level ratios). Got {x.shape}.")
        band, level = np.split(-np.log(np.maximum(x, 1.0)).reshape(x.shape[0], -1, n), 2, axis=1)
        return band.sum(axis=1) + self.level_weight * level.sum(axis=1)

    def fit(self, X: np.ndarray, y: Sequence[str] | np.ndarray, classes: Sequence[str]) -> ParityRule:
        """Fit the temperature on windows ``X`` (n, n_relations * n_states) of states ``y``; returns self."""
        self.classes_ = np.asarray(list(classes), dtype=str)
        index = {c: i for i, c in enumerate(self.classes_.tolist())}
        labels = np.asarray(y).astype(str)
        unknown = sorted(set(labels.tolist()) - set(index))
        if unknown:
            raise DataError(f"every label in y must be one of classes. Got unknown labels {unknown}.")
        target = np.array([index[v] for v in labels.tolist()], dtype=np.int64)
        self.temperature_ = fit_temperature(self._logits(X), target)
        return self

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """Probabilities, shape (n, n_states); NaN rows stay NaN."""
        if not hasattr(self, "temperature_"):
            raise NotFittedError("ParityRule must be fitted before use. Call fit(X, y, classes) first.")
        z = self._logits(X) / self.temperature_
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
        """Inverse of :meth:`to_dict`."""
        try:
            rule = cls(**data.get("params", {}))
            rule.classes_ = np.asarray(data["classes"], dtype=str)
            rule.temperature_ = float(data["temperature"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"parity rule must have classes and temperature. Missing/bad: {exc}.") from None
        return rule


class _BandColumns:
    """The open-set rule seen through the band-box half of ``transform_with_levels`` (for :func:`judge`)."""

    def __init__(self, rule: OpenSetRule) -> None:
        self.rule = rule

    @staticmethod
    def _band(features: np.ndarray) -> np.ndarray:
        f = np.atleast_2d(np.asarray(features, dtype=np.float64))
        return f[:, : f.shape[1] // 2]

    def score(self, features: np.ndarray) -> np.ndarray:
        """Open-set score of the band-box ratios, shape (n,)."""
        return self.rule.score(self._band(features))

    def is_unknown(self, features: np.ndarray, probabilities: np.ndarray | None = None) -> np.ndarray:
        """Rejection on the band-box ratios, shape (n,)."""
        return self.rule.is_unknown(self._band(features), probabilities)


class ConditionModel:
    """Raw windows in, verdicts out: :class:`ConditionFeatures` + decision + :class:`OpenSetRule`.

    Parameters
    ----------
    features : ConditionFeatures, optional
        Unfitted template (``kind="scores"``); default ``ConditionFeatures()``.
    classifier : HealthClassifier, optional
        Unfitted template; None (default) decides with :class:`ParityRule`.
    open_set : OpenSetRule, optional
        Unfitted template; default ``OpenSetRule(quantile=0.995, margin=3.0)``.

    Attributes
    ----------
    features_, decision_, open_set_
        The fitted parts.
    """

    def __init__(self, *, features: ConditionFeatures | None = None, classifier: HealthClassifier | None = None,
                 open_set: OpenSetRule | None = None) -> None:
        self.features = features
        self.classifier = classifier
        self.open_set = open_set

    def fit(self, windows_by_state: Mapping[str, np.ndarray]) -> ConditionModel:
        """Fit all parts on raw windows per state, shape (n_k, window, 4); returns self."""
        template = self.features or ConditionFeatures()
        self.features_ = ConditionFeatures(**{**template.get_params(), "kind": "scores"}).fit(windows_by_state)
        states = list(self.features_.states_)
        blocks = [self.features_.transform_with_levels(windows_by_state[s]) for s in states]
        X = np.concatenate(blocks)
        y = np.repeat(np.asarray(states), [b.shape[0] for b in blocks])
        valid = np.all(np.isfinite(X), axis=1)
        X, y = X[valid], y[valid]
        if self.classifier is None:
            rule = ParityRule(level_weight=self.features_.level_weight)
            self.decision_: ParityRule | HealthClassifier = rule.fit(X, y, states)
        else:
            self.decision_ = HealthClassifier(**self.classifier.get_params()).fit(X, y, classes=states)
        template_rule = self.open_set or OpenSetRule(quantile=0.995, margin=3.0)
        self.open_set_ = OpenSetRule(**template_rule.get_params()).fit(_BandColumns._band(X), y, states)
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "open_set_"):
            raise NotFittedError("ConditionModel must be fitted before use. Call fit(...) or ConditionModel.load(dir).")

    def predict(self, windows: np.ndarray) -> np.ndarray:
        """State per raw window, shape (n,): a trained state, ``unknown`` or ``invalid``."""
        return np.asarray([v.state for v in self.judge(windows)])

    def judge(self, windows: np.ndarray) -> list[Verdict]:
        """Verdicts of raw windows, shape (n_windows, window, 4)."""
        self._check_fitted()
        features = self.features_.transform_with_levels(windows)
        reasons = self.features_.window_reasons(windows)
        return judge(features, cast(Any, self.decision_), cast(Any, _BandColumns(self.open_set_)), reasons)

    def score(self, rec_windows: np.ndarray, n_samples: int | None = None) -> tuple[np.ndarray, list[Verdict]]:
        """Window starts (sample index) and verdicts, like :meth:`HealthModel.score`.

        Parameters
        ----------
        rec_windows : ndarray, shape (n_windows, window, 4)
            From :func:`~hydrowatch.condition.features.windows_from_recording`.
        n_samples : int, optional
            Length of the recording; default ``window + (n_windows − 1)·hop``.
        """
        self._check_fitted()
        w = np.asarray(rec_windows)
        n = n_samples if n_samples is not None else self.features_.window + (w.shape[0] - 1) * self.features_.hop
        return self.features_.window_starts(n), self.judge(w)

    def save(self, directory: str | Path) -> None:
        """Write the parts into ``directory`` (created if missing)."""
        self._check_fitted()
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        self.features_.save(d / FILES["features"])
        if isinstance(self.decision_, ParityRule):
            (d / FILES["rule"]).write_text(json.dumps(self.decision_.to_dict(), indent=1))
        else:
            self.decision_.save(d / FILES["classifier"])
        (d / FILES["open_set"]).write_text(json.dumps(self.open_set_.to_dict(), indent=1))

    @classmethod
    def load(cls, directory: str | Path) -> ConditionModel:
        """Read a directory written by :meth:`save`."""
        d = Path(directory)
        needed = [FILES["features"], FILES["open_set"]]
        missing = [n for n in needed if not (d / n).is_file()]
        if missing or not ((d / FILES["rule"]).is_file() or (d / FILES["classifier"]).is_file()):
            raise DataError(f"a condition model directory must hold {needed} and {FILES['rule']} or "
                            f"{FILES['classifier']}. Missing {missing or 'the decision'}.", str(d))
        model = cls()
        model.features_ = ConditionFeatures.load(d / FILES["features"])
        try:
            if (d / FILES["rule"]).is_file():
                model.decision_ = ParityRule.from_dict(json.loads((d / FILES["rule"]).read_text()))
            else:
                model.decision_ = HealthClassifier.load(d / FILES["classifier"])
            model.open_set_ = OpenSetRule.from_dict(json.loads((d / FILES["open_set"]).read_text()))
        except json.JSONDecodeError as exc:
            raise DataError(f"condition model files must be valid JSON. Got: {exc}.", str(d)) from None
        return model
