"""MLflow tracking of training runs and the model registry (../shared/docs/stack-notes.md, "MLflow").

One run per trained bundle, spanning its training: parameters (reference model orders or delay lines and neurons,
data plan, window), metrics (one-step NRMSE per sensor, Q/S or γ, test accuracy, per-class recall, the accuracy
checks), the report plots and tables as artifacts, and the bundle as an MLflow model of the run (pyfunc,
:mod:`hydrowatch.training.mlflow_model`); a registered model version points at that model, with an alias
(``champion``) that the scorer can follow. The tracking URI is always
explicit: ``--tracking-uri``, else ``MLFLOW_TRACKING_URI``, else ``sqlite:///<cwd>/mlruns/mlflow.db``
with artifacts next to the database (``mlruns/artifacts``).
"""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.log import event, get_logger
from hydrowatch.training.mlflow_model import bundle_folder, log_bundle_model
from hydrowatch.training.options import (
    DEFAULT_ALIAS,
    DEFAULT_EXPERIMENT,
    DEFAULT_MODEL_NAME,
    DEFAULT_SCORING_EXPERIMENT,
)

if TYPE_CHECKING:
    from hydrowatch.training.bundle import ModelBundle

_log = get_logger(__name__)


def tracking_uri(explicit: str | None = None) -> str:
    """The tracking URI to use: ``explicit``, ``$MLFLOW_TRACKING_URI`` or ``sqlite:///<cwd>/mlruns/mlflow.db``."""
    uri = explicit or os.environ.get("MLFLOW_TRACKING_URI")
    if uri:
        return uri
    folder = Path.cwd() / "mlruns"
    folder.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{folder / 'mlflow.db'}"


def _artifact_root(uri: str) -> str | None:
    """Artifacts folder next to a sqlite database (None: the server's default)."""
    if uri.startswith("sqlite:///"):
        db = Path(uri[len("sqlite:///") :])
        return (db.parent / "artifacts").resolve().as_uri()
    return None


def _client(uri: str) -> Any:
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    os.environ.setdefault("MLFLOW_SUPPRESS_PRINTING_URL_TO_STDOUT", "true")  # stdout is our JSON; runs_url says it
    for name in ("mlflow", "alembic"):
        logging.getLogger(name).setLevel(logging.WARNING)
    import mlflow
    from mlflow.tracking import MlflowClient

    mlflow.set_tracking_uri(uri)
    mlflow.set_registry_uri(uri)
    return MlflowClient(tracking_uri=uri, registry_uri=uri)


EXPERIMENT_KIND = {"mlflow.experimentKind": "custom_model_development"}
"""The experiment tag that MLflow 3 UIs before the GenAI/Model-training switch read to open an experiment in the
model-training view rather than the GenAI one (traces, tokens). MLflow 3.17's UI follows its own switch instead,
remembered in the browser (default GenAI) or given in the address: :func:`runs_table_url` (issue 16)."""
RUNS_VIEW = "checks"
"""Share key of the runs-table view written to a training experiment (:func:`set_runs_view`)."""
SHARED_VIEW_TAG = "mlflow.sharedViewState."
"""Prefix of the experiment tags that hold MLflow's shared runs-table views (the UI's "share view"; the address
names one with ``viewStateShareKey``)."""
MLFLOW_UI = "http://127.0.0.1:5000"
"""Where ``mlflow ui`` serves by default: the runs table's address for a store that is not a server."""


def set_runs_view(client: Any, experiment_id: str, metrics: Sequence[str]) -> None:
    """Write the runs-table view :data:`RUNS_VIEW` to the experiment: columns the registered model and ``metrics``
    (MLflow 3.17 shows no metric column until one is chosen), newest run first; :func:`runs_table_url` opens it."""
    columns = ["attributes.`Models`", *(f"metrics.`{m}`" for m in metrics)]
    view = {"selectedColumns": columns, "orderByKey": "attributes.start_time", "orderByAsc": False}
    client.set_experiment_tag(experiment_id, SHARED_VIEW_TAG + RUNS_VIEW, json.dumps(view))


def runs_table_url(uri: str, experiment_id: str) -> str:
    """The address of an experiment's runs table in MLflow's UI, in the model-training view, with the columns of
    :func:`set_runs_view`: on the tracking server for an ``http(s)`` URI, else on :data:`MLFLOW_UI`."""
    base = uri.rstrip("/") if uri.startswith(("http://", "https://")) else MLFLOW_UI
    return f"{base}/#/experiments/{experiment_id}/runs?workflowType=machine_learning&viewStateShareKey={RUNS_VIEW}"


