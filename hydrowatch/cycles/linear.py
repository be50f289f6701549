"""A fitted linear discriminant as plain arrays: what :class:`~hydrowatch.cycles.ComponentClassifier` predicts with.

scikit-learn fits it (``LinearDiscriminantAnalysis``, solver ``svd``, optionally after a ``StandardScaler``);
:meth:`LinearDiscriminant.from_fitted` keeps only its arrays, so a fitted classifier is numbers that a bundle stores
as JSON (:mod:`hydrowatch.cycles.state`) instead of a pickle of scikit-learn objects. The maths are
scikit-learn's (version 1.x, ``sklearn/discriminant_analysis.py`` and ``LinearClassifierMixin``):

- standardise: ``z = (x - mean) / scale`` (identity without a scaler);
- decision: ``d = z @ coef.T + intercept``, one column per class (one column, the second class's log-odds, for two);
- probabilities: softmax of ``d`` (two classes: ``[1 - σ(d), σ(d)]``), the predicted class its largest;
- discriminant coordinates: ``(z - xbar) @ scalings`` truncated to ``components`` columns.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.special import expit

from hydrowatch.errors import ParameterError


class LinearDiscriminant:
    """A fitted (standardiser +) linear discriminant, as arrays.

    Parameters
    ----------
    classes : ndarray, shape (n_classes,)
        Class labels, in the order of the probability columns.
    coef : ndarray, shape (n_classes, n_features) or (1, n_features) for two classes
    intercept : ndarray, shape (n_classes,) or (1,)
    xbar : ndarray, shape (n_features,)
        Overall mean of the (standardised) training features.
    scalings : ndarray, shape (n_features, rank)
        Discriminant directions.
    components : int
        Discriminant coordinates kept by :meth:`transform` (at most ``n_classes - 1``).
    mean, scale : ndarray, shape (n_features,), optional
        The standardiser's mean and scale (both or neither).
    """

    def __init__(self, *, classes: np.ndarray, coef: np.ndarray, intercept: np.ndarray, xbar: np.ndarray,
                 scalings: np.ndarray, components: int, mean: np.ndarray | None = None,
                 scale: np.ndarray | None = None) -> None:
        self.classes = classes
        self.coef = coef
        self.intercept = intercept
        self.xbar = xbar
        self.scalings = scalings
        self.components = components
        self.mean = mean
        self.scale = scale

    @classmethod
    def from_fitted(cls, model: Any) -> LinearDiscriminant:
        """The arrays of a fitted ``LinearDiscriminantAnalysis`` (solver ``svd``) or of a pipeline of a
        ``StandardScaler`` and one."""
        steps = [step for _, step in model.steps] if hasattr(model, "steps") else [model]
        lda = steps[-1]
        if getattr(lda, "solver", None) != "svd" or len(steps) > 2:
            raise ParameterError(f"model must be an LDA with solver='svd', optionally after a StandardScaler. Got "
                                 f"{model!r}.")
        mean = scale = None
        if len(steps) == 2:
            scaler = steps[0]
            n = lda.coef_.shape[1]
            mean = np.asarray(scaler.mean_ if scaler.with_mean else np.zeros(n), dtype=np.float64)
            scale = np.asarray(scaler.scale_ if scaler.with_std else np.ones(n), dtype=np.float64)
        return cls(classes=np.asarray(lda.classes_), coef=np.asarray(lda.coef_, dtype=np.float64),
                   intercept=np.asarray(lda.intercept_, dtype=np.float64), xbar=np.asarray(lda.xbar_, np.float64),
                   scalings=np.asarray(lda.scalings_, dtype=np.float64),
                   components=int(lda.transform(lda.xbar_[None, :]).shape[1]),  # its public output width
                   mean=mean, scale=scale)

    def _standardised(self, x: np.ndarray) -> np.ndarray:
        return x if self.mean is None or self.scale is None else (x - self.mean) / self.scale

    def decision_function(self, x: np.ndarray) -> np.ndarray:
        """``z @ coef.T + intercept``: shape (n, n_classes), or (n,) for two classes (the second's log-odds)."""
        scores = self._standardised(x) @ self.coef.T + self.intercept
        return scores.reshape(-1) if scores.shape[1] == 1 else scores

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        """Probability of each class (``classes`` order), shape (n, n_classes)."""
        d = self.decision_function(x)
        if d.ndim == 1:
            p = expit(d)  # 1 / (1 + exp(-d)) without overflow far from the boundary
            return np.stack([1.0 - p, p], axis=1)
        e = np.exp(d - d.max(axis=1, keepdims=True))
        return np.asarray(e / e.sum(axis=1, keepdims=True))

    def predict(self, x: np.ndarray) -> np.ndarray:
        """The most probable class per row, shape (n,)."""
        d = self.decision_function(x)
        return np.asarray(self.classes[(d > 0).astype(int) if d.ndim == 1 else d.argmax(axis=1)])

    def transform(self, x: np.ndarray) -> np.ndarray:
        """Discriminant coordinates, shape (n, ``components``)."""
        return np.asarray(((self._standardised(x) - self.xbar) @ self.scalings)[:, : self.components])

    def to_state(self) -> dict[str, Any]:
        """Parameters and arrays (:mod:`hydrowatch.cycles.state`)."""
        return {"classes": self.classes, "coef": self.coef, "intercept": self.intercept, "xbar": self.xbar,
                "scalings": self.scalings, "components": self.components, "mean": self.mean, "scale": self.scale}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> LinearDiscriminant:
        """The inverse of :meth:`to_state`."""
        return cls(**state)
