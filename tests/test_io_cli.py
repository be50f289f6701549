"""hydrowatch info / import / export: outputs, one-line errors and exit codes."""

import json
import subprocess
import sys

import numpy as np
import pytest

from hydrowatch.cli import main
from hydrowatch.io import read_recording, write_recording
from hydrowatch.recording import Recording


@pytest.fixture
def csv_file(tmp_path):
    n = 400
    t = np.arange(n) / 200.0
    lines = ["t,voltage [V],flow [L/min],speed [rad/s],torque [N·m]"]
    lines += [f"{t[i]:.3f},{np.sin(t[i]):.6f},{20 + i % 7},{50 + i % 5},{30 + i % 3}" for i in range(n)]
    path = tmp_path / "rig run 1.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_import_then_info_then_export_round_trip(tmp_path, csv_file, capsys):
    mcap = tmp_path / "rig.mcap"
    code, out, err = run_cli(
        capsys,
        "import",
        csv_file,
        "--out",
        mcap,
        "--label",
        "relief_spring_warning",
        "--fleet",
        "north",
        "--machine",
        "rig1",
    )
    assert code == 0 and err == ""
    assert out.startswith(f"wrote {mcap}: 400 samples, 0.000-1.995 s") and "relief_spring_warning" in out
    code, out, _ = run_cli(capsys, "info", mcap, "--json")
    info = json.loads(out)
    assert code == 0 and info["finished"] and info["messages"] == 4
    assert info["channels"][0]["topic"] == "hydro/north/rig1/sensors" and info["channels"][0]["samples"] == 400
    assert info["metadata"]["hydrowatch"]["state"] == "relief_spring_warning"
    code, out, _ = run_cli(capsys, "info", mcap)
    assert "hydro/north/rig1/sensors  hydrowatch.sensor_chunk.v2" in out and "status:    complete: 4 messages" in out
    parquet = tmp_path / "rig.parquet"
    assert run_cli(capsys, "export", mcap, "--out", parquet)[0] == 0
    back = read_recording(parquet)
    assert back.state == "relief_spring_warning" and back.meta["machine"] == "rig1"
    np.testing.assert_array_equal(back["flow"], 20 + np.arange(400) % 7)


def test_import_missing_column_is_one_line_and_exit_2(tmp_path, csv_file, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(",".join(line.split(",")[:2]) for line in csv_file.read_text().splitlines()) + "\n")
    code, out, err = run_cli(capsys, "import", bad, "--out", tmp_path / "x.mcap")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"hydrowatch import: error: {bad}: the command 'voltage' and at "
                                                    "least one sensor of ['flow', 'speed', 'torque'] must be present")
    assert "Got no ['one of flow, speed, torque']" in err
    assert not (tmp_path / "x.mcap").exists()  # nothing half-written


def test_import_a_csv_without_torque_then_export_it(tmp_path, csv_file, capsys):
    sparse = tmp_path / "no torque.csv"
    sparse.write_text("\n".join(",".join(line.split(",")[:4]) for line in csv_file.read_text().splitlines()) + "\n")
    code, out, _ = run_cli(capsys, "import", sparse, "--out", tmp_path / "s.mcap", "--label", "healthy")
    assert code == 0 and "channels voltage,flow,speed," in out
    code, _, _ = run_cli(capsys, "export", tmp_path / "s.mcap", "--out", tmp_path / "s.csv")
    assert code == 0
    assert (tmp_path / "s.csv").read_text().splitlines()[0] == '"t","voltage","flow","speed","state"'


def test_import_unknown_label_and_wrong_suffix(tmp_path, csv_file, capsys):
    code, _, err = run_cli(capsys, "import", csv_file, "--out", tmp_path / "x.mcap", "--label", "broken")
    assert code == 2 and "health label given with --label must be 'healthy'" in err and "Got 'broken'" in err
    code, _, err = run_cli(capsys, "import", csv_file, "--out", tmp_path / "x.parquet")
    assert code == 2 and "--out must end in .mcap" in err


def test_export_truncated_mcap_needs_recover(tmp_path, capsys):
    n = 200 * 60
    t = np.arange(n) / 200.0
    rng = np.random.default_rng(3)
    rec = Recording(t, {c: rng.normal(size=n) for c in ("voltage", "flow", "speed", "torque")}, {"state": "healthy"})
    full = write_recording(rec, tmp_path / "full.mcap")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    code, out, err = run_cli(capsys, "export", cut, "--out", tmp_path / "cut.csv")
    assert code == 2 and "file must be a finished MCAP. Got unfinished file" in err and "--recover" in err
    code, out, err = run_cli(capsys, "export", cut, "--out", tmp_path / "cut.csv", "--recover")
    assert code == 0 and "recovered" in out
    back = read_recording(tmp_path / "cut.csv")
    assert 0 < len(back) < n and len(back) % 100 == 0  # whole 0.5 s chunks only
    np.testing.assert_array_equal(back["torque"], rec["torque"][: len(back)])
    code, out, _ = run_cli(capsys, "info", cut)
    assert code == 0 and "unfinished file" in out and f"{len(back)} samples" in out


def test_errors_never_print_a_traceback(tmp_path, capsys):
    garbage = tmp_path / "g.mcap"
    garbage.write_bytes(b"\x89MCAP0\r\n" + b"\xff" * 100)
    for argv in (["export", garbage, "--out", tmp_path / "g.csv"], ["info", tmp_path / "none.mcap"]):
        code, _, err = run_cli(capsys, *argv)
        assert code == 2 and err.count("\n") == 1, err
    # the installed entry point, end to end (one subprocess: starting the CLI imports every command)
    proc = subprocess.run([sys.executable, "-m", "hydrowatch", "info", str(garbage)], capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert (
        proc.stderr.startswith(f"hydrowatch info: error: {garbage}: file must be an MCAP file. Got: ")
        and proc.stderr.count("\n") == 1
    )
