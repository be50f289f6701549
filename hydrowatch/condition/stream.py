"""One machine's verdicts from the evidence of its recent windows (river style): :class:`ConditionStream`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hydrowatch.condition.evidence import (
    SUPPORT_POINTS,
    EvidenceSmoother,
    distinct_points,
    operating_points,
    supported_states,
)
from hydrowatch.condition.model import ConditionModel
from hydrowatch.condition.ring import Ring
from hydrowatch.errors import NotFittedError
from hydrowatch.verdict import Verdict

Evidence = tuple[np.ndarray, np.ndarray, np.ndarray, int, int, np.ndarray, bool]
"""One stream's pooled evidence (:meth:`ConditionStream.evidence`), what :func:`judge_streams` stacks."""

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
    ``2 · (n_relations + 1) · n_states`` floats, as many flags (whether each window read ``unknown``
    alone), rows of n_states flags (which states it preferred to ``healthy`` alone) and operating points. Pooling,
    its open-set limit and its support: :mod:`hydrowatch.condition.evidence`, :class:`ConditionModel`
    (``pooled_excess``, :data:`~hydrowatch.condition.model.CLEAR_FACTOR`,
    :data:`~hydrowatch.condition.evidence.SUPPORT_POINTS`).

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
        # Rings allocated once, not a deque of per-window arrays: a scorer's ``leads`` rows were views that kept each
        # batch's whole array alive for n_windows windows (hydrowatch.condition.ring).
        self._alone = Ring(n_windows, (), bool)
        self._leads = Ring(n_windows, (len(model.decision_.classes_),), bool)
        self._points = Ring(n_windows)

    def update(self, window: np.ndarray) -> None:
        """Add one raw window, shape (window, 4 or 5; with or without the temperature as the stream was made).
        Returns nothing."""
        raw = np.asarray(window)[None]
        self.update_features(self.model.features_.transform_evidence(raw)[0], float(operating_points(raw)[0]))

    def update_features(self, features: np.ndarray, point: float, alone_unknown: bool | None = None,
                        leads: np.ndarray | None = None) -> None:
        """Add one window's ``transform_evidence`` row (NaN: invalid, skipped). Returns nothing.

        ``point``: the window's :func:`~hydrowatch.condition.evidence.operating_points` (NaN: it moved the command).
        ``alone_unknown``: whether the window alone read ``unknown`` (:meth:`ConditionModel.alone_unknown`), when
        a scorer of many machines has it from one batched call; None works it out. ``leads`` likewise: the window's
        row of :meth:`ConditionModel.alone_leads` (n_states,)."""
        row = np.asarray(features, dtype=np.float64).reshape(-1)
        self._smoother.update(row)
        if np.all(np.isfinite(row)):
            width = 2 * len(self.model.features_.feature_names_)
            if alone_unknown is None:
                alone_unknown = bool(self.model.alone_unknown(row[None, :width])[0])
            self._alone.add(bool(alone_unknown))
            self._leads.add(self.model.alone_leads(row[None, :width])[0] if leads is None else leads)
            self._points.add(float(point))

    def evidence(self) -> Evidence | None:
        """What :meth:`get` judges: the decision's and the open set's pooled scores and the last valid window's
        own ratios, each shape (n_ratios,) (all three that row when ``n_windows`` is 1), how many windows
        are pooled, how many of them read ``unknown`` alone, which states windows at enough operating points
        prefer to ``healthy`` (n_states,) (:func:`~hydrowatch.condition.evidence.supported_states`), and whether the
        pooled windows span that many operating points (else the open set judges the last window alone); None
        before any.

        A scorer of many machines stacks these rows and judges them in one call (:func:`judge_streams`).
        """
        pooled = self._smoother.get()
        latest = self._smoother.latest()
        if pooled is None or latest is None:
            return None
        current = latest[: pooled[0].size]
        supported = supported_states(self._leads.rows(), self._points.rows())
        if self.n_windows == 1:
            return current, current, current, 1, int(self._alone.latest()), supported, False
        spans = distinct_points(self._points.rows()) >= SUPPORT_POINTS
        return (pooled[0], pooled[1], current, len(self._smoother), int(self._alone.rows().sum()), supported,
                bool(spans))

    def get(self) -> Verdict | None:
        """The verdict of the pooled windows, or None before the first valid window."""
        evidence = self.evidence()
        return None if evidence is None else judge_streams(self.model, self.n_windows, [evidence])[0]


def judge_streams(model: ConditionModel, n_windows: int, evidence: Sequence[Evidence],
                  reasons: Sequence[str | None] | None = None) -> list[Verdict]:
    """Verdicts of many streams' :meth:`ConditionStream.evidence` rows in one call (same as each stream's ``get``).

    Parameters
    ----------
    n_windows : int
        The streams' ``n_windows`` (1: each row judged alone).
    evidence : sequence of (decision, open_set, current, windows pooled, of them read ``unknown`` alone, supported,
    spans)
        Rows of shape (n_ratios,), NaN rows invalid windows; ``supported`` (n_states,) and ``spans`` as in
        :meth:`ConditionStream.evidence`.
    reasons : sequence of str or None, optional
        Why a window is invalid (its verdict then says so).
    """
    decision, open_set, current = (np.stack([e[i] for e in evidence]) for i in range(3))
    if n_windows == 1:
        return model.judge_evidence(current, current, reasons)
    return model.judge_pooled(decision, open_set, current, reasons, windows=np.array([e[3] for e in evidence]),
                              support=np.array([e[4] for e in evidence]), supported=np.stack([e[5] for e in evidence]),
                              spans=np.array([e[6] for e in evidence], dtype=bool))
