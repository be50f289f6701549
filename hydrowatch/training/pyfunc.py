"""The python_function face of a model bundle: :class:`BundleModel`, what ``mlflow.pyfunc.load_model`` returns for a
model that ``hydrowatch train`` logged (:mod:`hydrowatch.training.mlflow_model`, issue 16, item 5)::

    model = mlflow.pyfunc.load_model("models:/hydrowatch@champion")
    windows = model.predict(samples)      # one row per window: machine, start_s, state, probability

``samples``: one row per sample, columns as in a Parquet or CSV recording (docs/formats.md): ``t`` [s], ``voltage``
[V] and the sensors the bundle reads (``flow`` [L/min], ``speed`` [rad/s], ``torque`` [N·m], …), at 200 Hz; an
optional ``machine`` column holds several machines' samples, each scored on its own (in the order they first
appear). Parameter ``smoothing`` (pyfunc ``params``): windows each verdict pools, default the method's (parity 12,
others 1), as ``score --smoothing``. The verdicts are those of ``hydrowatch score`` on the same samples.

A cycles bundle (``train --rig``, a rig's whole cycles) takes a DataFrame of cycles instead and answers one row per
cycle and component (:mod:`hydrowatch.training.pyfunc_cycles`).
"""

from __future__ import annotations

from typing import Any

import pandas as pd
import pyarrow as pa
from mlflow.pyfunc.model import PythonModel, PythonModelContext

from hydrowatch.errors import DataError
from hydrowatch.io.recordings import recording_from_table
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.mlflow_model import BUNDLE_ARTIFACT, MACHINE_COLUMN, WINDOW_COLUMNS
from hydrowatch.training.pyfunc_cycles import score_cycle_frame
from hydrowatch.training.scoring import score_recording, smoothing_for


class BundleModel(PythonModel):
    """The pyfunc face of a :class:`~hydrowatch.training.bundle.ModelBundle`; the bundle is read in ``load_context``."""

    def load_context(self, context: PythonModelContext) -> None:
        """Read the bundle from the model's ``bundle`` artifact."""
        self.bundle_ = ModelBundle.load(context.artifacts[BUNDLE_ARTIFACT])

    def predict(self, context: PythonModelContext, model_input: pd.DataFrame,
                params: dict[str, Any] | None = None) -> pd.DataFrame:
        """Verdicts of every window of ``model_input`` (module docstring); ``params["smoothing"]`` as ``score``.
        A cycles bundle's: of every cycle and component."""
        if self.bundle_.health_method.streams == "cycles":
            return score_cycle_frame(self.bundle_, model_input)
        requested = (params or {}).get("smoothing")
        return score_samples(self.bundle_, model_input, smoothing_for(self.bundle_, requested))


def score_samples(bundle: ModelBundle, samples: pd.DataFrame, smoothing: int) -> pd.DataFrame:
    """One row per window (:data:`~hydrowatch.training.mlflow_model.WINDOW_COLUMNS`) of each machine's samples in
    ``samples``, scored by ``bundle`` with ``smoothing`` as :func:`~hydrowatch.training.scoring.score_recording`.

    Raises
    ------
    DataError
        Samples that a recording file with the same columns would be refused for (missing channel, NaN, time
        base), naming the machine.
    """
    if not isinstance(samples, pd.DataFrame):
        raise DataError(f"the model's input must be a pandas DataFrame of samples. Got {type(samples).__name__}.")
    groups = samples.groupby(MACHINE_COLUMN, sort=False) if MACHINE_COLUMN in samples.columns else [("", samples)]
    rows = []
    for machine, part in groups:
        table = pa.Table.from_pandas(part.drop(columns=[MACHINE_COLUMN], errors="ignore"), preserve_index=False)
        source = f"model input{f' machine {machine}' if machine != '' else ''}"
        result = score_recording(bundle, recording_from_table(table, source, required=bundle.health_method.channels),
                                 smoothing)
        rows += [(str(machine), w["start_s"], w["state"], w["probability"]) for w in result["windows"]]
    return pd.DataFrame(rows, columns=list(WINDOW_COLUMNS)).astype({"probability": float})
