"""Open set for cycles: a cycle that no known condition of the component explains reads ``unknown``.

The rule: a cycle of known condition ``k`` lies near ``k``'s training centroid in the classifier's
discriminant space (:meth:`ComponentClassifier.distances`); a condition never trained on lies far
from every centroid. Per known condition, ``threshold_k = margin * quantile_q`` of the distances of
*calibration* cycles of ``k`` to their own centroid, where the calibration cycles are the last 30 %
of each condition's training cycles scored by a classifier fitted on the first 70 % (the honest
split inside the training cycles: unseen cycles, not the fitted ones, set the scale). A cycle is
``unknown`` when ``min_k distance_k / threshold_k > 1``.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from hydrowatch.cycles.classify import ComponentClassifier
from hydrowatch.cycles.splits import ordered_split
from hydrowatch.errors import NotFittedError, ParameterError

UNKNOWN = "unknown"


class OpenSetComponent:
    """A :class:`ComponentClassifier` that answers ``unknown`` for cycles far from every known condition.

    Parameters
    ----------
    classifier : ComponentClassifier
        Unfitted; copied, never changed.
    quantile : float, default 0.99
        Quantile of a known condition's calibration distances that sets its threshold.
    margin : float, default 1.5
        Factor on that quantile (> 1 keeps rare known cycles in).
    """

    def __init__(self, classifier: ComponentClassifier, *, quantile: float = 0.99, margin: float = 1.5) -> None:
        self.classifier = classifier
        self.quantile = quantile
        self.margin = margin

    def fit(self, values: np.ndarray, labels: np.ndarray, nuisance: np.ndarray | None = None) -> OpenSetComponent:
        """Calibrate the thresholds, then fit the classifier on every training cycle (recording order)."""
        if not 0.0 < self.quantile <= 1.0 or self.margin <= 0:
            raise ParameterError(f"quantile must be in (0, 1] and margin > 0. Got {self.quantile}, {self.margin}.")
        fit_part, check = ordered_split(labels)
        inner = copy.deepcopy(self.classifier).fit(
            values[fit_part], labels[fit_part], None if nuisance is None else nuisance[fit_part]
        )
        distances = inner.distances(values[check])
        own = distances[np.arange(len(check)), np.searchsorted(inner.classes_, labels[check])]
        self.thresholds_ = np.array(
            [self.margin * np.quantile(own[labels[check] == c], self.quantile) for c in inner.classes_]
        )
        self.classifier_ = copy.deepcopy(self.classifier).fit(values, labels, nuisance)
        return self

    def predict(self, values: np.ndarray) -> np.ndarray:
        """Each cycle's condition, or ``"unknown"``; shape (n_cycles,), dtype object."""
        if not hasattr(self, "classifier_"):
            raise NotFittedError("OpenSetComponent must be fitted before predict. Call fit first.")
        out = self.classifier_.predict(values).astype(object)
        out[self.novelty(values) > 1.0] = UNKNOWN
        return out

    def novelty(self, values: np.ndarray) -> np.ndarray:
        """``min_k distance_k / threshold_k`` per cycle, shape (n_cycles,); above 1 reads unknown."""
        if not hasattr(self, "classifier_"):
            raise NotFittedError("OpenSetComponent must be fitted before novelty. Call fit first.")
        return np.asarray((self.classifier_.distances(values) / self.thresholds_).min(axis=1))

    def to_state(self) -> dict[str, Any]:
        """Parameters and fitted arrays (:mod:`hydrowatch.cycles.state`); the unfitted ``classifier`` as its
        parameters."""
        if not hasattr(self, "classifier_"):
            raise NotFittedError("OpenSetComponent must be fitted before to_state. Call fit first.")
        parameters = {k: getattr(self.classifier, k) for k in ComponentClassifier.PARAMETERS}
        if parameters["channels"] is not None:
            parameters["channels"] = [int(c) for c in parameters["channels"]]
        return {"quantile": self.quantile, "margin": self.margin, "classifier": parameters,
                "thresholds_": self.thresholds_, "classifier_": self.classifier_.to_state()}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> OpenSetComponent:
        """The inverse of :meth:`to_state`."""
        out = cls(ComponentClassifier(**state["classifier"]), quantile=state["quantile"], margin=state["margin"])
        out.thresholds_ = state["thresholds_"]
        out.classifier_ = ComponentClassifier.from_state(state["classifier_"])
        return out
