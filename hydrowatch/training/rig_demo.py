"""``hydrowatch demo --rig NAME``: the pipeline on a rig's recorded cycles (docs/rigs.md, issue 17).

1. import: the rig's data folder read with its description (:func:`hydrowatch.io.rig_cycles.read_rig_data`), cycles
   counted per component state;
2. train: the ``cycles`` method, evaluated on the honest split per component, logged to MLflow and registered
   (:func:`~hydrowatch.training.rig_pipeline.train_rig_and_track`), as ``hydrowatch-<rig>@champion``;
3. replay: the registered model loaded back from the registry and every cycle scored in recording order
   (:func:`~hydrowatch.training.rig_pipeline.score_cycles`), written to ``scores.json``;
4. report: ``report.html`` with the counts, the honest split's figures and confusion matrices per component, and
   the replay's counts.

The replay scores cycles the model was fitted on (all of them): its accuracy shows that the registered model reads
the data back as trained, not how well it generalises; the honest split says that.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

from hydrowatch.io.rig_cycles import read_rig_data
from hydrowatch.io.wide import Cycles
from hydrowatch.methods.cycles.train import state_name
from hydrowatch.report.html import Section, write_html
from hydrowatch.report.plots import confusion_png
from hydrowatch.rig import RigDescription, data_root
from hydrowatch.rig.description import rig_text
from hydrowatch.training.bundle import load_bundle
from hydrowatch.training.options import DEFAULT_ALIAS, TrainingSettings
from hydrowatch.training.rig_pipeline import score_cycles, train_rig_and_track


def rig_data_folder(rig: str, data: str | Path | None) -> Path:
    """``data``, else the shared data folder of a shipped rig (``data_root() / rig``)."""
    return Path(data) if data is not None else data_root() / rig


def import_counts(rig: RigDescription, cycles: Cycles) -> dict[str, dict[str, int]]:
    """Cycles per state of each component, states in the description's order."""
    out = {}
    for c in (c for c in rig.components if c in cycles.labels):
        counted = Counter(map(state_name, cycles.labels[c]))
        out[c] = {s: counted[s] for s in map(state_name, rig.label(c).values) if counted[s]}
    return out


def run_rig_demo(rig: str, out: str | Path, *, data: str | Path | None = None,
                 tracking: str | None = None) -> dict[str, Any]:
    """Import, train, log, replay from the registry, report (module docstring); returns the summary: ``rig``,
    ``data``, ``cycles``, ``imported`` (component → state → cycles), ``honest`` (component → ``accuracy``,
    ``macro_f1``, ``unknown``, ``features``), ``run_id``, ``model_uri``, ``tracking_uri``, ``runs_url``,
    ``replay`` (component → ``counts``, ``accuracy``), ``out``, ``report``, ``scores``."""
    out = Path(out)
    folder = rig_data_folder(rig, data)
    description, _ = rig_text(rig)
    cycles = read_rig_data(folder, description)
    imported = import_counts(description, cycles)
    result, trained = train_rig_and_track(
        rig, folder, out / "model", TrainingSettings(method="cycles"), tracking=tracking,
        experiment=f"hydrowatch-{description.name}", model_name=f"hydrowatch-{description.name}",
        alias=DEFAULT_ALIAS, report_dir=out / "training")
    bundle = load_bundle(trained["model_uri"], trained["tracking_uri"])
    scored = score_cycles(bundle, cycles)
    (out / "scores.json").write_text(json.dumps(scored))
    replay = {c: {"counts": scored["summary"]["counts"][c], "accuracy": scored["summary"]["accuracy"][c]}
              for c in scored["summary"]["counts"]}
    report = write_html(out / "report.html", f"hydrowatch on rig {description.name}",
                        _sections(description, folder, imported, result.evaluation, trained, replay))
    return {"rig": description.name, "data": str(folder), "cycles": len(cycles), "imported": imported,
            "honest": trained["components"], "run_id": trained["run_id"], "model_uri": trained["model_uri"],
            "tracking_uri": trained["tracking_uri"], "runs_url": trained["runs_url"], "replay": replay,
            "out": str(out), "report": str(report), "scores": str(out / "scores.json")}


def _sections(rig: RigDescription, folder: Path, imported: dict[str, dict[str, int]], evaluation: dict[str, Any],
              trained: dict[str, Any], replay: dict[str, Any]) -> list[Section]:
    data = Section("Import").text(
        f"{sum(next(iter(imported.values())).values()) if imported else 0} cycles of {rig.window.length_s:g} s, "
        f"{len(rig.channels.names)} channels on a {rig.window.grid_hz:g} Hz grid, read from {folder}.")
    data.table(["component", "cycles per state"],
               [[c, ", ".join(f"{s}: {n}" for s, n in counts.items())] for c, counts in imported.items()])
    honest = Section("Training: the honest split per component").text(
        f"{evaluation['split']}. Features chosen on the training cycles only. MLflow run {trained['run_id']} "
        f"({trained['tracking_uri']}), registered as {trained['model_uri']}.")
    figures = evaluation["components"]
    honest.table(["component", "accuracy", "macro-F1", "read unknown", "features", "train / test cycles"],
                 [[c, f["accuracy"], f["macro_f1"], f["unknown"], f["features"],
                   f"{f['train_cycles']} / {f['test_cycles']}"] for c, f in figures.items()])
    for c, f in figures.items():
        states = list(f["per_class_recall"])
        honest.image(confusion_png(f["confusion_matrix"], [*states, "unknown"], f"{c}, honest split"), c)
    played = Section("Replay: every cycle scored by the registered model").text(
        "The model is fitted on every cycle, so this reads the training data back (what the registry serves), "
        "not a measure of how it generalises: the honest split above is.")
    played.table(["component", "cycles per verdict", "accuracy"],
                 [[c, ", ".join(f"{s}: {n}" for s, n in r["counts"].items()), r["accuracy"]]
                  for c, r in replay.items()])
    return [data, honest, played]
