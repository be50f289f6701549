"""The demo's HTML report: the live fleet first (which machines need attention, since when, why), then the
models, their accuracy on other seeds and commands, and the training detail; and the fleet section of a rig's
cycles machines (``demo --rig``: each machine's verdict and its components' from the bus's ``cycle_verdict`` rows)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hydrowatch.report.cycle_table import COMPONENT_COLUMNS, CycleTable, component_cells, cycle_row
from hydrowatch.report.fleet_table import FleetTable, wear_cells
from hydrowatch.report.html import Section, write_html
from hydrowatch.report.plots import confusion_png, timeline_png
from hydrowatch.report.training import training_section
from hydrowatch.results import TrainingResult


def accuracy_section(accuracy: Mapping[str, list[dict[str, Any]]]) -> Section:
    """Accuracy of every bundle on separately simulated recordings, one confusion matrix per command."""
    section = Section("Accuracy on recordings made apart from the training data").text(
        "Every trained state simulated again with another seed, with the training command (filtered noise "
        "0-4 V), a working duty cycle (holds, ramps, steps) and filtered noise on a narrow range (1-3 V). "
        "Windows judged 'unknown' count as wrong.")
    section.table(["model", "command", "accuracy", "windows"],
                  [[kind, a["command"], a["accuracy"], a["windows"]] for kind, runs in accuracy.items() for a in runs])
    for kind, runs in accuracy.items():
        for a in runs:
            section.image(confusion_png(a["confusion_matrix"], a["labels"], f"{kind}, {a['command']} command"),
                          f"confusion {kind} {a['command']}")
    return section


def fleet_section(live: Mapping[str, Any], states: list[str]) -> Section:
    """The live fleet: machines most urgent first (state, since when, why), then timelines of verdicts and of
    the true labels."""
    table = live["table"]
    rows = table.by_urgency()
    attention = table.attention()
    section = Section("Fleet: which machines need attention").text(
        f"{len(attention)} of {len(rows)} machines need attention"
        + (": " + ", ".join(f"{a['machine']} ({a['state']})" for a in attention) + "." if attention else "."))
    section.table(["machine", "state", "since [s]", "probability", "why", "last window end [s]", "windows"],
                  [[m, r.state, r.since_s, r.probability, r.why(), r.last_s, r.windows] for m, r in rows.items()])
    section.text(
        "The simulated fleet: m00 healthy, m01 load warning throughout, m02-m04 develop a load fault, a pump leak "
        "and a motor leak from t = 20 s to alert at t = 80 s, m05 a valve leak the model was never trained on "
        "(it should read 'unknown'), m06 a motor leak wearing slowly from new (warning from about 100 s).")
    wear = live.get("wear") or {}
    if wear:
        section.text("How worn each part is and when it will reach the alert (the scorer's index and forecast, "
                     "most urgent first: the soonest alert, then the highest index). m06's motor leak wears from new "
                     "to index 1.3 over 15 minutes: 0.48 after the default 330 s, the alert at 692 s.")
        section.table(["machine", "part", "index [95 %]", "trend / h", "time to alert [95 %]"],
                      [[m, *wear_cells(f, p)] for m, parts in wear.items() for f, p in parts.items()
                       if p.get("alert_in_s") is not None or (p.get("value") or 0.0) >= 0.15])
    section.image(timeline_png(live["timelines"], states), "verdict timelines")
    truth = {m: [(t, t + 0.1, s) for t, s in points] for m, points in live["truth"].items()}
    section.text("True labels of the simulated machines (nearest named level of the current fault):")
    section.image(timeline_png(truth, states), "true labels")
    return section


def cycles_fleet_section(rows: Sequence[Mapping[str, Any]]) -> Section:
    """The fleet of a rig's cycles machines after the bus's ``cycle_verdict`` rows (dicts with their ``machine``):
    machines most urgent first with their verdict on their last cycle (:mod:`hydrowatch.report.cycle_table`), since
    when and why; then per machine each component's last verdict, since which cycle, and the cycles read per state."""
    table, cycles = FleetTable(), CycleTable()
    by_machine: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        by_machine.setdefault(str(row["machine"]), []).append(cycle_row(row))
    for machine, mine in sorted(by_machine.items()):
        for verdict in cycles.update(machine, sorted(mine, key=lambda r: r["cycle"])):
            table.update(machine, verdict)
    attention = table.attention()
    section = Section("Fleet: which machines need attention").text(
        f"{len(attention)} of {len(table.latest())} machines need attention"
        + (": " + ", ".join(f"{a['machine']} ({a['state']})" for a in attention) + "." if attention else ".")
        + " A machine's verdict is its verdict on its last cycle: healthy when every component is in its healthy "
          "state, unknown when a component is, else the components that are not healthy (component=state).")
    section.table(["machine", "state", "since [s]", "probability", "why", "last cycle end [s]", "cycles"],
                  [[m, r.state, f"{r.since_s:.0f}", r.probability, r.why(), f"{r.last_s:.0f}", r.windows]
                   for m, r in table.by_urgency().items()])
    for machine, parts in cycles.by_machine().items():
        counts = {c: Counter(r["state"] for r in by_machine[machine] if r["component"] == c) for c in parts}
        section.text(f"{machine}: each component's verdict on the last cycle, and the cycles read per state.")
        section.table([*COMPONENT_COLUMNS, "cycles per state"],
                      [[*component_cells(c, r), ", ".join(f"{s}: {n}" for s, n in sorted(counts[c].items()))]
                       for c, r in parts.items()])
    return section


def write_demo_report(path: str | Path, results: Mapping[str, TrainingResult],
                      accuracy: Mapping[str, list[dict[str, Any]]], live: Mapping[str, Any], champion: str) -> Path:
    """Write the demo's HTML report; returns its path."""
    states = next(iter(results.values())).bundle.states
    sections = [fleet_section(live, states), Section("Models").text(
        f"{len(results)} health models were trained and tracked in MLflow ({', '.join(results)}); '{champion}', the "
        "best on the working duty cycle, holds the registry alias 'champion' and scores the live fleet.")]
    sections.append(accuracy_section(accuracy))
    sections += [training_section(r, f"Training: {kind}") for kind, r in results.items()]
    return write_html(path, "hydrowatch demo", sections)
