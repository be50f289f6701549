"""``hydrowatch simulate`` end to end, in a subprocess: files per state, labels, formats, bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hydrowatch.cli import main
from hydrowatch.io import read_recording
from hydrowatch.plant.faults import STUDY_STATES
from hydrowatch.plant.parameters import PlantParameters


def _simulate(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hydrowatch", "simulate", *args], capture_output=True, text=True,
                          timeout=300, cwd=Path(__file__).resolve().parents[1])


def test_writes_one_labelled_mcap_per_state(tmp_path):
    done = _simulate("--out", str(tmp_path), "--states", "healthy,load_alert,valve_coil_warning",
                     "--seconds", "5", "--volts", "1:3", "--seed", "3")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["states"] == ["healthy", "load_alert", "valve_coil_warning"]
    assert summary["seconds"] == 5.0 and summary["seed"] == 3 and summary["format"] == "mcap"
    assert sorted(Path(f).name for f in summary["files"]) == ["healthy.mcap", "load_alert.mcap",
                                                             "valve_coil_warning.mcap"]
    recs = {r.state: r for r in (read_recording(f) for f in summary["files"])}
    assert set(recs) == set(summary["states"])
    for state, rec in recs.items():
        assert len(rec) == 1000 and rec.meta["machine"] == state
        assert 1.0 <= rec["voltage"].min() and rec["voltage"].max() <= 3.0
    assert recs["load_alert"]["torque"].mean() > 1.5 * recs["healthy"]["torque"].mean()  # heavier brake


def test_parquet_noise_off_and_replayed_command(tmp_path):
    command = tmp_path / "cmd.csv"
    command.write_text("voltage\n" + "\n".join(["2.0"] * 600) + "\n")
    out = tmp_path / "out"
    nominal = tmp_path / "nominal.json"
    PlantParameters(TL=12.0, Ctm=6e-13).to_json(nominal)
    done = _simulate("--out", str(out), "--states", "healthy,motor_leak_alert", "--command", str(command),
                     "--no-noise", "--format", "parquet", "--nominal", str(nominal))
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["seconds"] == 3.0 and summary["command"] == str(command) and summary["noise"] is False
    healthy = read_recording(out / "healthy.parquet")
    leak = read_recording(out / "motor_leak_alert.parquet")
    assert healthy.state == "healthy" and leak.state == "motor_leak_alert"
    np.testing.assert_array_equal(healthy["voltage"], np.full(600, 2.0))
    assert np.ptp(healthy["speed"]) < 1e-6  # settled, noiseless
    assert healthy.meta["parameters"]["TL"] == 12.0  # the given healthy machine
    assert leak["speed"][-1] / healthy["speed"][-1] == pytest.approx(0.70, abs=0.005)  # calibrated against it


def test_default_states_are_the_studys_seven(tmp_path):
    done = _simulate("--out", str(tmp_path), "--seconds", "0.5", "--effects", "pump_ripple")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["states"] == list(STUDY_STATES) and "pump_ripple" in summary["effects"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"{s}.mcap" for s in STUDY_STATES)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--states", "healthy,gearbox_alert"], "health state must be one of"),
        (["--volts", "4:0"], "voltage range"),
        (["--command", "missing.csv"], "missing.csv"),
        (["--effects", "warp_drive"], "effect id must be one of"),
        (["--seconds", "-1"], "seconds must be"),
    ],
)
def test_bad_input_is_one_clean_line(tmp_path, capsys, args, message):
    assert main(["simulate", "--out", str(tmp_path / "o"), *args]) == 2  # in-process: the same error path
    captured = capsys.readouterr()
    assert message in captured.err and len(captured.err.strip().splitlines()) == 1
    assert captured.out == ""


def test_a_model_saved_by_gap_drives_the_simulation(tmp_path, capsys):
    """--nominal takes 'hydrowatch gap --save-model' output: its parameters and its effects."""
    from hydrowatch.gap.report import MODEL_SCHEMA

    heavier = PlantParameters().replace(TL=13.0)
    model = {"schema": MODEL_SCHEMA, "parameters": heavier.to_dict(),
             "effects": {"quadratic_drag": {"Kd": 0.05}}}
    (tmp_path / "model.json").write_text(json.dumps(model))
    for name, extra in (("plain", []), ("model", ["--nominal", str(tmp_path / "model.json")])):
        assert main(["simulate", "--out", str(tmp_path / name), "--states", "healthy", "--seconds", "5",
                     "--volts", "1.9:2.1", "--no-noise", "--format", "parquet", *extra]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["effects"] == {"quadratic_drag": {"Kd": 0.05}}
    plain = read_recording(tmp_path / "plain" / "healthy.parquet")
    saved = read_recording(tmp_path / "model" / "healthy.parquet")
    # A heavier brake plus drag: the machine runs slower and the shaft carries more torque.
    assert saved["speed"][-200:].mean() < 0.95 * plain["speed"][-200:].mean()
    assert saved["torque"][-200:].mean() > plain["torque"][-200:].mean() + 2.0
