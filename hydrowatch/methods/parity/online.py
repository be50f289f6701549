"""The parity method online: closed raw windows of the fleet judged by the condition model, pooled or not.

The fleet driver (:class:`~hydrowatch.training.window_fleet.WindowFleet`) keeps every machine's window in
progress in one fleet-wide array and hands the windows that close to :meth:`ParityJudge.judge` in
batches: the evidence of each window (one :meth:`ConditionFeatures.transform_evidence` call per batch
and model: each machine is pooled and judged by its own commissioned model when it has one), the
verdict from the window alone (``smoothing`` 1) or pooled over the machine's last ``smoothing`` valid
windows (one :class:`~hydrowatch.condition.stream.ConditionStream` per machine, judged in one
:func:`~hydrowatch.condition.stream.judge_streams` call per model). A break does not flush the pooled
evidence (as :class:`ConditionStream` skips invalid windows); the oil temperature coming or going
(its boxes differ) starts the pool again. A chunk without the temperature, for a bundle that reads
it, has it unknown (NaN, not a break: the leak boxes widened by the oil's range,
:mod:`hydrowatch.condition.oil`). A sensor the model does not read (trained on a subset) is NaN when a
chunk lacks it, never a break: the relations fill it.

Verdicts equal :meth:`ConditionModel.judge` of the same windows, pooled or not (tested). Asked (the scorer's
``…/expected``), :meth:`ParityJudge.expected` gives what each machine's healthy unit expected its sensors to read
(:mod:`hydrowatch.condition.predictions`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from hydrowatch.condition.degradation_stream import DegradationStream
from hydrowatch.condition.estimates import ParityEstimates
from hydrowatch.condition.evidence import operating_points
from hydrowatch.condition.layout import CHANNELS as WINDOW_CHANNELS
from hydrowatch.condition.layout import TEMPERATURE, WIDTH
from hydrowatch.condition.model import ConditionModel
from hydrowatch.condition.oil import temperature_known
from hydrowatch.condition.predictions import expected_sensors
from hydrowatch.condition.stream import ConditionStream, Evidence, judge_streams
from hydrowatch.errors import ParameterError
from hydrowatch.expected import ExpectedWindow
from hydrowatch.verdict import Verdict

UNKNOWN_TEMPERATURE = float("nan")
"""Oil temperature of a chunk without one when a parity bundle uses it: unknown (the window is judged with the
leak boxes widened by the oil's range, :mod:`hydrowatch.condition.oil`)."""


class ParityJudge:
    """Closed raw windows of many machines → verdicts and relation scores (module docstring).

    Parameters
    ----------
    model : ConditionModel
        The fleet's condition model.
    temperature : bool
        Whether the windows carry the oil temperature (5th column; unknown, NaN, when a chunk has none).
    window, hop : int
        Samples per window and between window starts.
    smoothing : int, default 1
        Valid windows of a machine pooled in each verdict (1: each window alone).
    unit_model : callable, optional
        Machine (``fleet/machine``) → its commissioned :class:`ConditionModel`, or None for the fleet model
        (:class:`hydrowatch.training.commissioning.Commissionings`). A commissioned model shares the fleet
        model's states, but its boxes (which pooling clips to) and its open-set pooling differ: each machine is
        pooled and judged by its own model.
    """

    def __init__(self, model: ConditionModel, temperature: bool, window: int, hop: int, *, smoothing: int = 1,
                 unit_model: Callable[[str], ConditionModel | None] | None = None) -> None:
        if int(smoothing) != smoothing or smoothing < 1:
            raise ParameterError(f"smoothing must be an integer >= 1. Got {smoothing!r}; 1 judges each window alone.")
        self.model, self.window, self.hop = model, window, hop
        self.columns = list(WINDOW_CHANNELS)
        # the window layout keeps every sensor's column; one the model does not read may be absent (NaN)
        self.defaults: dict[str, float] = {c: float("nan") for c in WINDOW_CHANNELS[1:]
                                           if c not in model.features_.sensors}
        if temperature:
            self.columns.append(TEMPERATURE)
            self.defaults[TEMPERATURE] = UNKNOWN_TEMPERATURE
        self.smoothing = int(smoothing)
        self.unit_model = unit_model
        self.shape = (len(model.features_.relations_), len(model.features_.states_))
        self._pools: dict[str, ConditionStream] = {}
        self._indices: dict[str, DegradationStream] = {}

    def _models(self, machines: Sequence[str]) -> list[ConditionModel]:
        """Each machine's model: its commissioned one, or the fleet model."""
        if self.unit_model is None:
            return [self.model] * len(machines)
        return [self.unit_model(m) or self.model for m in machines]

    def judge(self, raw: np.ndarray, machines: Sequence[str]
              ) -> list[tuple[Verdict, np.ndarray, dict[str, Any] | None]]:
        """Verdicts, relation scores (n_relations, n_states) and degradation indices (None where invalid;
        :class:`~hydrowatch.condition.degradation_stream.DegradationStream`) of closed windows ``raw`` (m, window,
        n_columns)."""
        features = self.model.features_
        width = 2 * len(features.feature_names_)
        models = self._models(machines)
        known = temperature_known(raw, WIDTH) if TEMPERATURE in self.columns else np.zeros(len(raw), dtype=bool)
        rows = np.empty((len(raw), features.evidence_width()))
        verdicts: list[Verdict | None] = [None] * len(raw)
        indices: list[dict[str, Any] | None] = [None] * len(raw)
        for model in {id(m): m for m in models}.values():  # each machine by its own (commissioned) model
            mine = np.flatnonzero([m is model for m in models])
            found, valid, estimates = model.features_.evidence_and_estimates(raw[mine])
            rows[mine] = found
            for i, index in zip(mine.tolist(), self._degradation(model, [machines[i] for i in mine.tolist()], valid,
                                                                  estimates)):
                indices[i] = index
            reasons = model.features_.window_reasons(raw[mine])
            unknown_alone = model.alone_unknown(found[:, :width])
            leads = model.alone_leads(found[:, :width])  # one batched call, like the flags above
            points = operating_points(raw[mine])
            evidence: list[Evidence] = []
            everything = np.ones(len(features.states_), dtype=bool)  # a window alone asks for no support
            for i, why, novel, point, lead in zip(mine.tolist(), reasons, unknown_alone.tolist(), points.tolist(),
                                                  leads):
                row, machine = rows[i], machines[i]
                alone = (row[:width], row[:width], row[:width], 1, int(novel), everything, False)
                if self.smoothing == 1:
                    evidence.append(alone)
                    continue
                pool = self._pools.get(machine)
                if pool is None or pool.model is not model or pool.temperature != bool(known[i]):
                    # the oil temperature came or went (its boxes differ): the pool starts again
                    pool = self._pools[machine] = ConditionStream(model, n_windows=self.smoothing,
                                                                  temperature=bool(known[i]))
                pool.update_features(row, point, novel, lead)
                got = pool.evidence() if why is None and np.all(np.isfinite(row)) else None
                evidence.append(got if got is not None else alone)
            for i, v in zip(mine.tolist(), judge_streams(model, self.smoothing, evidence, reasons)):
                verdicts[i] = v
        band = rows[:, : width // 2]
        out: list[tuple[Verdict, np.ndarray, dict[str, Any] | None]] = []
        for maybe, s, index in zip(verdicts, band, indices):
            assert maybe is not None
            out.append((maybe, s.reshape(self.shape), index))
        return out

    def expect(self) -> None:
        """Nothing to get ready: the raw windows hold every sensor as measured."""

    def expected(self, raw: np.ndarray, machines: Sequence[str]) -> list[ExpectedWindow | None]:
        """What each machine's (commissioned) healthy unit expected the sensors of its closed window ``raw`` (m,
        window, n_columns) to read (:func:`~hydrowatch.condition.predictions.expected_sensors`); None where the
        window cannot be judged."""
        models = self._models(machines)
        out: list[ExpectedWindow | None] = [None] * len(raw)
        for model in {id(m): m for m in models}.values():
            mine = np.flatnonzero([m is model for m in models])
            for i, found in zip(mine.tolist(), expected_sensors(model.features_, raw[mine])):
                out[i] = found
        return out

    def _degradation(self, model: ConditionModel, machines: Sequence[str], valid: np.ndarray,
                     estimates: ParityEstimates | None) -> list[dict[str, Any] | None]:
        """Each window's degradation index (None where invalid), from its machine's :class:`DegradationStream`
        (started again when the machine's model changes, as ``score`` starts with a recording)."""
        out: list[dict[str, Any] | None] = [None] * len(machines)
        if estimates is None:
            return out
        for k, i in enumerate(np.flatnonzero(valid).tolist()):
            machine = machines[i]
            stream = self._indices.get(machine)
            if stream is None or stream.features is not model.features_:
                stream = self._indices[machine] = DegradationStream(model.features_)
            out[i] = stream.update(*({f: float(v[k]) for f, v in part.items()}
                                     for part in (estimates.severity, estimates.mse, estimates.curvature)))
        return out
