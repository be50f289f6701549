"""``hydrowatch demo --rig NAME``: the pipeline on a rig's recorded cycles (docs/rigs.md, issue 17).

1. import: the rig's data read with its description (:func:`hydrowatch.io.rig_cycles.read_rig_data`), cycles
   counted per component state, and written as a recording of ``rig_cycles`` messages (``<out>/<rig>.mcap``,
   what ``hydrowatch import --rig`` writes);
2. train: the ``cycles`` method, evaluated on the honest split per component, logged to MLflow and registered
   (:func:`~hydrowatch.training.rig_pipeline.train_rig_and_track`), as ``hydrowatch-<rig>@champion``
   (:func:`~hydrowatch.training.options.mlflow_name`, the plant's ``hydrowatch@champion`` left alone);
3. replay on the bus: the scorer service loads the registered model from the registry, the replay service
   publishes the recording, every cycle's per-component verdicts are collected off ``…/cycle_health``
   (:func:`~hydrowatch.training.rig_bus.score_on_bus`); the registered model also scores the cycles offline
   (``scores.json``, the ``score --json`` object), and the bus's verdicts are compared with it;
4. report: ``report.html`` opening with the fleet (the replayed machine's verdict on its last cycle, since when and
   why, and each component's; :func:`~hydrowatch.report.demo.cycles_fleet_section`), then the counts, the honest
   split's figures and confusion matrices per component, and the replay's counts.

The replay scores cycles the model was fitted on (all of them): its accuracy shows that the registered model reads
the data back as trained, not how well it generalises; the honest split says that.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

from hydrowatch.io.rig_cycles import read_rig_data, write_rig_recording
from hydrowatch.io.wide import Cycles
from hydrowatch.methods.cycles.train import state_name
from hydrowatch.report.demo import cycles_fleet_section
from hydrowatch.report.html import Section, write_html
from hydrowatch.report.plots import confusion_png
from hydrowatch.rig import RigDescription, data_root
from hydrowatch.rig.description import rig_text
from hydrowatch.training.bundle import load_bundle
from hydrowatch.training.options import DEFAULT_ALIAS, TrainingSettings
from hydrowatch.training.rig_bus import score_on_bus
from hydrowatch.training.rig_pipeline import score_cycles, train_rig_and_track

DEMO_FLEET = "demo"
"""Fleet id of the demo's recording and verdicts (``hydro/demo/<rig>/cycles``)."""


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
    ``data``, ``cycles``, ``imported`` (component → state → cycles), ``recording`` (the imported MCAP file),
    ``bus_seconds`` (replay start to last verdict), ``honest`` (component → ``accuracy``, ``macro_f1``, ``unknown``,
    ``features``), ``run_id``, ``model_uri``, ``tracking_uri``, ``runs_url``, ``replay`` (component →
    :func:`bus_figures`), ``out``, ``report``, ``scores``."""
    out = Path(out)
    folder = rig_data_folder(rig, data)
    description, text = rig_text(rig)
    cycles = read_rig_data(folder, description)
    imported = import_counts(description, cycles)
    out.mkdir(parents=True, exist_ok=True)
    recording = write_rig_recording(out / f"{description.name}.mcap", cycles, description, text, fleet=DEMO_FLEET,
                                    machine=description.name)
    result, trained = train_rig_and_track(
        rig, folder, out / "model", TrainingSettings(method="cycles"), tracking=tracking, alias=DEFAULT_ALIAS,
        report_dir=out / "training")  # experiment and registered model: hydrowatch-<rig> (options.mlflow_name)
    bundle = load_bundle(trained["model_uri"], trained["tracking_uri"])
    scored = score_cycles(bundle, cycles)
    (out / "scores.json").write_text(json.dumps(scored))
    components = list(scored["summary"]["counts"])
    rows, seconds = score_on_bus(recording, trained["model_uri"], trained["tracking_uri"], fleet=DEMO_FLEET,
                                 rows=len(cycles) * len(components), logs=out / "logs")
    replay = bus_figures(rows, scored, components)
    report = write_html(out / "report.html", f"hydrowatch on rig {description.name}",
                        [cycles_fleet_section(rows),
                         *_sections(description, folder, imported, result.evaluation, trained, replay)])
    return {"rig": description.name, "data": str(folder), "cycles": len(cycles), "imported": imported,
            "recording": str(recording), "bus_seconds": seconds,
            "honest": trained["components"], "run_id": trained["run_id"], "model_uri": trained["model_uri"],
            "tracking_uri": trained["tracking_uri"], "runs_url": trained["runs_url"], "replay": replay,
            "out": str(out), "report": str(report), "scores": str(out / "scores.json")}


def bus_figures(rows: list[dict[str, Any]], offline: dict[str, Any], components: list[str]) -> dict[str, Any]:
    """Per component, of the bus's ``cycle_verdict`` rows: ``cycles`` (rows received), ``counts`` (state → rows),
    ``accuracy`` (share equal to the cycle's ``truth``; None without labels) and ``offline_agreement`` (share equal
    to ``score`` of the same cycle offline, ``offline``: :func:`score_cycles`'s object)."""
    out: dict[str, Any] = {}
    for c in components:
        mine = [r for r in rows if r["component"] == c]
        labelled = [r for r in mine if r["truth"] is not None]
        same = [r["state"] == offline["cycles"][r["cycle"]]["components"][c]["state"] for r in mine]
        out[c] = {"cycles": len(mine), "counts": dict(sorted(Counter(r["state"] for r in mine).items())),
                  "accuracy": sum(r["state"] == r["truth"] for r in labelled) / len(labelled) if labelled else None,
                  "offline_agreement": sum(same) / len(same) if same else None}
    return out


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
    played = Section("Replay on the bus: every cycle scored by the registered model").text(
        "The replay service published the imported recording on the bus; the scorer service, with the model loaded "
        "from the registry, answered each cycle with a verdict per component. The model is fitted on every cycle, so "
        "this reads the training data back (what the registry serves), not a measure of how it generalises: the "
        "honest split above is. 'same as offline': share of verdicts equal to `score` of the same cycle.")
    played.table(["component", "verdicts received", "cycles per verdict", "accuracy", "same as offline"],
                 [[c, r["cycles"], ", ".join(f"{s}: {n}" for s, n in r["counts"].items()), r["accuracy"],
                   r["offline_agreement"]] for c, r in replay.items()])
    return [data, honest, played]
