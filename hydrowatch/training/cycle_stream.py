"""A cycles bundle on the bus: ``rig_cycles`` messages in, ``cycle_verdict`` messages out (docs/rigs.md, issue 17).

The scorer service hands each ``rig_cycles`` message of a machine to :meth:`CycleJudge.judge`; the verdicts are
the bundle's own (:meth:`hydrowatch.methods.cycles.CyclesMethod.judge_cycles`, the same as ``hydrowatch score``
of the same cycles), one row per cycle and component, with the cycle's label as ``truth`` when it carries one and the
component's healthy state (``healthy``, v2) so that watch, the web page and reports rank the verdict.
"""

from __future__ import annotations

import pyarrow as pa

from hydrowatch.errors import DataError
from hydrowatch.io.rig_cycles import cycles_from_batches
from hydrowatch.methods.cycles import CyclesMethod
from hydrowatch.schemas import CYCLE_VERDICT, wire_schema
from hydrowatch.training.bundle import ModelBundle


class CycleJudge:
    """Judge ``rig_cycles`` messages with a cycles bundle.

    Parameters
    ----------
    bundle : ModelBundle
        A bundle of the ``cycles`` method (``train --rig``).

    Raises
    ------
    DataError
        When the bundle is of another method.
    """

    def __init__(self, bundle: ModelBundle) -> None:
        method = bundle.health_method
        if not isinstance(method, CyclesMethod):
            raise DataError(f"rig cycles are judged by a cycles bundle (train --rig). Got a {bundle.method} bundle.",
                            bundle.version)
        self.method: CyclesMethod = method
        self.version = bundle.version

    def judge(self, batch: pa.RecordBatch, source: str) -> pa.RecordBatch:
        """The ``cycle_verdict`` message of one ``rig_cycles`` message (rows: cycle after cycle, each component in
        the bundle's order).

        Raises
        ------
        DataError
            As :func:`hydrowatch.io.rig_cycles.cycles_from_batches` (another rig, grid or channels, a label outside
            the description), naming ``source`` and the row.
        """
        cycles, index = cycles_from_batches([batch], self.method.rig, source)
        verdicts = self.method.judge_cycles(cycles.values)
        truth = self.method.truth(cycles.labels)
        length = self.method.rig.window.length_s
        rows: dict[str, list[object]] = {name: [] for name in CYCLE_VERDICT.names}
        for i, cycle in enumerate(index):
            for component, judged in verdicts.items():
                v = judged[i]
                row = {"cycle": int(cycle), "window_start": float(cycles.start_s[i]),
                       "window_end": float(cycles.start_s[i]) + length, "component": component, "state": v.state,
                       "probability": float(v.probability or 0.0),
                       "probabilities": [{"state": s, "probability": float(p)} for s, p in v.probabilities.items()],
                       "novelty": float(v.novelty if v.novelty is not None else float("nan")), "reason": v.reason,
                       "truth": truth[component][i] if component in truth else None,
                       "healthy": self.method.component_states[component][0], "model_version": self.version}
                for name, value in row.items():
                    rows[name].append(value)
        return pa.RecordBatch.from_pydict(rows, schema=wire_schema(CYCLE_VERDICT))
