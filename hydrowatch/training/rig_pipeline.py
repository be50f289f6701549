"""Train and score a rig's cycles with the ``cycles`` method (docs/rigs.md): ``hydrowatch train --rig`` and
``hydrowatch score`` of a cycles bundle.

Training reads a rig's cycles (:func:`hydrowatch.io.rig_cycles.read_rig_data`: a wide folder, a long CSV/Parquet
table or an MCAP file of ``import --rig``), fits
:class:`~hydrowatch.methods.cycles.CyclesMethod`, saves the bundle and logs the run to MLflow like every method
(:func:`~hydrowatch.training.tracking.log_training`), the honest split's figures per component as metrics.
Scoring reads data of the same kinds with the description kept in the bundle; a wide folder's label file is optional.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path
from typing import Any

from hydrowatch.cycles.openset import UNKNOWN
from hydrowatch.errors import DataError
from hydrowatch.io.rig_cycles import read_rig_data, start_times
from hydrowatch.io.wide import Cycles
from hydrowatch.methods.cycles import CyclesMethod
from hydrowatch.results import TrainingResult
from hydrowatch.rig.description import rig_text
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.options import DEFAULT_ALIAS, TrainingSettings, given_or_default_names
from hydrowatch.training.pipeline import logged_fields
from hydrowatch.training.tracking import log_training


def cycle_metrics(result: TrainingResult) -> dict[str, float]:
    """The run's MLflow metrics: ``test_accuracy`` (mean over components), per component ``accuracy.<c>``,
    ``macro_f1.<c>``, ``unknown.<c>`` (honest split) and ``recall.<c>.<state>``, and ``train_seconds``."""
    ev = result.evaluation
    metrics = {"test_accuracy": ev["test_accuracy"], "train_seconds": result.seconds}
    for c, figures in ev["components"].items():
        metrics.update({f"{key}.{c}": figures[key] for key in ("accuracy", "macro_f1", "unknown")})
        metrics.update({f"recall.{c}.{s}": r for s, r in figures["per_class_recall"].items()})
    return metrics


def train_rig_and_track(
    rig: str,
    data: str | Path,
    out: str | Path,
    settings: TrainingSettings,
    *,
    tracking: str | None = None,
    experiment: str | None = None,
    model_name: str | None = None,
    register: bool = True,
    alias: str | None = DEFAULT_ALIAS,
    report_dir: str | Path | None = None,
) -> tuple[TrainingResult, dict[str, Any]]:
    """Train the cycles method on rig ``rig`` (a shipped name or a .toml file) from the folder ``data``, save the
    bundle to ``out``, log and register it; returns the result and the JSON summary (``hydrowatch train``'s: the
    result's summary plus ``rig``, ``components`` (per component ``accuracy``, ``macro_f1``, ``unknown``,
    ``features``), ``out``, ``run_id``, ``tracking_uri``, ``model_uri``, ``registered_version``, ``runs_url``).

    ``experiment`` and ``model_name`` default to ``hydrowatch-<rig>`` (:func:`~hydrowatch.training.options.mlflow_name`
    of the description's name), never the plant's ``hydrowatch``; ``register=False`` logs the run without registering.
    """
    started, clock = time.time(), time.perf_counter()
    description, text = rig_text(rig)
    experiment, model_name = given_or_default_names(experiment, model_name, register=register, rig=description.name)
    cycles = read_rig_data(data, description)
    fitted = CyclesMethod.fit_cycles(text, description, cycles, settings)
    bundle = ModelBundle(fitted.method, fitted.manifest)
    result = TrainingResult(bundle, {}, {}, fitted.evaluation, {}, time.perf_counter() - clock)
    bundle.save(out)
    with tempfile.TemporaryDirectory(prefix="hydrowatch-report-") as tmp:
        folder = Path(report_dir) if report_dir is not None else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "evaluation.json").write_text(json.dumps(result.evaluation, indent=1, default=float))
        logged = log_training(
            params={**settings.to_dict(), "rig": description.name, "data": str(data), "cycles": len(cycles)},
            metrics=cycle_metrics(result), bundle=bundle, bundle_dir=out, report_dir=folder, tracking=tracking,
            experiment=experiment, run_name=f"cycles-{description.name}-{bundle.version[7:]}", model_name=model_name,
            alias=alias, tags={"method": CyclesMethod.name, "rig": description.name, "bundle_version": bundle.version},
            started_s=started,
        )
    components = {c: {k: f[k] for k in ("accuracy", "macro_f1", "unknown", "features")}
                  for c, f in result.evaluation["components"].items()}
    summary = {**result.summary(), "rig": description.name, "components": components, "out": str(out),
               **logged_fields(logged)}
    return result, summary


def read_rig_folder(method: CyclesMethod, data: str | Path) -> Cycles:
    """The cycles in ``data`` read with the bundle's rig description (:func:`read_rig_data`)."""
    return read_rig_data(data, method.rig)


def score_cycles(bundle: ModelBundle, cycles: Cycles) -> dict[str, Any]:
    """``hydrowatch score --json``'s object for a cycles bundle (docs/formats.md).

    ``source``, ``rig``, ``cycles`` and ``summary``. ``cycles[i]``: ``cycle`` (row, from 0), ``start_s`` (the
    window's start for a long table or an imported file, else cycle × cycle length, s) and ``components``: per
    component the verdict's ``state``, ``probability``, ``probabilities``, ``novelty``, ``reason`` when ``unknown``
    and, when labelled, ``truth`` (the label, or ``unknown`` for a state the bundle was not trained on).
    ``summary``: ``cycles``, and per component ``counts`` and ``accuracy`` (None when unlabelled), ``model_version``.
    """
    method = bundle.health_method
    if not isinstance(method, CyclesMethod):
        raise DataError(f"a rig folder is scored with a cycles bundle (train --rig). Got a {bundle.method} bundle.",
                        cycles.source)
    verdicts = method.judge_cycles(cycles.values)
    truth = method.truth(cycles.labels)
    starts = start_times(cycles, method.rig)
    rows = []
    for i in range(len(cycles)):
        parts = {}
        for c, judged in verdicts.items():
            parts[c] = judged[i].to_dict()
            if c in truth:
                parts[c]["truth"] = truth[c][i]
        rows.append({"cycle": i, "start_s": float(starts[i]), "components": parts})
    counts = {c: {s: sum(v.state == s for v in judged) for s in sorted({v.state for v in judged})}
              for c, judged in verdicts.items()}
    accuracy = {c: (sum(v.state == t for v, t in zip(judged, truth[c])) / len(judged) if c in truth else None)
                for c, judged in verdicts.items()}
    return {"source": cycles.source, "rig": method.rig.name, "cycles": rows,
            "summary": {"cycles": len(cycles), "counts": counts, "accuracy": accuracy,
                        "model_version": bundle.version}}


def cycle_scoring_metrics(scored: dict[str, Any]) -> dict[str, float]:
    """``score --log-run``'s metrics of a cycles bundle's object: ``cycles``, per component ``accuracy.<c>`` (when
    labelled) and ``unknown.<c>`` (share of cycles read unknown)."""
    summary = scored["summary"]
    n = summary["cycles"]
    metrics = {"cycles": float(n)}
    for c, counts in summary["counts"].items():
        metrics[f"unknown.{c}"] = counts.get(UNKNOWN, 0) / n if n else float("nan")
        if summary["accuracy"][c] is not None:
            metrics[f"accuracy.{c}"] = summary["accuracy"][c]
    return metrics
