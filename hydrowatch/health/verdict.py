"""Verdicts: what the model says about one window, and their smoothing over consecutive windows.

A verdict's ``state`` is one of the trained health states, ``"unknown"`` (the open-set rule found
no known state that explains the window) or ``"invalid"`` (the window cannot be judged: NaN
errors, a stuck sensor; ``reason`` says which). ``probability`` is the calibrated probability of
``state`` (None for unknown and invalid), ``probabilities`` the classifier's calibrated
probabilities of every trained state (empty for invalid).

Smoothing (:class:`VerdictSmoother`, river style) averages the last ``n_windows`` valid verdicts:
each contributes its probability vector over the trained states plus an ``unknown`` entry (1 for
an unknown verdict, 0 otherwise); the smoothed state is the largest average and its probability
that average. Invalid windows are skipped, so a gap does not flush the history. With the default
``n_windows=3`` a state change shows after two windows (10 s) instead of one, and isolated
misclassified windows (the warning/alert confusions of Figure 6.11) are outvoted.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.health.classifier import HealthClassifier
from hydrowatch.health.openset import OpenSetRule

UNKNOWN = "unknown"
INVALID = "invalid"


@dataclass(frozen=True)
class Verdict:
    """The health verdict of one window (or of a smoothed run of windows)."""

    state: str
    probability: float | None
    probabilities: dict[str, float] = field(default_factory=dict)
    reason: str | None = None
    novelty: float | None = None
    """Open-set score (above 1: no known state fits), when a rule was applied."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form: ``state``, ``probability``, ``probabilities`` and, when set, ``reason``, ``novelty``."""
        out: dict[str, Any] = {"state": self.state, "probability": self.probability,
                               "probabilities": dict(self.probabilities)}
        if self.reason is not None:
            out["reason"] = self.reason
        if self.novelty is not None:
            out["novelty"] = self.novelty
        return out


def judge(
    features: np.ndarray,
    classifier: HealthClassifier,
    open_set: OpenSetRule | None = None,
    reasons: Sequence[str | None] | None = None,
) -> list[Verdict]:
    """Verdicts of windows from their feature vectors.

    Parameters
    ----------
    features : ndarray, shape (n_windows, n_sensors * n_states)
        Relative entropies (``RelativeEntropyFeatures.transform``); NaN rows are invalid windows.
    classifier : HealthClassifier
    open_set : OpenSetRule, optional
        Without it no window reads ``unknown``.
    reasons : sequence of str or None, optional
        Why each window is invalid (``RelativeEntropyFeatures.window_reasons``).
    """
    f = np.atleast_2d(np.asarray(features, dtype=np.float64))
    proba = classifier.predict_proba(f)
    classes = classifier.classes_.tolist()
    novelty = open_set.score(f) if open_set is not None else np.full(f.shape[0], np.nan)
    unknown = open_set.is_unknown(f, proba) if open_set is not None else np.zeros(f.shape[0], dtype=bool)
    out = []
    for i in range(f.shape[0]):
        why = reasons[i] if reasons is not None else None
        if why is not None or not np.all(np.isfinite(f[i])):
            out.append(Verdict(INVALID, None, {}, why or "relative entropies are not finite"))
            continue
        probs = {c: float(p) for c, p in zip(classes, proba[i])}
        nov = None if np.isnan(novelty[i]) else float(novelty[i])
        if unknown[i]:
            out.append(Verdict(UNKNOWN, None, probs, None, nov))
        else:
            top = int(np.argmax(proba[i]))
            out.append(Verdict(classes[top], float(proba[i, top]), probs, None, nov))
    return out


class VerdictSmoother:
    """Average of the last ``n_windows`` valid verdicts of one machine (river style).

    Parameters
    ----------
    n_windows : int, default 3
        Verdicts averaged (1: no smoothing).
    """

    def __init__(self, *, n_windows: int = 3) -> None:
        if n_windows < 1:
            raise ParameterError(f"n_windows must be >= 1. Got {n_windows}.")
        self.n_windows = n_windows
        self._history: deque[np.ndarray] = deque(maxlen=n_windows)
        self._labels: list[str] | None = None

    def update(self, verdict: Verdict) -> None:
        """Add one window's verdict; invalid verdicts are skipped. Returns nothing."""
        if verdict.state == INVALID:
            return
        if self._labels is None:
            self._labels = [*verdict.probabilities, UNKNOWN]
        vector = np.array([verdict.probabilities.get(c, 0.0) for c in self._labels[:-1]] + [0.0])
        if verdict.state == UNKNOWN:
            vector[:] = 0.0
            vector[-1] = 1.0
        self._history.append(vector)

    def get(self) -> Verdict | None:
        """The smoothed verdict, or None before the first valid window."""
        if not self._history or self._labels is None:
            return None
        mean = np.mean(np.stack(self._history), axis=0)
        top = int(np.argmax(mean))
        probs = {c: float(p) for c, p in zip(self._labels[:-1], mean[:-1])}
        return Verdict(self._labels[top], float(mean[top]), probs)
