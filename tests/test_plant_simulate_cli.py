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
        (["--degrade", "load:0:1"], "--degrade must have the form FAULT:FROM:TO:SECONDS"),
        (["--degrade", "gearbox:0:1:60"], "--degrade FAULT must be one of"),
        (["--degrade", "load:x:1:60"], "--degrade FROM must be a number. Got 'x'"),
        (["--degrade", "load:0:5:60"], "--degrade TO must be an index in [0, 3.33)"),
        (["--degrade", "load:0:1:-5"], "--degrade SECONDS must be > 0"),
        (["--degrade", "load:0:1:60:cubic"], "--degrade shape must be one of"),
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


def test_degrade_writes_a_part_wearing_labelled_per_sample(tmp_path, capsys):
    from hydrowatch.plant.faults import speed_drop
    from hydrowatch.plant.fleet import DegradationPath
    from hydrowatch.plant.paths import parse_degradation, path_index

    assert parse_degradation("valve_coil:0.2:1.2:600:exp") == DegradationPath(
        "valve_coil", 0.0, 600.0, final_drop=0.36, start_drop=0.06, shape="exp")
    hold = tmp_path / "hold.csv"  # 40 s at 2 V, where the index is defined
    hold.write_text("t,voltage\n" + "".join(f"{k / 200:.3f},2.0\n" for k in range(8000)))
    assert main(["simulate", "--out", str(tmp_path), "--degrade", "load:0:1.2:40", "--command", str(hold),
                 "--no-noise", "--format", "parquet", "--seed", "4"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["states"] == [] and summary["degrade"] == ["load:0:1.2:40"]
    rec = read_recording(tmp_path / "degrade_load.parquet")
    assert len(rec) == 8000
    labels = rec.meta["labels"]
    assert labels[0] == "healthy" and labels[-1] == "load_alert" and "load_warning" in set(labels)
    # at a constant 2 V the speed falls as the index says: drop = index x 0.30
    speed = rec["speed"]
    path = parse_degradation("load:0:1.2:40")
    for t in (20.0, 39.0):
        i = int(t * 200)
        assert 1.0 - speed[i] / speed[200] == pytest.approx(0.30 * path_index(path, t), abs=0.02)
    assert speed_drop("load", 0.0) == 0.0
