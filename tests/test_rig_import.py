"""``hydrowatch import --rig``: a rig's data (wide folder or long table) into ``rig_cycles`` MCAP recordings, read
back unchanged; ``train --rig`` and ``score`` on the long layout and on imported files; bad cycles refused."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from test_rig_cycles_method import RIG, write_rig_folder

from hydrowatch.cli import main
from hydrowatch.errors import DataError
from hydrowatch.io.rig_cycles import cycles_from_batches, read_rig_data, read_rig_recording, rig_cycles_batch
from hydrowatch.io.wide import read_cycles
from hydrowatch.rig import load_rig
from hydrowatch.schemas import RIG_CYCLES, wire_schema

PRESS = """name = "press2"
[window]
kind = "fixed"
length_s = 4.0
hop_s = 4.0
grid_hz = 10.0
[layout]
kind = "long"
time_column = "time"
[channels.u]
unit = "V"
role = "command"
rate_hz = 100.0
[channels.p]
unit = "bar"
role = "sensor"
rate_hz = 100.0
source = "P_raw"
scale = 0.5
[channels.q]
unit = "L/min"
role = "sensor"
rate_hz = 100.0
[labels.valve]
values = ["ok", "worn"]
healthy = "ok"
[labels.pump]
values = [0, 1]
healthy = 0
"""


def press_table(path: Path, windows: int, seed: int) -> Path:
    """A long CSV at 100 Hz of ``windows`` 4 s windows: u steps 0 → 5 V at 1 s and back at 3 s; p (stored as 2 ×
    bar) follows at 20 bar per volt, 30 % less when the valve is worn; q drops 2 L/min with a pump leak; the valve
    label changes every 3 windows, the pump's every 2 (each constant inside a window); noise 0.3 bar, 0.3 L/min."""
    rng = np.random.default_rng(seed)
    n = windows * 400
    time = np.arange(n) / 100.0
    phase = time % 4.0
    u = np.where((phase >= 1.0) & (phase < 3.0), 5.0, 0.0)
    window = (np.arange(n) // 400).astype(int)
    worn = (window // 3) % 2 == 1
    pump = (window // 2) % 2
    p = u * 4.0 * np.where(worn, 0.7, 1.0) + 10.0 + rng.normal(0, 0.3, n)
    q = 20.0 - 2.0 * pump + 0.2 * u + rng.normal(0, 0.3, n)
    rows = ["time,u,P_raw [bar],q,valve,pump"]
    rows += [f"{a:.2f},{b:.3f},{2 * c:.4f},{d:.4f},{'worn' if w else 'ok'},{k}"
             for a, b, c, d, w, k in zip(time, u, p, q, worn, pump)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def rigs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("rigs")
    (root / "tiny.toml").write_text(RIG, encoding="utf-8")
    (root / "press2.toml").write_text(PRESS, encoding="utf-8")
    write_rig_folder(root / "wide", np.tile([100.0, 80.0, 60.0], 12), np.tile([0.0, 1.0], 18), seed=3)
    press_table(root / "press.csv", 60, seed=0)
    press_table(root / "press_new.csv", 12, seed=1)
    (root / "mlruns").mkdir()
    return root


def test_a_wide_folder_imports_to_mcap_and_reads_back_unchanged(rigs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = rigs / "wide.mcap"
    assert main(["import", str(rigs / "wide"), "--rig", str(rigs / "tiny.toml"), "--out", str(out),
                 "--fleet", "lab", "--machine", "rig1"]) == 0
    assert "36 cycles of rig tiny-cycles, 3 channels on a 1 Hz grid" in capsys.readouterr().out
    text, back = read_rig_recording(out)
    assert text == RIG
    direct = read_cycles(rigs / "wide", load_rig(rigs / "tiny.toml"))
    np.testing.assert_array_equal(back.values, direct.values)
    assert back.channels == ("P", "Q", "T")
    np.testing.assert_array_equal(back.labels["valve"], direct.labels["valve"])
    np.testing.assert_array_equal(back.labels["pump"], direct.labels["pump"])
    np.testing.assert_allclose(back.start_s[:3], [0.0, 20.0, 40.0])
    # the rig command reads the imported file like the folder
    assert main(["rig", str(rigs / "tiny.toml"), "--data", str(out), "--json"]) == 0
    counted = json.loads(capsys.readouterr().out)["data"]
    assert counted["windows"] == 36 and counted["counts"]["valve"] == {"100.0": 12, "80.0": 12, "60.0": 12}


def test_a_long_table_trains_scores_and_imports_through_its_description(
    rigs: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    uri = f"sqlite:///{rigs / 'mlruns' / 'mlflow.db'}"
    model = rigs / "press-model"
    assert main(["train", "--rig", str(rigs / "press2.toml"), "--data", str(rigs / "press.csv"), "--out", str(model),
                 "--tracking-uri", uri, "--experiment", "press", "--no-register", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["rig"] == "press2" and set(summary["components"]) == {"valve", "pump"}
    assert summary["states"] == ["valve=ok", "valve=worn", "pump=0", "pump=1"]
    for figures in summary["components"].values():  # 18 test windows per component, separated by 6 noise widths
        assert figures["accuracy"] >= 0.9
    imported = rigs / "press_new.mcap"
    assert main(["import", str(rigs / "press_new.csv"), "--rig", str(rigs / "press2.toml"), "--out",
                 str(imported)]) == 0
    capsys.readouterr()
    for data in (rigs / "press_new.csv", imported):
        assert main(["score", "--model", str(model), "--data", str(data), "--json"]) == 0
        scored = json.loads(capsys.readouterr().out)
        assert scored["summary"]["cycles"] == 12
        assert [c["start_s"] for c in scored["cycles"][:3]] == [0.0, 4.0, 8.0]
        assert scored["summary"]["accuracy"]["valve"] >= 11 / 12 and scored["summary"]["accuracy"]["pump"] >= 11 / 12


def test_cycles_of_another_rig_or_shape_or_label_are_refused(rigs: Path) -> None:
    tiny, press = load_rig(rigs / "tiny.toml"), load_rig(rigs / "press2.toml")
    cycles = read_rig_data(rigs / "wide", tiny)
    starts = np.arange(len(cycles)) * 20.0
    good = rig_cycles_batch(cycles, range(4), tiny.name, starts)
    with pytest.raises(DataError, match="message 0, row 0: cycles must be of rig 'press2'"):
        cycles_from_batches([good], press, "bus")
    rows = good.to_pydict()
    rows["values"][2] = rows["values"][2][:-1]
    with pytest.raises(DataError, match=r"message 1, row 2: a cycle must hold channels \['P', 'Q', 'T'\] × 20 "
                                        r"samples. Got \['P', 'Q', 'T'\] and 59 values"):
        cycles_from_batches([good, pa.RecordBatch.from_pydict(rows, schema=wire_schema(RIG_CYCLES))], tiny, "bus")
    rows = good.to_pydict()
    rows["labels"][1] = [{"name": "valve", "value": "70"}, {"name": "pump", "value": "0"}]
    with pytest.raises(DataError, match=r"row 1: label 'valve' must be one of \['100', '80', '60'\]. Got '70'"):
        cycles_from_batches([pa.RecordBatch.from_pydict(rows, schema=wire_schema(RIG_CYCLES))], tiny, "bus")
    with pytest.raises(DataError, match="cycles must be of rig 'press2'. Got rig 'tiny-cycles'"):
        read_rig_data(_imported(rigs), press)


def _imported(rigs: Path) -> Path:
    out = rigs / "wide2.mcap"
    assert main(["import", str(rigs / "wide"), "--rig", str(rigs / "tiny.toml"), "--out", str(out)]) == 0
    return out


def test_import_rig_refuses_a_label_option_and_an_mcap_input(rigs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["import", str(rigs / "wide"), "--rig", str(rigs / "tiny.toml"), "--out", str(rigs / "x.mcap"),
                 "--label", "healthy"]) == 2
    assert "--rig takes the labels from the rig description" in capsys.readouterr().err
    assert main(["import", str(_imported(rigs)), "--rig", str(rigs / "tiny.toml"), "--out",
                 str(rigs / "y.mcap")]) != 0
    assert "it is imported already" in capsys.readouterr().err
    # a sample reader (export, train without --rig) names what the file holds instead
    assert main(["export", str(rigs / "wide2.mcap"), "--out", str(rigs / "x.parquet")]) == 2
    assert "it holds whole cycles of rig 'tiny-cycles', written by `import --rig`" in capsys.readouterr().err
