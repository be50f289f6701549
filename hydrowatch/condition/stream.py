"""One machine's verdicts from the evidence of its recent windows (river style): :class:`ConditionStream`."""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np

from hydrowatch.condition.evidence import EvidenceSmoother
from hydrowatch.condition.model import ConditionModel
from hydrowatch.errors import NotFittedError
from hydrowatch.verdict import Verdict

POOLED_WINDOWS = 12
"""Default windows pooled per verdict (60 s at 5 s windows): what 13 states with severities spread in
their bands need on duty cycles (100 % once the pool is full) and what the open set needs for
look-alike valve faults in holds (docs/command-invariance.md, round 4). A new state is named after
about half a pool."""


class ConditionStream:
    """Verdicts of one machine whose evidence is pooled over its last ``n_windows`` valid windows.

    ``update`` takes each new raw window (or, for a scorer that batches many machines through
    ``model.features_.transform_evidence``, its row via ``update_features``) and returns nothing;
    ``get`` returns the current verdict, None before the first valid window. Invalid windows are
    skipped (a gap does not flush the history). State: at most ``n_windows`` rows of
    ``2 · (n_relations + 1) · n_states`` floats and as many flags (whether each window read ``unknown``
    alone). Pooling and its open-set limit: :mod:`hydrowatch.condition.evidence`, :class:`ConditionModel`
    (``pooled_excess``, :data:`~hydrowatch.condition.model.CLEAR_FACTOR`).

    Parameters
    ----------
    model : ConditionModel
        Fitted.
    n_windows : int, default :data:`POOLED_WINDOWS` (12)
        Valid windows pooled (1: each window alone). 6 (30 s) settles 13-state duty cycles at
        trained severities; 12 (60 s) is what severities spread in their bands and the open set need
        (docs/command-invariance.md).
    temperature : bool, default True
        Whether the machine's windows carry the oil temperature (False: the boxes of windows without
        it, :mod:`hydrowatch.condition.oil`).
    """

    def __init__(self, model: ConditionModel, *, n_windows: int = POOLED_WINDOWS, temperature: bool = True) -> None:
        if not hasattr(model, "open_set_"):
            raise NotFittedError("model must be a fitted ConditionModel. Call fit(...) or ConditionModel.load(dir).")
        self.model = model
        self.n_windows = n_windows
        self.temperature = temperature
        self._smoother = EvidenceSmoother(n_windows=n_windows, layout=model.features_.evidence_layout(temperature))
        self._alone: deque[bool] = deque(maxlen=n_windows)

    def update(self, window: np.ndarray) -> None:
        """Add one raw window, shape (window, 4 or 5; with or without the temperature as the stream was made).
        Returns nothing."""
        self.update_features(self.model.features_.transform_evidence(np.asarray(window)[None])[0])

    def update_features(self, features: np.ndarray, alone_unknown: bool | None = None) -> None:
        """Add one window's ``transform_evidence`` row (NaN: invalid, skipped). Returns nothing.

        ``alone_unknown``: whether the window alone read ``unknown`` (:meth:`ConditionModel.alone_unknown`), when
        a scorer of many machines has it from one batched call; None works it out."""
        row = np.asarray(features, dtype=np.float64).reshape(-1)
        self._smoother.update(row)
        if np.all(np.isfinite(row)):
            if alone_unknown is None:
                width = 2 * len(self.model.features_.feature_names_)
                alone_unknown = bool(self.model.alone_unknown(row[None, :width])[0])
            self._alone.append(bool(alone_unknown))

    def evidence(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int] | None:
        """What :meth:`get` judges: the decision's and the open set's pooled scores and the last valid window's
        own ratios, each shape (n_ratios,) (all three that row when ``n_windows`` is 1), how many windows
        are pooled and how many of them read ``unknown`` alone; None before any.

        A scorer of many machines stacks these rows and judges them in one call (:func:`judge_streams`).
        """
        pooled = self._smoother.get()
        latest = self._smoother.latest()
        if pooled is None or latest is None:
            return None
        current = latest[: pooled[0].size]
        if self.n_windows == 1:
            return current, current, current, 1, int(self._alone[-1])
        return pooled[0], pooled[1], current, len(self._smoother), sum(self._alone)

    def get(self) -> Verdict | None:
        """The verdict of the pooled windows, or None before the first valid window."""
        evidence = self.evidence()
        return None if evidence is None else judge_streams(self.model, self.n_windows, [evidence])[0]


def judge_streams(model: ConditionModel, n_windows: int,
                  evidence: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, int, int]],
                  reasons: Sequence[str | None] | None = None) -> list[Verdict]:
    """Verdicts of many streams' :meth:`ConditionStream.evidence` rows in one call (same as each stream's ``get``).

    Parameters
    ----------
    n_windows : int
        The streams' ``n_windows`` (1: each row judged alone).
    evidence : sequence of (decision, open_set, current, windows pooled, of them read ``unknown`` alone)
        Rows of shape (n_ratios,); NaN rows are invalid windows.
    reasons : sequence of str or None, optional
        Why a window is invalid (its verdict then says so).
    """
    decision, open_set, current = (np.stack([e[i] for e in evidence]) for i in range(3))
    if n_windows == 1:
        return model.judge_evidence(current, current, reasons)
    return model.judge_pooled(decision, open_set, current, reasons, windows=np.array([e[3] for e in evidence]),
                              support=np.array([e[4] for e in evidence]))
