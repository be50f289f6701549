"""How a :class:`~hydrowatch.condition.model.ConditionModel` judges rows of (pooled) parity scores: its decision and
open-set rule each seen through their columns (:class:`Columns`), with the pooled open-set limit and the clear rule.

Moved out of ``model.py`` (one job: the rules on pooled evidence); ``model`` re-exports the constants.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from hydrowatch.condition.rule import ParityRule

POOLED_EXCESS = 2.0
"""Default open-set limit on pooled evidence, min_k Σ_r (F̄[r, k] − 1) (:class:`ConditionModel`). Calibrated on the
spread that units and days bring (issue 11, tuning population seed 2033: 20 units of ±20 % parameters, each
scored on a later day, and 19 units commissioned from another unit's model): pooled over 12 windows, known
states' excess reached 1.57 at its 99.9th percentile (13 states, own models; 1.26 commissioned on filtered noise,
valve_leak_alert on duty cycles the largest, a consistent misfit of 1.0–1.6, not a severity that wanders), while
the unseen faults' 10th percentile was 11.5 (own models) and 2.3–3.6 (commissioned). The earlier limit 1.0 (set on
default-parameter units) read those known states ``unknown`` pooled although every single window named them;
docs/unseen-units.md."""
CLEAR_FACTOR = 1.5
"""A pool reads ``unknown`` only when at least one of its windows read ``unknown`` alone, or when its excess is above
``CLEAR_FACTOR`` × ``pooled_excess`` (3.0 by default): pooled evidence extends a novelty that some window showed to the
windows of the pool that did not load the part, it does not make one (issue 11: pooling never makes a verdict worse).
A known state whose severity sits just outside its band (a spread severity on a later day, a commissioned unit's model
error) misfits by a little in *every* window, which no window alone rejects but the pooled mean does (report seed 2038,
7 states, spread severities: one unit's pump_leak_alert at a consistent excess of 2.85, 94.6 % right per window, 93.2
pooled); an unseen fault shows in the windows that load its part. Without the clear limit the same rule cost the open
set up to 5.6 points on the worst unit (2038). Measured on the tuning population (seed 2033, 20 units, evidence rows
of bench_unseen_units.py re-judged at the limit 2.0): changes of at most 0.8 points (13 states commissioned on a duty
cycle, worst unit 90.0 → 90.8; the commissioned open set 93.1 → 92.8 and 91.7 → 91.1 for the median unit);
docs/unseen-units.md, "Pooling never makes a verdict worse"."""

CLEAR_WINDOWS = 3
"""The clear limit (:data:`CLEAR_FACTOR`) rejects only pools of at least this many windows. Over one or two windows
the pooled mean excess is a single window's statistic, which the per-window open-set rule has already judged, and
the limit was set on the spread of 12-window pools: at the start of a recording (the pool's first windows) it read
known machines ``unknown`` that no window alone rejected (fresh seed 2046: an own 7-state unit's pump_leak_alert in
its first window, a duty-commissioned unit's in its first two). Re-judged on the kept rows of seeds 2033 (tuning),
2045 and 2046: no worst unit lower, pooled below per window on 2 units fewer, the open set 0.2 points lower for the
median unit (98.1 → 97.9 on 2045, 97.4 → 97.2 on 2046; docs/unseen-units.md)."""


class Columns:
    """A decision or open-set rule seen through columns [lo, hi) of the feature rows (for :func:`judge`).

    :meth:`~hydrowatch.condition.model.ConditionModel.judge_evidence` hands :func:`judge` one row per window holding the
    decision's scores (band then level ratios) followed by the open-set rule's (band half used);
    each part reads its own columns. With ``limit`` the open set also rejects rows whose best known
    state leaves a summed excess min_k Σ_r (F[r, k] − 1) above it (pooled evidence); with ``support`` (n,), how
    many windows of each pooled row read ``unknown`` alone, a row none of whose windows did is rejected only above
    :data:`CLEAR_FACTOR` × ``limit`` (its novelty score then at most 1), and then only if it pools at least
    :data:`CLEAR_WINDOWS` windows (``windows``, (n,)).
    """

    def __init__(self, part: Any, lo: int, hi: int, limit: float | None = None,
                 windows: np.ndarray | None = None, support: np.ndarray | None = None) -> None:
        self.part, self.lo, self.hi, self.limit, self.windows = part, lo, hi, limit, windows
        self.support = support

    @property
    def classes_(self) -> np.ndarray:
        """The decision's states."""
        return cast(np.ndarray, self.part.classes_)

    def _cut(self, features: np.ndarray) -> np.ndarray:
        return np.atleast_2d(np.asarray(features, dtype=np.float64))[:, self.lo:self.hi]

    def _excess(self, features: np.ndarray) -> np.ndarray:
        f = self._cut(features)
        return cast(np.ndarray, (f - 1.0).reshape(f.shape[0], -1, len(self.part.states_)).sum(axis=1).min(axis=1))

    def predict_proba(self, features: np.ndarray) -> np.ndarray:
        """The decision's probabilities, shape (n, n_states) (pooled rows weighted by their windows, ParityRule)."""
        if self.windows is not None and isinstance(self.part, ParityRule):
            return self.part.predict_proba(self._cut(features), self.windows)
        return cast(np.ndarray, self.part.predict_proba(self._cut(features)))

    def _unsupported(self, features: np.ndarray) -> np.ndarray:
        """Pooled rows none of whose windows read unknown alone and whose excess is not clear (n,) (class docstring)."""
        if self.limit is None or self.support is None:
            return np.zeros(np.atleast_2d(features).shape[0], dtype=bool)
        clear = np.nan_to_num(self._excess(features)) > CLEAR_FACTOR * self.limit
        if self.windows is not None:
            clear &= np.asarray(self.windows) >= CLEAR_WINDOWS
        return cast(np.ndarray, (np.asarray(self.support) <= 0) & ~clear)

    def score(self, features: np.ndarray) -> np.ndarray:
        """Open-set score, shape (n,): above 1 means unknown."""
        s = cast(np.ndarray, self.part.score(self._cut(features)))
        if self.limit is None:
            return s
        s = np.maximum(s, self._excess(features) / self.limit)
        return np.where(self._unsupported(features), np.minimum(s, 1.0), s)

    def is_unknown(self, features: np.ndarray, probabilities: np.ndarray | None = None) -> np.ndarray:
        """Open-set rejection, shape (n,)."""
        unknown = cast(np.ndarray, self.part.is_unknown(self._cut(features), probabilities))
        if self.limit is None:
            return unknown
        return (unknown | (np.nan_to_num(self._excess(features)) > self.limit)) & ~self._unsupported(features)
