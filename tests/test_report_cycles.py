"""The report's fleet of a rig's cycles machines (``demo --rig``): each machine's verdict on its last cycle, most
urgent first, and each component's verdict, since which cycle, with the cycles read per state on the bus."""

from __future__ import annotations

import html
import re
from pathlib import Path
from typing import Any

from hydrowatch.report.demo import cycles_fleet_section
from hydrowatch.report.html import write_html


def _rows(machine: str, valve: list[str]) -> list[dict[str, Any]]:
    """Bus rows (``to_pylist`` form, probabilities as a list of structs) of cycles 0, 1, … of 60 s: the pump healthy
    (``0``), the valve as given; in the order a scorer publishes them (cycle after cycle)."""
    rows = []
    for cycle, state in enumerate(valve):
        for component, s, healthy in (("pump", "0", "0"), ("valve", state, "100")):
            p = 0.8 if s == "unknown" else 0.95
            rows.append({"machine": machine, "cycle": cycle, "window_start": 60.0 * cycle,
                         "window_end": 60.0 * cycle + 60.0, "component": component, "state": s, "probability": p,
                         "probabilities": [{"state": healthy, "probability": p}, {"state": "x", "probability": 1 - p}],
                         "novelty": 1.6 if s == "unknown" else 0.2, "reason": None, "truth": healthy,
                         "healthy": healthy, "model_version": "hydrowatch-tiny/1"})
    return rows


def _tables(path: Path) -> list[list[list[str]]]:
    text = path.read_text(encoding="utf-8")
    cells = r"<t[dh]>(.*?)</t[dh]>"
    return [[[html.unescape(c) for c in re.findall(cells, tr)] for tr in re.findall(r"<tr>(.*?)</tr>", table)]
            for table in re.findall(r"<table>(.*?)</table>", text)]


def test_the_report_opens_with_the_cycles_machines_most_urgent_first(tmp_path: Path) -> None:
    # rows arrive interleaved between machines and out of cycle order within one: the section sorts them per machine
    rows = _rows("rig1", ["100", "100", "100"]) + _rows("rig2", ["100", "80", "80", "80"])
    rows = rows[:2] + rows[6:8] + rows[4:6] + rows[2:4] + rows[8:]
    path = write_html(tmp_path / "report.html", "rig", [cycles_fleet_section(rows)])
    text = path.read_text(encoding="utf-8")
    assert "1 of 2 machines need attention: rig2 (valve=80)." in html.unescape(text)
    machines, rig1, rig2 = _tables(path)
    assert machines[1] == ["rig2", "valve=80", "60", "0.95", "valve 80 (p = 0.95; healthy 100) since cycle 1", "240",
                           "4"]
    assert machines[2][:3] == ["rig1", "healthy", "0"] and machines[2][6] == "3"
    assert rig2[0][-1] == "cycles per state" and rig2[1][:3] == ["pump", "0", "healthy"]
    assert rig2[2] == ["valve", "80", "warning", "0.95", "100", "1", "0.2", "100", "100: 1, 80: 3"]
    assert rig1[2][-1] == "100: 3"


def test_an_unknown_component_makes_its_machine_unknown_first_in_the_report(tmp_path: Path) -> None:
    rows = _rows("rig1", ["80"]) + _rows("rig2", ["100", "unknown"])
    machines = _tables(write_html(tmp_path / "r.html", "rig", [cycles_fleet_section(rows)]))[0]
    assert [r[:2] for r in machines[1:]] == [["rig2", "unknown"], ["rig1", "valve=80"]]
    assert machines[1][3] == "0" and machines[1][4] == "valve unknown (novelty 1.60) since cycle 1"