def _experiment_id(client: Any, name: str, uri: str) -> str:
    """The experiment's id, created when missing, and marked a model-training experiment (:data:`EXPERIMENT_KIND`)."""
    found = client.get_experiment_by_name(name)
    if found is None:
        root = _artifact_root(uri)
        return str(client.create_experiment(name, artifact_location=f"{root}/{name}" if root else None,
                                            tags=EXPERIMENT_KIND))
    for key, value in EXPERIMENT_KIND.items():
        if found.tags.get(key) != value:
            client.set_experiment_tag(found.experiment_id, key, value)
    return str(found.experiment_id)


def _finite(metrics: dict[str, float]) -> dict[str, float]:
    return {k: float(v) for k, v in metrics.items() if v is not None and math.isfinite(float(v))}


def log_training(
    *,
    params: dict[str, Any],
    metrics: dict[str, float],
    bundle: ModelBundle,
    bundle_dir: str | Path,
    report_dir: str | Path | None = None,
    tracking: str | None = None,
    experiment: str = DEFAULT_EXPERIMENT,
    run_name: str | None = None,
    model_name: str | None = DEFAULT_MODEL_NAME,
    alias: str | None = DEFAULT_ALIAS,
    tags: dict[str, str] | None = None,
    started_s: float | None = None,
    columns: Sequence[str] = (),
) -> dict[str, Any]:
    """Log one training run and register its bundle; returns ``run_id``, ``tracking_uri``, ``experiment``,
    ``model_uri`` (registry), ``version``, ``model_id`` (the logged model) and ``runs_url`` (:func:`runs_table_url`).

    ``started_s`` (s since the Unix epoch): when the training began; the run then spans the training, so MLflow shows
    its duration (default: the run starts when logging does). ``columns``: metrics the experiment's runs-table view
    shows (:func:`set_runs_view`; empty: leave the view alone).

    Parameters
    ----------
    params, metrics : dict
        Logged in one batch each (non-finite metrics are left out).
    bundle, bundle_dir : ModelBundle, path
        The bundle and the folder it is saved in; logged as the run's MLflow model, named ``run_name``
        (:func:`~hydrowatch.training.mlflow_model.log_bundle_model`), which the registered version points at.
    report_dir : path, optional
        Plots and tables; logged under ``report/``.
    model_name : str or None
        Registered model name (None: do not register).
    alias : str or None
        Alias moved to the new version (None: leave aliases alone).
    """
    import mlflow

    uri = tracking_uri(tracking)
    client = _client(uri)
    experiment_id = _experiment_id(client, experiment, uri)
    start_ms = int((time.time() if started_s is None else started_s) * 1000)
    if columns:
        set_runs_view(client, experiment_id, columns)
    begun = client.create_run(experiment_id, start_time=start_ms, run_name=run_name).info.run_id
    with mlflow.start_run(run_id=begun) as run:
        mlflow.log_params({k: str(v)[:500] for k, v in params.items()})
        mlflow.log_metrics(_finite(metrics))
        if tags:
            mlflow.set_tags(tags)
        model = log_bundle_model(bundle, bundle_dir, name=run_name, tags=tags)
        if report_dir is not None:
            mlflow.log_artifacts(str(report_dir), "report")
        run_id = run.info.run_id
    out: dict[str, Any] = {"run_id": run_id, "tracking_uri": uri, "experiment": experiment, "model_uri": None,
                           "version": None, "model_id": model.model_id, "runs_url": runs_table_url(uri, experiment_id)}
    if model_name:
        try:
            client.get_registered_model(model_name)
        except Exception:  # noqa: BLE001 - MLflow raises its own RestException when missing
            client.create_registered_model(model_name)
        version = register_version(client, model_name, model, run_id, tags or {})
        if alias:
            client.set_registered_model_alias(model_name, alias, version.version)
        out["version"] = str(version.version)
        out["model_uri"] = f"models:/{model_name}@{alias}" if alias else f"models:/{model_name}/{version.version}"
    event(_log, "training run logged", run_id=run_id, model=out["model_uri"], model_id=model.model_id, uri=uri)
    return out


def register_version(client: Any, model_name: str, model: Any, run_id: str, tags: dict[str, str]) -> Any:
    """A new version of ``model_name`` whose source is the logged model (``models:/<model_id>``), and the logged
    model's tag ``mlflow.modelVersions`` listing it, as ``mlflow.register_model`` does (the model's page shows its
    registered versions from that tag); quietly (``register_model`` prints to stderr)."""
    from mlflow.utils.mlflow_tags import MLFLOW_MODEL_VERSIONS

    version = client.create_model_version(model_name, source=model.model_uri, run_id=run_id, tags=tags,
                                          model_id=model.model_id)
    listed = json.loads(client.get_logged_model(model.model_id).tags.get(MLFLOW_MODEL_VERSIONS) or "[]")
    listed.append({"name": model_name, "version": str(version.version)})
    client.set_logged_model_tags(model.model_id, {MLFLOW_MODEL_VERSIONS: json.dumps(listed)})
    return version


