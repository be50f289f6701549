"""hydrowatch rig: checks a description, reads its data, refuses bad input in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hydrowatch.cli import main
from hydrowatch.io.tabular import write_table
from hydrowatch.rig import data_root


def _run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_the_shipped_and_the_plant_descriptions_are_summarised(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, "rig", "uci-hydraulic", "--json")
    summary = json.loads(out)
    assert code == 0 and summary["layout"] == "wide" and len(summary["channels"]) == 17
    assert summary["components"]["accumulator"] == {"values": [130.0, 115.0, 100.0, 90.0], "healthy": 130.0}
    code, out, _ = _run(capsys, "rig", "plant")
    assert code == 0 and out.startswith("rig plant: long layout, fixed windows of 5 s every 5 s on a 200 Hz grid")
    assert "  voltage: V, command, 200 Hz from voltage" in out


def test_the_plants_export_is_read_and_counted(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    n = 3000
    t = np.arange(n) / 200.0
    channels = {"voltage": np.sin(t), "flow": np.ones(n), "speed": np.ones(n), "torque": np.ones(n)}
    write_table(tmp_path / "run.parquet", t, channels, np.full(n, "healthy", dtype=object), {})
    code, out, _ = _run(capsys, "rig", "plant", "--data", tmp_path / "run.parquet", "--json")
    assert code == 0 and json.loads(out)["data"]["counts"] == {"state": {"healthy": 3}}


def test_bad_rigs_and_bad_data_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _run(capsys, "rig", "zema")
    assert code == 2 and "rig must be a .toml file, 'plant' or one of ['uci-hydraulic']" in err
    (tmp_path / "bad.toml").write_text('name = "x"\n[window]\nkind = "cycle"\n', encoding="utf-8")
    code, _, err = _run(capsys, "rig", tmp_path / "bad.toml")
    assert code == 2 and "bad.toml: key 'window.length_s' must be given" in err and "Traceback" not in err
    code, _, err = _run(capsys, "rig", "uci-hydraulic", "--data", tmp_path)
    assert code == 2 and "file must exist" in err


UCI = data_root() / "uci-hydraulic"


@pytest.mark.skipif(not (UCI / "profile.txt").is_file(), reason=f"the UCI hydraulic data is not at {UCI}")
def test_the_real_uci_data_is_counted(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, "rig", "uci-hydraulic", "--data", UCI, "--json")
    data = json.loads(out)["data"]
    assert code == 0 and data["windows"] == 2205 and data["counts"]["stable"] == {"0.0": 1449, "1.0": 756}
