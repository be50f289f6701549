"""Open-set rejection: windows of a fault the model was never trained on read ``unknown``.

A classifier always answers one of the states it knows. The rule here looks at the relative
entropies themselves: a window of known state ``k`` is close to ``k``'s base distributions on
*every* sensor, so its **fit score** to state ``k``, ``s_k = sum over sensors of D(P_{sensor,k} || Q)``,
is small; a window of an unseen fault is far from every known state on at least one sensor.

Calibration (``fit``): per known state ``k``, ``threshold_k = margin * quantile_q(s_k)`` over that
state's calibration windows (use the classifier's train + validation windows; never the test ones).
Rejection: a window is ``unknown`` when ``min_k s_k / threshold_k > 1`` (no known state explains it),
or, optionally, when the classifier's top probability is below ``min_probability``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hydrowatch.errors import DataError, NotFittedError, ParameterError


class OpenSetRule:
    """Rejects windows that no known health state explains.

    Parameters
    ----------
    quantile : float, default 0.995
        Quantile of a known state's fit scores that sets its threshold.
    margin : float, default 1.5
        Factor on that quantile (>1 keeps rare known windows in).
    min_probability : float, default 0.0
        Also reject when the top class probability is below this (0: off).

    Attributes
    ----------
    states_ : tuple of str
    thresholds_ : ndarray, shape (n_states,)
        Fit-score threshold per state, nats.
    """

    def __init__(self, *, quantile: float = 0.995, margin: float = 1.5, min_probability: float = 0.0) -> None:
        self.quantile = quantile
        self.margin = margin
        self.min_probability = min_probability

    def get_params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {"quantile": self.quantile, "margin": self.margin, "min_probability": self.min_probability}

    def _fit_scores(self, features: np.ndarray, n_states: int) -> np.ndarray:
        f = np.asarray(features, dtype=np.float64)
        if f.ndim != 2 or f.shape[1] % n_states:
            raise DataError(f"features must be (n, n_sensors * {n_states}). Got {f.shape}.")
        return f.reshape(f.shape[0], -1, n_states).sum(axis=1)

    def fit(self, features: np.ndarray, y: Sequence[str] | np.ndarray, states: Sequence[str]) -> OpenSetRule:
        """Calibrate thresholds on known windows; returns self.

        Parameters
        ----------
        features : ndarray, shape (n, n_sensors * n_states)
            Relative entropies, sensor-major, states in the order of ``states``.
        y : array of str, shape (n,)
            True state of each window.
        states : sequence of str
            Known states, in feature order.
        """
        if not 0.5 <= self.quantile <= 1.0 or not self.margin > 0 or not 0.0 <= self.min_probability < 1.0:
            raise ParameterError(
                f"quantile must be in [0.5, 1], margin > 0 and min_probability in [0, 1). Got {self.quantile}, "
                f"{self.margin}, {self.min_probability}."
            )
        labels = np.asarray(y).astype(str)
        scores = self._fit_scores(features, len(states))
        if labels.shape != (scores.shape[0],):
            raise DataError(f"y must have one label per window ({scores.shape[0]}). Got shape {labels.shape}.")
        thresholds = np.empty(len(states))
        for k, state in enumerate(states):
            mine = scores[labels == state, k]
            mine = mine[np.isfinite(mine)]
            if mine.size < 2:
                raise DataError(f"state '{state}' must have at least 2 valid calibration windows. Got {mine.size}.")
            thresholds[k] = self.margin * np.quantile(mine, self.quantile)
        self.states_ = tuple(states)
        self.thresholds_ = thresholds
        return self

    def score(self, features: np.ndarray) -> np.ndarray:
        """``min_k s_k / threshold_k`` per window, shape (n,); above 1 means no known state fits."""
        if not hasattr(self, "thresholds_"):
            raise NotFittedError("OpenSetRule must be fitted before use. Call fit(features, y, states) first.")
        return (self._fit_scores(features, len(self.states_)) / self.thresholds_).min(axis=1)

    def is_unknown(self, features: np.ndarray, probabilities: np.ndarray | None = None) -> np.ndarray:
        """True where the window is rejected, shape (n,); NaN windows are not flagged (they are invalid)."""
        s = self.score(features)
        unknown = np.nan_to_num(s, nan=0.0) > 1.0
        if probabilities is not None and self.min_probability > 0:
            top = np.nan_to_num(np.asarray(probabilities).max(axis=1), nan=1.0)
            unknown |= top < self.min_probability
        return unknown

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"params": self.get_params(), "states": list(self.states_), "thresholds": self.thresholds_.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OpenSetRule:
        """Inverse of :meth:`to_dict`."""
        try:
            rule = cls(**data["params"])
            rule.states_ = tuple(data["states"])
            rule.thresholds_ = np.asarray(data["thresholds"], dtype=np.float64)
        except (KeyError, TypeError) as exc:
            raise DataError(f"open-set rule must have params, states and thresholds. Missing/bad: {exc}.") from None
        return rule
