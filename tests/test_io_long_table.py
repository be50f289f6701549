"""Import of the long layout through a rig description: renames, scaling, grid, windows, labels, refusals;
the plant's own description reads the plant's own export."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from hydrowatch.errors import DataError
from hydrowatch.io.long_table import read_windows
from hydrowatch.io.tabular import write_table
from hydrowatch.rig import RigDescription, load_rig
from hydrowatch.rig.plant import plant_rig

PRESS = """name = "press"
[window]
kind = "fixed"
length_s = 2.0
hop_s = 1.0
grid_hz = 50.0
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
source = "P_psi"
scale = 0.0689476
[channels.T]
unit = "°C"
role = "condition"
rate_hz = 100.0
optional = true
[labels.state]
values = ["ok", "worn"]
healthy = "ok"
"""


@pytest.fixture
def press(tmp_path: Path) -> RigDescription:
    (tmp_path / "press.toml").write_text(PRESS, encoding="utf-8")
    return load_rig(tmp_path / "press.toml")


def _table(n: int = 500, state_change: int = 300) -> dict[str, list[object]]:
    time = np.arange(n) / 100.0
    return {
        "time": list(time),
        "u": list(np.sin(time)),
        "P_psi [bar]": list(np.full(n, 1000.0)),  # a unit in the header is checked against the description
        "state": ["ok"] * state_change + ["worn"] * (n - state_change),
    }


def _csv(path: Path, columns: dict[str, list[object]]) -> Path:
    names = list(columns)
    rows = zip(*columns.values(), strict=True)
    path.write_text(",".join(names) + "\n" + "".join(",".join(map(str, r)) + "\n" for r in rows), encoding="utf-8")
    return path


def test_a_long_table_is_renamed_scaled_averaged_and_cut_into_labelled_windows(
    press: RigDescription, tmp_path: Path
) -> None:
    columns = _table()
    columns["P_psi"] = columns.pop("P_psi [bar]")
    windows = read_windows(_csv(tmp_path / "run.csv", columns), press)
    # 5 s at 100 Hz -> 250 grid samples at 50 Hz -> windows of 100 every 50: starts 0, 1, 2, 3 s
    assert windows.channels == ("u", "p") and windows.grid_hz == 50.0  # optional T absent
    assert windows.values.shape == (3, 2, 100) and windows.mixed == 1  # the window at 2-4 s holds ok and worn
    np.testing.assert_allclose(windows.start_s, [0.0, 1.0, 3.0])
    np.testing.assert_allclose(windows.channel("p"), 68.9476)
    expected = np.sin(np.arange(200) / 100.0).reshape(100, 2).mean(axis=1)
    np.testing.assert_allclose(windows.channel("u")[0], expected)
    np.testing.assert_array_equal(windows.labels["state"], ["ok", "ok", "worn"])
    parquet = tmp_path / "run.parquet"
    pq.write_table(pa.table(columns), parquet)
    np.testing.assert_allclose(read_windows(parquet, press).values, windows.values)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda c: c.pop("time"), r"column 'time' \[s\] must be present"),
        (lambda c: c.pop("P_psi [bar]"), r"column 'P_psi' \(channel 'p'\) must be present"),
        (lambda c: c.update({"P_psi [psi]": c.pop("P_psi [bar]")}), r"column 'P_psi' must be in bar .* Got \[psi\]"),
        (lambda c: c["u"].__setitem__(7, "x"), r"column 'u' must be numeric. Got 'x' in row 7"),
        (lambda c: c["u"].__setitem__(9, "nan"), r"row 9, column 'u' must be a finite number"),
        (lambda c: c["state"].__setitem__(4, "broken"), r"row 4, column 'state' must be one of \['ok', 'worn'\]"),
        (
            lambda c: c["time"].__setitem__(slice(100, None), [x + 0.5 for x in c["time"][100:]]),
            r"samples must be 10 ms apart \(100 Hz\). Got a step of 510.000 ms before row 100 \(time=1.500000 s",
        ),
        (lambda c: [v.__delitem__(slice(150, None)) for v in c.values()], r"at least one window of 2 s. Got 1.5 s"),
    ],
)
def test_a_bad_long_table_is_refused_naming_column_and_row(
    press: RigDescription, tmp_path: Path, change: object, match: str
) -> None:
    columns = _table()
    change(columns)  # type: ignore[operator]
    with pytest.raises(DataError, match=match) as caught:
        read_windows(_csv(tmp_path / "bad.csv", columns), press)
    assert str(caught.value).startswith(str(tmp_path / "bad.csv"))


def test_a_long_table_needs_a_long_rig_with_one_rate(press: RigDescription, tmp_path: Path) -> None:
    path = _csv(tmp_path / "run.csv", _table())
    with pytest.raises(DataError, match="layout must be 'long'"):
        read_windows(path, load_rig_text(tmp_path, PRESS.replace('kind = "long"', 'kind = "wide"')))
    with pytest.raises(DataError, match=r"share one rate_hz. Got \[50.0, 100.0\]"):
        read_windows(path, load_rig_text(tmp_path, PRESS.replace("rate_hz = 100.0\nsource", "rate_hz = 50.0\nsource")))
    with pytest.raises(DataError, match="suffix must be .csv or .parquet"):
        read_windows(tmp_path / "run.txt", press)


def load_rig_text(folder: Path, text: str) -> RigDescription:
    path = folder / "other.toml"
    path.write_text(text, encoding="utf-8")
    return load_rig(path)


def test_parquet_field_units_are_checked_and_aliases_accepted(press: RigDescription, tmp_path: Path) -> None:
    columns = _table()
    pressure = pa.array(columns.pop("P_psi [bar]"))
    table = pa.table(columns).append_column(pa.field("P_psi", pa.float64(), metadata={"unit": "psi"}), pressure)
    pq.write_table(table, tmp_path / "psi.parquet")
    with pytest.raises(DataError, match=r"psi.parquet: column 'P_psi' must be in bar .* Got \[psi\]"):
        read_windows(tmp_path / "psi.parquet", press)
    columns = _table()
    columns["T [degC]"] = [20.0] * len(columns["time"])  # an accepted spelling of °C
    assert read_windows(_csv(tmp_path / "alias.csv", columns), press).channels == ("u", "p", "T")


def test_the_plant_description_reads_the_plants_own_export(tmp_path: Path) -> None:
    n = 2600  # 13 s at 200 Hz: two 5 s windows
    t = np.arange(n) / 200.0
    channels = {"voltage": np.sin(t), "flow": np.full(n, 3.0), "speed": np.full(n, 90.0), "torque": np.full(n, 2.0)}
    path = tmp_path / "healthy.csv"
    write_table(path, t, channels, np.full(n, "pump_leak_alert", dtype=object), {})
    windows = read_windows(path, plant_rig())
    assert windows.channels == ("voltage", "flow", "speed", "torque") and windows.values.shape == (2, 4, 1000)
    np.testing.assert_array_equal(windows.labels["state"], ["pump_leak_alert"] * 2)
    np.testing.assert_allclose(windows.start_s, [0.0, 5.0])
    np.testing.assert_allclose(windows.channel("voltage")[1], np.sin(t[1000:2000]))
