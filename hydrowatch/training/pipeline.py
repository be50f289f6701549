"""Train, save, write the artifacts, track in MLflow: shared by ``hydrowatch train``, the trainer service, the demo."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from hydrowatch.report.training import run_metrics, write_training_artifacts
from hydrowatch.results import TrainingResult
from hydrowatch.training.accuracy import COMMANDS, accuracy_metrics, measure_accuracy
from hydrowatch.training.bundle import write_index
from hydrowatch.training.data import read_labelled
from hydrowatch.training.options import DEFAULT_ALIAS, DEFAULT_EXPERIMENT, DEFAULT_MODEL_NAME, TrainingSettings
from hydrowatch.training.tracking import log_training
from hydrowatch.training.trainer import train

RUNS_TABLE_COLUMNS = ("test_accuracy", "recall_min", *(f"accuracy.{c}" for c in COMMANDS), "train_seconds")
"""The metrics the training experiment's runs table shows as columns
(:func:`~hydrowatch.training.tracking.set_runs_view`): the held-out accuracy and weakest recall, the accuracy
checks on each command (with ``check_seconds``), the training time."""


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
    check_seconds: float = 0.0,
    check_seed: int = 100,
) -> tuple[TrainingResult, dict[str, Any]]:
    """Train from the recordings at ``data``, save the bundle to ``out``, log and register it.

    Returns the training result and the JSON summary (``hydrowatch train``'s output): the
    result's summary plus ``out``, ``run_id``, ``tracking_uri``, ``model_uri``, ``registered_version``,
    ``runs_url`` (the runs table in MLflow's UI, :data:`RUNS_TABLE_COLUMNS` as columns) and, with
    ``check_seconds`` > 0, ``checks`` (command → accuracy): every trained state simulated again for
    ``check_seconds`` s with ``check_seed`` under each command of
    :data:`~hydrowatch.training.accuracy.COMMANDS`, logged as metrics ``accuracy.<command>``,
    ``windows.<command>``, ``recall_min.<command>`` and ``recall.<command>.<state>`` (the states must be
    simulator states). ``skip_unreadable`` leaves out files that cannot be read yet
    (see :func:`read_labelled`).
    """
    started = time.time()
    result = train(read_labelled(data, skip_unreadable=skip_unreadable), settings)
    result.bundle.save(out)
    checks = [measure_accuracy(result.bundle, command=c, seconds=check_seconds, seed=check_seed)
              for c in COMMANDS] if check_seconds > 0 else []
    with tempfile.TemporaryDirectory(prefix="hydrowatch-report-") as tmp:
        folder = Path(report_dir) if report_dir is not None else Path(tmp)
        if checks:
            result.evaluation["checks"] = checks
        write_training_artifacts(result, folder)
        logged = log_training(
            params=settings.to_dict(), metrics={**run_metrics(result), **accuracy_metrics(checks)},
            bundle=result.bundle, bundle_dir=out, report_dir=folder, tracking=tracking, experiment=experiment,
            run_name=f"{settings.name}-{result.bundle.version[7:]}", model_name=model_name, alias=alias,
            tags={"method": settings.method, "reference": settings.name, "bundle_version": result.bundle.version},
            started_s=started, columns=RUNS_TABLE_COLUMNS,
        )
    summary = {**result.summary(), "out": str(out), **logged_fields(logged)}
    if checks:
        summary["checks"] = {a["command"]: a["accuracy"] for a in checks}
    return result, summary


def logged_fields(logged: dict[str, Any]) -> dict[str, Any]:
    """What ``hydrowatch train``'s JSON summary says of the MLflow run, from
    :func:`~hydrowatch.training.tracking.log_training`'s answer: ``run_id``, ``tracking_uri``, ``model_uri``,
    ``registered_version``, ``runs_url``."""
    return {"run_id": logged["run_id"], "tracking_uri": logged["tracking_uri"], "model_uri": logged["model_uri"],
            "registered_version": logged["version"], "runs_url": logged["runs_url"]}


def train_each(
    data: str | Path, out: str | Path, settings: Sequence[TrainingSettings], *,
    report_dir: str | Path | None = None, **options: Any,
) -> Iterator[dict[str, Any]]:
    """:func:`train_and_track` for each settings (``--method both|all``); yields the summaries in order.

    With one settings the bundle goes to ``out`` (plots to ``report_dir``). With several, each goes
    to ``out/<key>`` (``report_dir/<key>``) as its own MLflow run, the key being the method
    (``both``: ``entropy``, ``parity``) or, when methods repeat, the settings' name (``all``: ``bj``,
    ``narx``, ``parity``); ``out/bundles.json`` indexes them and names the last one the default, so
    ``score --model out`` and the scorer load it (the registry alias, if any, also ends on it).
    """
    if len(settings) == 1:
        yield train_and_track(data, out, settings[0], report_dir=report_dir, **options)[1]
        return
    methods = [s.method for s in settings]
    keys = methods if len(set(methods)) == len(methods) else [s.name for s in settings]
    for key, s in zip(keys, settings):
        report = None if report_dir is None else Path(report_dir) / key
        yield train_and_track(data, Path(out) / key, s, report_dir=report, **options)[1]
        write_index(out, keys[: keys.index(key) + 1])