METRICS_PER_BATCH = 1000
"""Most metrics MLflow takes in one ``log_batch`` call."""


def log_scoring(*, params: dict[str, Any], metrics: dict[str, float], steps: list[tuple[str, float, int]],
                tracking: str | None = None, experiment: str = DEFAULT_SCORING_EXPERIMENT,
                run_name: str | None = None) -> dict[str, Any]:
    """Log one ``score`` run: ``params`` (model, its version, data, smoothing), ``metrics`` (one value each) and
    ``steps`` (key, value, step: a curve per key, the degradation index over the windows); returns ``run_id``,
    ``tracking_uri`` and ``experiment``. Non-finite values are left out."""
    from mlflow.entities import Metric, Param

    uri = tracking_uri(tracking)
    client = _client(uri)
    experiment_id = _experiment_id(client, experiment, uri)
    run_id = client.create_run(experiment_id, run_name=run_name, tags={"kind": "scoring"}).info.run_id
    now = int(time.time() * 1000)
    logged = [Metric(k, v, now, 0) for k, v in _finite(metrics).items()]
    logged += [Metric(k, float(v), now, int(step)) for k, v, step in steps if math.isfinite(float(v))]
    try:
        client.log_batch(run_id, params=[Param(k, str(v)[:500]) for k, v in params.items()])
        for lo in range(0, len(logged), METRICS_PER_BATCH):
            client.log_batch(run_id, metrics=logged[lo:lo + METRICS_PER_BATCH])
    except BaseException:
        client.set_terminated(run_id, "FAILED")
        raise
    client.set_terminated(run_id, "FINISHED")
    event(_log, "scoring run logged", run_id=run_id, metrics=len(logged), uri=uri)
    return {"run_id": run_id, "tracking_uri": uri, "experiment": experiment}


def set_alias(model_name: str, alias: str, version: str, tracking: str | None = None) -> None:
    """Point ``alias`` of ``model_name`` at ``version``."""
    _client(tracking_uri(tracking)).set_registered_model_alias(model_name, alias, version)


def parse_model_uri(uri: str) -> tuple[str, str | None, str | None]:
    """``models:/NAME@ALIAS`` → (NAME, ALIAS, None); ``models:/NAME/VERSION`` → (NAME, None, VERSION)."""
    body = uri[len("models:/") :] if uri.startswith("models:/") else ""
    name, at, alias = body.partition("@")
    if at and name and alias:
        return name, alias, None
    name, slash, version = body.partition("/")
    if slash and name and version:
        return name, None, version
    raise ParameterError(f"model URI must be models:/NAME@ALIAS or models:/NAME/VERSION. Got {uri!r}.")


def resolve_version(uri: str, tracking: str | None = None) -> tuple[str, str]:
    """(registered version, artifact source) that a registry URI points at now."""
    name, alias, version = parse_model_uri(uri)
    client = _client(tracking_uri(tracking))
    try:
        mv = client.get_model_version_by_alias(name, alias) if alias else client.get_model_version(name, version)
    except Exception as exc:  # noqa: BLE001 - MlflowException for unknown names, aliases, versions
        raise DataError(f"model {uri} must exist in the registry at {tracking_uri(tracking)}. Got: {exc}".split("\n")[0]
                        + " Train one with `hydrowatch train` or pass --tracking-uri.") from None
    return str(mv.version), str(mv.source)


def download_registered(uri: str, tracking: str | None = None) -> tuple[Path, str]:
    """Download the bundle a registry URI points at; returns (local folder, ``NAME/vVERSION``).

    A version registered since issue 16 is an MLflow model (source ``models:/<model_id>``) holding the bundle as
    its ``bundle`` artifact; one registered before is the bundle folder itself (source ``…/artifacts/bundle``)."""
    import mlflow

    name, _, _ = parse_model_uri(uri)
    version, source = resolve_version(uri, tracking)
    folder = Path(tempfile.mkdtemp(prefix="hydrowatch-model-"))
    local = Path(mlflow.artifacts.download_artifacts(artifact_uri=source, dst_path=str(folder)))
    return (bundle_folder(local) if (local / "MLmodel").exists() else local), f"{name}/v{version}"
