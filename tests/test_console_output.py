"""Output for people: ``train``, ``score``, ``gap`` and ``demo`` print a short summary on a terminal and the
same JSON as before with ``--json`` or when stdout is not a terminal (how tests and scripts call them).

The work behind each command is replaced by its recorded output (the objects below have the shapes
of contract.md and docs/), so these tests check what the commands print, not the training."""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from hydrowatch.cli import main
from hydrowatch.report.console import json_output

TRAINED = {
    "version": "sha256:0123456789abcdef0123", "method": "parity", "reference": "parity",
    "states": ["healthy", "load_warning", "load_alert"], "sensors": ["flow", "speed", "torque"],
    "nrmse_one_step": {}, "test_accuracy": 0.9929, "per_class_recall": {"healthy": 1.0, "load_warning": 0.95,
                                                                         "load_alert": 1.0},
    "test_windows": 210, "seconds": 12.34, "out": "model", "run_id": "5f1e2d", "tracking_uri": "sqlite:///mlruns/m.db",
    "model_uri": "models:/hydrowatch@champion", "registered_version": "3",
    "runs_url": "http://127.0.0.1:5000/#/experiments/1/runs?workflowType=machine_learning&viewStateShareKey=checks",
    "checks": {"training": 1.0, "duty_cycle": 0.964, "narrow_range": 0.91},
}
SCORED = {
    "source": "test/load_alert.parquet",
    "windows": [{"start_s": 0.0, "state": "healthy", "probability": 0.6, "probabilities": {}, "kl": {}},
                {"start_s": 5.0, "state": "load_alert", "probability": 0.93, "probabilities": {}, "kl": {}},
                {"start_s": 10.0, "state": "invalid", "probability": None, "probabilities": {}, "kl": {},
                 "reason": "gap"}],
    "summary": {"windows": 3, "counts": {"healthy": 1, "load_alert": 1, "invalid": 1}, "accuracy": 0.5,
                "model_version": "sha256:0123456789abcdef0123",
                "forecast": {"pump_leak": {"alert_in_s": 448.7, "ci95": [401.2, 512.0], "rate_per_h": 4.1}}},
}
GAP = {
    "mismatch": True,
    "effects": [{"id": "transport_delay", "parameters": {"tau": 0.0121}, "evidence": "valve relation lags"}],
    "located": [{"sensor": "flow", "regime": "fast command changes", "share": 0.42, "relation": "valve"}],
    "fit": {"nominal": {"flow": 0.31, "speed": 0.2}, "calibrated": {"flow": 0.12, "speed": 0.1},
            "after": {"flow": 0.05, "speed": 0.09}},
    "calibrated_parameters": {},
    "summary": "A dead time before the spool: the valve relation breaks. Not determined by this recording: Kr.",
}
DEMO = {
    "out": "demo", "report": "demo/report.html", "champion": "parity",
    "training": {"parity": {**TRAINED, "out": "demo/models/parity"}},
    "accuracy": {"parity": {"training": 1.0, "duty_cycle": 0.964, "narrow_range": 0.91},
                 "bj": {"training": 0.99, "duty_cycle": 0.28, "narrow_range": 0.25}},
    "fleet": {"m1": "healthy", "m2": "pump_leak_alert", "m3": "healthy", "m4": "load_warning"},
    "attention": [{"machine": "m2", "state": "pump_leak_alert", "since_s": 64.0, "probability": 0.93,
                   "why": "most probable trained state (p = 0.93)"},
                  {"machine": "m4", "state": "load_warning", "since_s": 2.5, "probability": 0.81,
                   "why": "most probable trained state (p = 0.81)"}],
    "wear": {"m4": {"motor_leak": {"value": 0.48, "ci95": [0.41, 0.55], "rate_per_h": 1.62, "alert_in_s": 360.0,
                                   "alert_ci95": [240.0, None]},
                    "load": {"value": 0.01, "ci95": [-0.03, 0.05], "reason": "too flat: the index rose 0.001"}}},
    "seconds": 181.6,
}


class _Stream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def test_json_when_asked_or_not_on_a_terminal() -> None:
    assert not json_output(False, _Stream(tty=True))
    assert json_output(True, _Stream(tty=True))
    assert json_output(False, _Stream(tty=False))
    assert json_output(False, object())  # type: ignore[arg-type]  # no isatty at all: a program reads it


