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
    monkeypatch.setattr(hydrowatch.training, "load_bundle", lambda *a: SimpleNamespace(version=TRAINED["version"]))
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
               "mlflow ui --backend-store-uri sqlite:///mlruns/m.db"]),
    ("score", ["test/load_alert.parquet: 3 windows: healthy 1, load_alert 1, invalid 1; accuracy 50.0 %",
               "last verdict, window from 5.0 s: load_alert (p = 0.93)",
               "pump_leak: alert in 448.7 operating s after the last window (95 %: 401.2–512.0 s)",
               "--json for every window"]),
    ("gap", ["sim-to-real gap of rig.mcap: mismatch found", "missing physics: transport_delay (tau 0.0121)",
             "located: flow in fast command changes (42.0 % of the samples)",
             "flow 0.310 → 0.120 → 0.050, speed 0.200 → 0.100 → 0.090",
             "the valve relation breaks. (the rest in the report's summary)",
             "gap.json", "next: open "]),
    ("demo", ["finished in 182 s: 2 of 4 machines need attention", "  m2       pump_leak_alert",
              "  m4       load_warning", "healthy: m1, m3", "champion: parity",
              "bj       training 99.0 %, duty_cycle 28.0 %",
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
