"""Artifacts of a training run: plots, the relative-entropy table (as table 6.1), evaluation JSON.

The table's rows are the method's ``kl`` rows (sensors for the entropy method, relations for the
parity method: median relation scores); the reference-model plots (error distributions, residual
correlations, pole-zero maps) are drawn when the run has reference models (the entropy method).
Accuracy checks on other commands (``evaluation["checks"]``, see
:func:`hydrowatch.training.pipeline.train_and_track`) add one confusion matrix each.

:func:`write_training_artifacts` writes them into a folder (MLflow logs the folder under
``report/``); :func:`training_section` gives the same material as an HTML report section.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from hydrowatch.health.metrics import weakest_recall
from hydrowatch.recording import UNITS
from hydrowatch.report.html import Section
from hydrowatch.report.plots import confusion_png, correlations_png, error_distributions_png, pole_zero_png
from hydrowatch.results import TrainingResult


def run_name(result: TrainingResult) -> str:
    """The method's name (``parity``, …), or the reference kind (``narx``, ``bj``) of a run with reference models."""
    return str(result.bundle.manifest.get("reference") or result.bundle.method)


def entropy_table(result: TrainingResult) -> tuple[list[str], list[list[Any]]]:
    """Median relative entropy of each state's classifier windows against every base state, nats.

    Rows: (true state, sensor); columns: the base states. The row of one true state is the
    study's table 6.1 (there for one window of ``load_alert``). Parity runs: (true state,
    relation) rows of median relation scores of the test windows.
    """
    states = result.bundle.states
    rows = []
    for true_state, d in result.window_entropies.items():
        for j, row in enumerate(result.bundle.kl_rows):
            median = np.nanmedian(d[:, j, :], axis=0).tolist() if d.shape[0] else [float("nan")] * len(states)
            rows.append([true_state, row, *median])
    return ["window state", result.bundle.health_method.row_label, *states], rows


def _pictures(result: TrainingResult) -> dict[str, bytes]:
    ev = result.evaluation
    title = f"Test windows ({ev['test_windows']}), {run_name(result)}"
    out = {"confusion_matrix.png": confusion_png(ev["confusion_matrix"], ev["labels"], title)}
    for check in ev.get("checks", []):
        out[f"confusion_{check['command']}.png"] = confusion_png(
            check["confusion_matrix"], check["labels"], f"{run_name(result)}, {check['command']} command, "
                                                        f"seed {check['seed']}")
    if not result.reference:  # no reference models (parity, stats): no error distributions to draw
        return out
    for j, sensor in enumerate(result.bundle.sensors):
        out[f"errors_{sensor}.png"] = error_distributions_png(
            {s: e[:, j] for s, e in result.base_errors.items()}, sensor, UNITS[sensor])
    out["residual_correlations.png"] = correlations_png({s: r["correlations"] for s, r in result.reference.items()})
    if result.bundle.manifest.get("reference") == "bj":
        roots = {s: r["summary"]["validation"]["roots"] for s, r in result.reference.items()}
        out["pole_zero.png"] = pole_zero_png(roots)
    return out


def write_training_artifacts(result: TrainingResult, folder: str | Path) -> list[Path]:
    """Write plots (PNG), ``relative_entropy.csv``, ``evaluation.json`` and ``reference.json``; returns the files."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    files = []
    for name, png in _pictures(result).items():
        (d / name).write_bytes(png)
        files.append(d / name)
    header, rows = entropy_table(result)
    with open(d / "relative_entropy.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(rows)
    (d / "evaluation.json").write_text(json.dumps(result.evaluation, indent=1, default=float))
    (d / "reference.json").write_text(json.dumps(result.reference, indent=1, default=str))
    return [*files, d / "relative_entropy.csv", d / "evaluation.json", d / "reference.json"]


def training_section(result: TrainingResult, title: str) -> Section:
    """An HTML section with the training run's numbers, tables and plots."""
    ev = result.evaluation
    section = Section(title).text(
        f"{result.bundle.health_method.headline}; test accuracy {ev['test_accuracy']:.4f} on {ev['test_windows']} "
        f"held-out windows; training took {result.seconds:.0f} s.")
    if result.reference:
        section.table(["sensor", "NRMSE one step", "residual acf inside bound", "ccf inside bound"],
                      [[s, r["nrmse_one_step"], r["correlations"]["acf_inside"], r["correlations"]["ccf_inside"]]
                       for s, r in result.reference.items()])
    caption = result.bundle.health_method.table_caption
    section.table(["state", "recall"], [[s, r] for s, r in ev["per_class_recall"].items()])
    header, rows = entropy_table(result)
    section.text(caption)
    section.table(header, rows)
    for name, png in _pictures(result).items():
        section.image(png, name)
    return section


def run_metrics(result: TrainingResult) -> dict[str, float]:
    """Metrics of a training run, MLflow keys: NRMSE, Q/S or γ per sensor, accuracy on the held-out windows
    (``test_accuracy``), per-class recall and the weakest one (``recall_min``), training time [s]."""
    ev = result.evaluation
    metrics: dict[str, float] = {"test_accuracy": ev["test_accuracy"],
                                 "test_accuracy_with_open_set": ev["test_accuracy_with_open_set"],
                                 "known_rejected": ev["known_rejected"], "ece": ev["ece"],
                                 "train_seconds": result.seconds}
    for sensor, r in result.reference.items():
        metrics[f"nrmse.{sensor}"] = r["nrmse_one_step"]
        summary = r["summary"]
        if "gamma" in summary:
            metrics[f"gamma.{sensor}"] = summary["gamma"]
        else:
            for key in ("Q", "Q_p", "S", "S_p"):
                metrics[f"{key}.{sensor}"] = summary["validation"][key]
        metrics[f"acf_inside.{sensor}"] = r["correlations"]["acf_inside"]
    metrics.update({f"recall.{s}": v for s, v in ev["per_class_recall"].items()})
    metrics["recall_min"] = weakest_recall(ev["per_class_recall"])
    if "rule_temperature" in ev:
        metrics["rule_temperature"] = ev["rule_temperature"]
    return metrics