@pytest.fixture
def commands(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """Every command's work replaced by its recorded output."""
    import hydrowatch.gap
    import hydrowatch.io
    import hydrowatch.training
    import hydrowatch.training.demo
    import hydrowatch.training.pipeline
    import hydrowatch.training.scoring

    class Analyser:
        report_, model_ = GAP, {"parameters": {}}

        def __init__(self, **_: Any) -> None:
            pass

        def fit(self, recording: Any) -> Analyser:
            return self

    monkeypatch.setattr(hydrowatch.training.pipeline, "train_each", lambda *a, **k: iter([TRAINED]))
    monkeypatch.setattr(hydrowatch.training, "load_bundle", lambda *a: SimpleNamespace(version=TRAINED["version"],
                                                                                    method=TRAINED["method"]))
    monkeypatch.setattr(hydrowatch.training.scoring, "smoothing_for", lambda bundle, n: 12)
    monkeypatch.setattr(hydrowatch.training, "recording_files", lambda data: [Path(SCORED["source"])])
    monkeypatch.setattr(hydrowatch.training, "score_recording", lambda *a: SCORED)
    monkeypatch.setattr(hydrowatch.io, "read_recording", lambda path: SimpleNamespace(meta={}))
    monkeypatch.setattr(hydrowatch.gap, "GapAnalyser", Analyser)
    monkeypatch.setattr(hydrowatch.training.demo, "run_demo", lambda settings, show: DEMO)
    return tmp_path


def _argv(name: str, tmp_path: Path) -> list[str]:
    return {"train": ["train", "--data", "data", "--out", "model"],
            "score": ["score", "--model", "model", "--data", "test"],
            "gap": ["gap", "--real", "rig.mcap", "--report", str(tmp_path / "gap.json"), "--html",
                    str(tmp_path / "gap.html")],
            "demo": ["demo", "--out", str(tmp_path / "demo")]}[name]


@pytest.mark.parametrize(("name", "expected"), [("train", TRAINED), ("score", SCORED), ("gap", GAP), ("demo", DEMO)])
def test_json_is_unchanged_when_stdout_is_not_a_terminal_or_json_is_asked(
        commands: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, name: str,
        expected: dict) -> None:
    if name == "gap":
        monkeypatch.setattr("hydrowatch.gap.html.write_html", lambda analyser, path: path)
    assert main(_argv(name, commands)) == 0
    assert json.loads(capsys.readouterr().out) == expected
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    assert main([*_argv(name, commands), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == expected


@pytest.mark.parametrize(("name", "lines"), [
    ("train", ["trained parity model sha256:0123456789ab… on 3 states in 12.3 s",
               "test accuracy 99.3 % on 210 windows; weakest recall load_warning 95.0 %",
               "accuracy on other commands: training 100.0 %, duty_cycle 96.4 %, narrow_range 91.0 %",
               "registered models:/hydrowatch@champion (version 3)", "next: hydrowatch score --model model",
               "mlflow ui --backend-store-uri sqlite:///mlruns/m.db, then open http://127.0.0.1:5000/#/experiments/1/"
               "runs?workflowType=machine_learning&viewStateShareKey=checks"]),
    ("score", ["test/load_alert.parquet: 3 windows: healthy 1, load_alert 1, invalid 1; accuracy 50.0 %",
               "last verdict, window from 5.0 s: load_alert (p = 0.93)",
               "pump_leak: alert in 448.7 operating s after the last window (95 %: 401.2–512.0 s)",
               "--json for every window"]),
    ("gap", ["sim-to-real gap of rig.mcap: mismatch found", "missing physics: transport_delay (tau 0.0121)",
             "located: flow in fast command changes (42.0 % of the samples)",
             "flow 0.310 → 0.120 → 0.050, speed 0.200 → 0.100 → 0.090",
             "the valve relation breaks. (the rest in the report's summary)",
             "gap.json", "next: open "]),
    ("demo", ["finished in 182 s: 2 of 4 machines need attention",
              "  m2       pump_leak_alert since 64 s: most probable trained state (p = 0.93)",
              "  m4       load_warning since 2 s", "healthy: m1, m3", "champion: parity",
              "bj       training 99.0 %, duty_cycle 28.0 %",
              "  m4       wear: motor_leak 0.48 [0.41–0.55] ↑1.62/h alert in 6 min (95 %: 4 min–open)",
              "next: open demo/report.html"]),
])
def test_a_terminal_gets_a_short_summary_with_the_key_numbers(
        commands: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, name: str,
        lines: list[str]) -> None:
    if name == "gap":
        monkeypatch.setattr("hydrowatch.gap.html.write_html", lambda analyser, path: path)
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    assert main(_argv(name, commands)) == 0
    out = capsys.readouterr().out
    for line in lines:
        assert line in out, (line, out)
    assert not out.lstrip().startswith("{") and len(out.splitlines()) <= 12
    if name == "demo":  # the fleet comes first: what needs attention before the models
        assert out.index("pump_leak_alert") < out.index("champion")
    if name == "gap":
        assert json.loads((commands / "gap.json").read_text()) == GAP  # the report file is written either way


def test_the_fleet_comes_most_urgent_first_with_since_when_and_why() -> None:
    """The demo report's first section and the demo summary's ``attention``: alerts, then faults never trained on,
    then warnings, invalid, healthy; since = start of the current run of that state."""
    from hydrowatch.report.demo import fleet_section
    from hydrowatch.report.fleet_table import FleetTable

    table = FleetTable()
    verdicts = [("m0", "healthy", None), ("m1", "load_warning", None), ("m2", "healthy", None),
                ("m5", "unknown", "no trained state explains the window (open-set rule)"),
                ("m2", "pump_leak_alert", None), ("m2", "pump_leak_alert", None), ("m3", "invalid", "gap")]
    for k, (machine, state, reason) in enumerate(verdicts):
        table.update(machine, {"window_start": 5.0 * k, "window_end": 5.0 * k + 5, "state": state,
                               "probability": 0.9 if reason is None else 0.0, "reason": reason})
    assert list(table.by_urgency()) == ["m2", "m5", "m1", "m3", "m0"]
    attention = table.attention()
    assert [a["machine"] for a in attention] == ["m2", "m5", "m1", "m3"]
    assert attention[0] == {"machine": "m2", "state": "pump_leak_alert", "since_s": 20.0, "probability": 0.9,
                            "why": "most probable trained state (p = 0.90)"}
    assert attention[1]["why"].startswith("no trained state explains")
    states = ["healthy", "load_warning", "pump_leak_alert"]
    live = {"table": table, "timelines": {"m0": [(0.0, 5.0, "healthy")]}, "truth": {"m0": [(0.0, "healthy")]}}
    section = fleet_section(live, states)
    assert section.title == "Fleet: which machines need attention"
    assert "4 of 5 machines need attention: m2 (pump_leak_alert), m5 (unknown)" in section.parts[0]
    rows = section.parts[1]
    assert rows.index("<td>m2</td>") < rows.index("<td>m5</td>") < rows.index("<td>m1</td>") < rows.index(
        "<td>m0</td>")


def test_each_machines_wear_comes_most_urgent_first_in_watch_and_the_demo_report() -> None:
    """FleetWear joins the verdicts' index and the forecasts: machines by their soonest alert, parts soonest alert
    first then by index; watch prints the worn parts, the demo report tabulates them."""
    from hydrowatch.report.demo import fleet_section
    from hydrowatch.report.fleet_table import FleetTable, FleetWear, render_wear

    wear = FleetWear()
    index = {"load": {"value": 0.02, "ci95": [-0.02, 0.06]}, "motor_leak": {"value": 0.48, "ci95": [0.41, 0.55]},
             "valve_coil": {"value": 0.3, "ci95": [0.2, 0.4]}}
    wear.add_verdict("f/a", {"state": "healthy", "degradation": index})
    wear.add_verdict("f/a", {"state": "healthy", "degradation": None})  # a verdict without one keeps the last
    wear.add_forecast("f/a", {"motor_leak": {"alert_in_s": 3600.0, "ci95": [3000.0, 4500.0], "rate_per_h": 0.5},
                              "load": {"alert_in_s": None, "ci95": [None, None], "reason": "too flat: x"}})
    wear.add_verdict("f/b", {"state": "healthy", "degradation": {"load": {"value": 0.9, "ci95": [0.85, 0.95]}}})
    wear.add_forecast("f/b", {"load": {"alert_in_s": 100.0, "ci95": [50.0, 200.0], "rate_per_h": 3.0}})
    wear.add_verdict("f/c", {"state": "healthy", "degradation": {"load": {"value": 0.01, "ci95": [0.0, 0.02]}}})
    found = wear.by_machine()
    assert list(found) == ["f/b", "f/a", "f/c"] and list(found["f/a"]) == ["motor_leak", "valve_coil", "load"]
    text = render_wear(found).splitlines()
    assert text[0] == "wear (most urgent first)" and len(text) == 3  # f/c has nothing worn to show
    assert text[1].startswith("f/b") and "load 0.90 [0.85–0.95] ↑3.00/h alert in 100 s (95 %: 50 s–3 min)" in text[1]
    assert text[2].index("motor_leak 0.48") < text[2].index("valve_coil 0.30") and "load" not in text[2]
    live = {"table": FleetTable(), "timelines": {}, "truth": {}, "wear": found}
    cells = fleet_section(live, ["healthy"]).parts[4]
    assert cells.index("<td>f/b</td>") < cells.index("<td>motor_leak</td>") < cells.index("<td>valve_coil</td>")
    assert "alert in 60 min (95 %: 50 min–75 min)" in cells
    from hydrowatch.report.fleet_table import wear_text
    assert wear_text("load", {"value": 1.02, "alert_in_s": 0.0, "alert_ci95": [0.0, 0.0]}) == "load 1.02 at alert"
