"""The parity method online: closed raw windows of the fleet judged by the condition model, pooled or not.

The fleet driver (:class:`~hydrowatch.training.window_fleet.WindowFleet`) keeps every machine's window in
progress in one fleet-wide array and hands the windows that close to :meth:`ParityJudge.judge` in
batches: the evidence of each window (one :meth:`ConditionFeatures.transform_evidence` call per batch,
by the machine's commissioned model when it has one), the verdict from the window alone (``smoothing``
1) or pooled over the machine's last ``smoothing`` valid windows (one
:class:`~hydrowatch.condition.stream.ConditionStream` per machine, judged for all machines in one
:func:`~hydrowatch.condition.stream.judge_streams` call). A break does not flush the pooled evidence
(as :class:`ConditionStream` skips invalid windows).

Verdicts equal :meth:`ConditionModel.judge` of the same windows, pooled or not (tested).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from hydrowatch.condition.estimates import CHANNELS as WINDOW_CHANNELS
from hydrowatch.condition.estimates import TEMPERATURE
from hydrowatch.condition.model import ConditionModel
from hydrowatch.condition.stream import ConditionStream, judge_streams
from hydrowatch.errors import ParameterError
from hydrowatch.verdict import Verdict

REFERENCE_TEMPERATURE_C = 40.0
"""Oil temperature assumed when a parity bundle uses it and a chunk has none, °C (the relations' reference)."""


class ParityJudge:
    """Closed raw windows of many machines → verdicts and relation scores (module docstring).

    Parameters
    ----------
    model : ConditionModel
        The fleet's condition model.
    temperature : bool
        Whether the windows carry the oil temperature (5th column; 40 °C assumed when a chunk has none).
    window, hop : int
        Samples per window and between window starts.
    smoothing : int, default 1
        Valid windows of a machine pooled in each verdict (1: each window alone).
    unit_model : callable, optional
        Machine (``fleet/machine``) → its commissioned :class:`ConditionModel`, or None for the fleet model
        (:class:`hydrowatch.training.commissioning.Commissionings`). A commissioned model shares the fleet
        model's states, decision and open-set rule, so pooling and judging stay one call; only the features
        (the unit's parameters) differ.
    """

    def __init__(self, model: ConditionModel, temperature: bool, window: int, hop: int, *, smoothing: int = 1,
                 unit_model: Callable[[str], ConditionModel | None] | None = None) -> None:
        if int(smoothing) != smoothing or smoothing < 1:
            raise ParameterError(f"smoothing must be an integer >= 1. Got {smoothing!r}; 1 judges each window alone.")
        self.model, self.window, self.hop = model, window, hop
        self.columns = list(WINDOW_CHANNELS)
        self.defaults: dict[str, float] = {}
        if temperature:
            self.columns.append(TEMPERATURE)
            self.defaults[TEMPERATURE] = REFERENCE_TEMPERATURE_C
        self.smoothing = int(smoothing)
        self.unit_model = unit_model
        self.shape = (len(model.features_.relations_), len(model.features_.states_))
        self._pools: dict[str, ConditionStream] = {}

    def _evidence(self, raw: np.ndarray, machines: Sequence[str]) -> np.ndarray:
        """``transform_evidence`` rows of closed windows, each by its machine's model (commissioned or fleet)."""
        if self.unit_model is None:
            return self.model.features_.transform_evidence(raw)
        models = [self.unit_model(m) or self.model for m in machines]
        rows: np.ndarray | None = None
        for model in {id(m): m for m in models}.values():
            mine = np.array([m is model for m in models])
            part = model.features_.transform_evidence(raw[mine])
            rows = np.empty((raw.shape[0], part.shape[1])) if rows is None else rows
            rows[mine] = part
        assert rows is not None
        return rows

    def judge(self, raw: np.ndarray, machines: Sequence[str]) -> list[tuple[Verdict, np.ndarray]]:
        """Verdicts and relation scores (n_relations, n_states) of closed windows ``raw`` (m, window, n_columns)."""
        features = self.model.features_
        width = 2 * len(features.feature_names_)
        rows = self._evidence(raw, machines)
        reasons = features.window_reasons(raw)
        evidence: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]] = []
        for machine, row, why in zip(machines, rows, reasons):
            alone = (row[:width], row[:width], row[:width], 1)
            if self.smoothing == 1:
                evidence.append(alone)
                continue
            pool = self._pools.get(machine)
            if pool is None:
                pool = self._pools[machine] = ConditionStream(self.model, n_windows=self.smoothing)
            pool.update_features(row)
            got = pool.evidence() if why is None and np.all(np.isfinite(row)) else None
            evidence.append(got if got is not None else alone)
        verdicts = judge_streams(self.model, self.smoothing, evidence, reasons)
        band = rows[:, : width // 2]
        return [(v, s.reshape(self.shape)) for v, s in zip(verdicts, band)]
