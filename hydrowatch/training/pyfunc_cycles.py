"""The python_function face of a cycles bundle (``train --rig``, docs/rigs.md): a DataFrame of a rig's cycles in,
one verdict per cycle and component out (issue 17)::

    model = mlflow.pyfunc.load_model("models:/hydrowatch-uci-hydraulic@champion")
    verdicts = model.predict(cycles)   # machine, cycle, component, state, probability, novelty

``cycles``: one row per sample of the rig's grid (``window.grid_hz``), the rows of a cycle in time order, columns
:data:`~hydrowatch.training.mlflow_model.CYCLE_COLUMN` (the cycle's id, an integer), one column per channel of the
description named as the description names it, in its unit (renamed and scaled: the values of a ``rig_cycles``
message or of ``Cycles.values``), and optionally ``machine`` (several machines' cycles, each scored on its own, in the
order they first appear). Every cycle must have ``window.length_s · grid_hz`` rows. The verdicts are
:meth:`~hydrowatch.methods.cycles.CyclesMethod.judge_cycles`', i.e. those of ``hydrowatch score`` of the same cycles.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from hydrowatch.errors import DataError
from hydrowatch.methods.cycles import CyclesMethod
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.mlflow_model import CYCLE_COLUMN, CYCLE_VERDICT_COLUMNS, MACHINE_COLUMN

SOURCE = "model input"


def frame_cycles(method: CyclesMethod, frame: pd.DataFrame, machine: str = "") -> tuple[list[int], np.ndarray]:
    """The cycle ids (order of first appearance) and values, shape (cycles, channels, samples), of one machine's rows.

    Raises
    ------
    DataError
        A missing column, a channel cell that is not a finite number (column and row), or a cycle whose row count
        is not the rig's samples per cycle (naming the cycle and the machine).
    """
    names, samples = method.sensors, method.window
    where = f"{SOURCE}{f' machine {machine}' if machine else ''}"
    missing = [c for c in (CYCLE_COLUMN, *names) if c not in frame.columns]
    if missing:
        raise DataError(f"a cycles model's input needs columns {[CYCLE_COLUMN, *names]} (rig {method.rig.name}, one "
                        f"row per grid sample). Got none for {missing}.", where)
    matrix = np.empty((len(frame), len(names)))
    for j, name in enumerate(names):
        column = pd.to_numeric(frame[name], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(column))
        if bad.size:
            raise DataError(f"column {name!r} must hold finite numbers. Got {frame[name].iloc[bad[0]]!r} at row "
                            f"{frame.index[bad[0]]}.", where)
        matrix[:, j] = column
    cycle = frame[CYCLE_COLUMN].to_numpy()
    if not np.issubdtype(cycle.dtype, np.integer):
        raise DataError(f"column {CYCLE_COLUMN!r} must hold integer cycle ids. Got dtype {cycle.dtype}.", where)
    ids, first, counts = np.unique(cycle, return_index=True, return_counts=True)
    order = np.argsort(first)
    wrong = [k for k in order if counts[k] != samples]
    if wrong:
        k = wrong[0]
        raise DataError(f"cycle {int(ids[k])} must have {samples} rows (rig {method.rig.name}: "
                        f"{method.rig.window.length_s:g} s at {method.rig.window.grid_hz:g} Hz). Got {counts[k]}.",
                        where)
    values = np.stack([matrix[cycle == ids[k]].T for k in order])
    return [int(ids[k]) for k in order], values


def score_cycle_frame(bundle: ModelBundle, frame: pd.DataFrame) -> pd.DataFrame:
    """One row per cycle and component, cycle after cycle (:data:`~hydrowatch.training.mlflow_model.
    CYCLE_VERDICT_COLUMNS`), of each machine's cycles in ``frame`` (module docstring), judged by the cycles bundle
    ``bundle``: the state (or ``unknown``), its probability and the novelty (above 1: no trained state explains it).
    """
    method = bundle.health_method
    if not isinstance(method, CyclesMethod):
        raise DataError(f"score_cycle_frame needs a cycles bundle (train --rig). Got a {bundle.method} bundle.")
    if not isinstance(frame, pd.DataFrame):
        raise DataError(f"a cycles model's input must be a pandas DataFrame of cycles. Got {type(frame).__name__}.")
    groups = frame.groupby(MACHINE_COLUMN, sort=False) if MACHINE_COLUMN in frame.columns else [("", frame)]
    rows = []
    for machine, part in groups:
        ids, values = frame_cycles(method, part, str(machine))
        judged = method.judge_cycles(values)
        rows += [(str(machine), cycle, component, verdicts[i].state, verdicts[i].probability, verdicts[i].novelty)
                 for i, cycle in enumerate(ids) for component, verdicts in judged.items()]
    out = pd.DataFrame(rows, columns=list(CYCLE_VERDICT_COLUMNS))
    return out.astype({"cycle": "int64", "probability": float, "novelty": float})
