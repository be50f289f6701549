"""A model bundle logged as an MLflow model (issue 16, item 5): the ``python_function`` flavour of the training run,
which the registered version points at.

The model's folder (``<experiment>/models/<model_id>/artifacts/`` in the artifact store) holds ``MLmodel``, the
bundle unchanged under ``artifacts/bundle/`` (hydrowatch loads a registered version from it, :func:`bundle_folder`),
``pyfunc_entry.py`` (MLflow's "models from code": the file that builds the
:class:`~hydrowatch.training.pyfunc.BundleModel` when the model is loaded, no pickled object) and
``requirements.txt``. :func:`log_bundle_model` links it to the active run; the run's parameters and metrics logged
before are linked to the model too, so the model's page shows them.

This module does not import the bundle (``training.bundle`` loads registered versions through
:mod:`hydrowatch.training.tracking`, which logs through this one); the model's code is
:mod:`hydrowatch.training.pyfunc`.
"""

from __future__ import annotations

import importlib.util
import shutil
import tempfile
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hydrowatch import __version__
from hydrowatch.errors import DataError
from hydrowatch.recording import OPTIONAL_CHANNELS

if TYPE_CHECKING:
    from hydrowatch.training.bundle import ModelBundle

BUNDLE_ARTIFACT = "bundle"
"""Name of the bundle among the pyfunc model's artifacts (``artifacts/bundle/`` in the model's folder)."""
MACHINE_COLUMN = "machine"
"""Optional input column of the model: whose samples a row is."""
WINDOW_COLUMNS = ("machine", "start_s", "state", "probability")
"""The model's output columns, one row per window: machine ('' without a ``machine`` column), start of the window
[s], verdict, its probability (NaN for ``invalid`` windows)."""
CYCLE_COLUMN = "cycle"
"""Input column of a cycles bundle's model (``train --rig``): the cycle a grid sample belongs to (integer id)."""
CYCLE_VERDICT_COLUMNS = ("machine", "cycle", "component", "state", "probability", "novelty")
"""A cycles bundle's model's output columns, one row per cycle and component: machine ('' without a ``machine``
column), the input's cycle id, the component, its state (or ``unknown``), the state's probability and the open-set
novelty (above 1: no trained state explains the cycle); :mod:`hydrowatch.training.pyfunc_cycles`."""
MODEL_REQUIREMENTS = (f"hydrowatch=={__version__}",)
"""What the logged model needs to load (its ``requirements.txt``): hydrowatch, which brings the rest. Given, so
MLflow does not infer them by loading the model in a subprocess (seconds per run)."""
ENTRY = "hydrowatch.training.pyfunc_entry"
"""The module MLflow copies into the model and runs to load it (found by name, never imported here)."""


def model_signature(bundle: ModelBundle) -> Any:
    """Input, output and params schema of the model of ``bundle``: ``t`` and the channels the bundle reads required,
    the plant's optional channels and ``machine`` optional; output :data:`WINDOW_COLUMNS`; parameter ``smoothing``
    defaulting to the method's (:func:`~hydrowatch.training.scoring.smoothing_for`). A cycles bundle (whose method
    judges whole cycles): :data:`CYCLE_COLUMN` and the rig's channels required, ``machine`` optional; output
    :data:`CYCLE_VERDICT_COLUMNS`; no parameter."""
    from mlflow.models import ModelSignature
    from mlflow.types import ColSpec, ParamSchema, ParamSpec, Schema

    if bundle.health_method.streams == "cycles":
        columns: list[Any] = [ColSpec("long", CYCLE_COLUMN), *(ColSpec("double", c) for c in bundle.sensors),
                              ColSpec("string", MACHINE_COLUMN, required=False)]
        types = {"cycle": "long", "probability": "double", "novelty": "double"}
        return ModelSignature(Schema(columns), Schema([ColSpec(types.get(c, "string"), c)
                                                       for c in CYCLE_VERDICT_COLUMNS]))

    needed = ["t", *bundle.health_method.channels]
    inputs: list[Any] = [ColSpec("double", name) for name in needed]
    inputs += [ColSpec("double", name, required=False) for name in OPTIONAL_CHANNELS if name not in needed]
    inputs.append(ColSpec("string", MACHINE_COLUMN, required=False))
    outputs: list[Any] = [ColSpec("double" if name in ("start_s", "probability") else "string", name)
                          for name in WINDOW_COLUMNS]
    smoothing = ParamSpec("smoothing", "long", bundle.health_method.default_smoothing)
    return ModelSignature(Schema(inputs), Schema(outputs), ParamSchema([smoothing]))


def log_bundle_model(bundle: ModelBundle, bundle_dir: str | Path, *, name: str | None = None,
                     tags: dict[str, str] | None = None) -> Any:
    """Log ``bundle`` (saved at ``bundle_dir``) as the MLflow model ``name`` of the active run; returns MLflow's
    ``ModelInfo`` (``model_id``; ``model_uri`` = ``models:/<model_id>``)."""
    import mlflow.pyfunc

    code = importlib.util.find_spec(ENTRY)
    if code is None or code.origin is None:
        raise DataError(f"module {ENTRY} must be installed with hydrowatch. Got none; reinstall hydrowatch.")
    with tempfile.TemporaryDirectory(prefix="hydrowatch-model-") as tmp, warnings.catch_warnings():
        staged = shutil.copytree(bundle_dir, Path(tmp) / BUNDLE_ARTIFACT)  # artifacts/bundle/, whatever its name
        warnings.filterwarnings("ignore", message=".*An input example was not provided")  # the signature is given
        return mlflow.pyfunc.log_model(
            name=name or "model", python_model=code.origin, artifacts={BUNDLE_ARTIFACT: str(staged)},
            signature=model_signature(bundle), pip_requirements=list(MODEL_REQUIREMENTS), tags=tags)


def bundle_folder(model_folder: str | Path) -> Path:
    """The bundle inside a downloaded model folder: the path its ``MLmodel`` file gives the ``bundle`` artifact.

    Raises
    ------
    DataError
        A model that is not one of hydrowatch's (no ``bundle`` artifact).
    """
    from mlflow.models import Model

    flavour = Model.load(str(model_folder)).flavors.get("python_function", {})
    try:
        return Path(model_folder) / str(flavour["artifacts"][BUNDLE_ARTIFACT]["path"])
    except (KeyError, TypeError):
        found = sorted(flavour.get("artifacts") or {})
        raise DataError(f"an MLflow model of hydrowatch must have a '{BUNDLE_ARTIFACT}' artifact (python_function "
                        f"flavour). Got artifacts {found}.", str(model_folder)) from None
