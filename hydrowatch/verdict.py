"""Verdicts: what a health method says about one window, and their smoothing over consecutive windows.

Shared by every health method, the scorer and the reports (so it lives above any one method's
package). A verdict's ``state`` is one of the trained health states, ``"unknown"`` (the open-set
rule found no known state that explains the window) or ``"invalid"`` (the window cannot be
judged: NaN values, a stuck sensor; ``reason`` says which). ``probability`` is the calibrated
probability of ``state`` (None for unknown and invalid), ``probabilities`` the calibrated
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
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError

UNKNOWN = "unknown"
"""State of a window that no trained state explains."""
INVALID = "invalid"
"""State of a window that cannot be judged (its verdict's ``reason`` says why)."""


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
