"""Train, save, write the artifacts, track in MLflow: shared by ``hydrowatch train``, the trainer service, the demo."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from hydrowatch.report.training import run_metrics, write_training_artifacts
from hydrowatch.training.data import read_labelled
from hydrowatch.training.options import DEFAULT_ALIAS, DEFAULT_EXPERIMENT, DEFAULT_MODEL_NAME, TrainingSettings
from hydrowatch.training.tracking import log_training
from hydrowatch.training.trainer import TrainingResult, train


def train_and_track(
    data: str | Path,
    out: str | Path,
    settings: TrainingSettings,
    *,
    tracking: str | None = None,
    experiment: str = DEFAULT_EXPERIMENT,
    model_name: str | None = DEFAULT_MODEL_NAME,
    alias: str | None = DEFAULT_ALIAS,
    report_dir: str | Path | None = None,
    skip_unreadable: bool = False,
) -> tuple[TrainingResult, dict[str, Any]]:
    """Train from the recordings at ``data``, save the bundle to ``out``, log and register it.

    Returns the training result and the JSON summary (``hydrowatch train``'s output): the
    result's summary plus ``out``, ``run_id``, ``tracking_uri``, ``model_uri``, ``registered_version``.
    ``skip_unreadable`` leaves out files that cannot be read yet (see :func:`read_labelled`).
    """
    result = train(read_labelled(data, skip_unreadable=skip_unreadable), settings)
    result.bundle.save(out)
    with tempfile.TemporaryDirectory(prefix="hydrowatch-report-") as tmp:
        folder = Path(report_dir) if report_dir is not None else Path(tmp)
        write_training_artifacts(result, folder)
        logged = log_training(
            params=settings.to_dict(), metrics=run_metrics(result), bundle_dir=out, report_dir=folder,
            tracking=tracking, experiment=experiment, run_name=f"{settings.reference}-{result.bundle.version[7:]}",
            model_name=model_name, alias=alias,
            tags={"reference": settings.reference, "bundle_version": result.bundle.version},
        )
    summary = {**result.summary(), "out": str(out), "run_id": logged["run_id"], "tracking_uri": logged["tracking_uri"],
               "model_uri": logged["model_uri"], "registered_version": logged["version"]}
    return result, summary
