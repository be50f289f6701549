"""Import of the wide per-cycle layout: synthetic files for joins, block means and every refusal;
the real UCI files when the shared data folder is there."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hydrowatch.errors import DataError
from hydrowatch.io.wide import block_means, healthy_mask, read_cycles, read_matrix, shared_cycles
from hydrowatch.rig import RigDescription, data_root, load_rig

RIG = """name = "tiny"
[window]
kind = "cycle"
length_s = 2.0
grid_hz = 1.0
[layout]
kind = "wide"
[channels.P]
unit = "bar"
role = "sensor"
rate_hz = 10.0
source = "P.txt"
[channels.T]
unit = "°C"
role = "condition"
rate_hz = 1.0
source = "T.txt"
scale = 2.0
offset = -1.0
[labels]
source = "labels.txt"
[labels.valve]
column = 0
values = [100, 80]
healthy = 100
[labels.pump]
column = 1
values = [0, 1]
healthy = 0
"""


def _write(folder: Path, name: str, rows: list[list[object]]) -> None:
    (folder / name).write_text("".join("\t".join(str(v) for v in row) + "\n" for row in rows), encoding="utf-8")


@pytest.fixture
def tiny(tmp_path: Path) -> tuple[Path, RigDescription]:
    (tmp_path / "rig.toml").write_text(RIG, encoding="utf-8")
    _write(tmp_path, "P.txt", [list(range(20)), [float(v) * 0.5 for v in range(20)], [7.0] * 20])
    _write(tmp_path, "T.txt", [[20, 21], [22, 23], [24, 25]])
    _write(tmp_path, "labels.txt", [[100, 0], [80, 0], [100, 1]])
    return tmp_path, load_rig(tmp_path / "rig.toml")


def test_files_are_joined_by_cycle_block_averaged_and_scaled(tiny: tuple[Path, RigDescription]) -> None:
    folder, rig = tiny
    cycles = read_cycles(folder, rig)
    assert cycles.values.shape == (3, 2, 2) and cycles.channels == ("P", "T") and len(cycles) == 3
    np.testing.assert_allclose(cycles.channel("P"), [[4.5, 14.5], [2.25, 7.25], [7.0, 7.0]])
    np.testing.assert_allclose(cycles.channel("T"), [[39.0, 41.0], [43.0, 45.0], [47.0, 49.0]])
    np.testing.assert_array_equal(cycles.labels["valve"], [100.0, 80.0, 100.0])
    np.testing.assert_array_equal(healthy_mask(cycles, rig), [True, False, False])
    with pytest.raises(KeyError, match="'Q'"):
        cycles.channel("Q")


def test_block_means_average_each_interval_and_refuse_a_fraction() -> None:
    np.testing.assert_allclose(block_means(np.arange(12.0).reshape(2, 6), 3.0, 1.0), [[1.0, 4.0], [7.0, 10.0]])
    np.testing.assert_allclose(block_means(np.ones((1, 4)), 2.0, 2.0), np.ones((1, 4)))
    with pytest.raises(DataError, match="whole number"):
        block_means(np.ones((1, 6)), 1.5, 1.0)
    with pytest.raises(DataError, match="multiple of 4"):
        block_means(np.ones((1, 6)), 4.0, 1.0)


@pytest.mark.parametrize(
    ("file", "rows", "match"),
    [
        ("P.txt", [list(range(20)), list(range(19)), [7.0] * 20], r"P.txt: row 1 must have 20 columns. Got 19"),
        (
            "P.txt",
            [list(range(20)), [*range(5), "x", *range(14)], [7.0] * 20],
            r"P.txt: row 1, column 5 must be a number. Got 'x'",
        ),
        ("T.txt", [[20, 21], [22, ""], [24, 25]], r"T.txt: row 1, column 1 must be a number. Got ''"),
        ("T.txt", [[20, 21], [22, 23], [24, "nan"]], r"T.txt: row 2, column 1 must be finite. Got 'nan'"),
        ("T.txt", [[20, 21], [22, 23]], r"T.txt: file must hold one row per cycle, as many as P.txt \(3\). Got 2 rows"),
        (
            "labels.txt",
            [[100, 0], [80, 0], [90, 1]],
            r"labels.txt: row 2, column 0 \(valve\) must be one of \[100.0, 80.0\]. Got 90",
        ),
        ("labels.txt", [[100, 0], [80, 0], [100, 1], [100, 1]], r"label file must hold one row per cycle.*Got 4 rows"),
        ("labels.txt", [[100], [80], [100]], r"labels.txt: row 0 must have at least 2 columns"),
        ("P.txt", [], r"P.txt: file must hold at least one row"),
    ],
)
def test_bad_files_are_refused_naming_file_row_and_column(
    tiny: tuple[Path, RigDescription], file: str, rows: list[list[object]], match: str
) -> None:
    folder, rig = tiny
    _write(folder, file, rows)
    with pytest.raises(DataError, match=match):
        read_cycles(folder, rig)


def test_a_missing_file_and_a_long_layout_are_refused(tiny: tuple[Path, RigDescription]) -> None:
    folder, rig = tiny
    (folder / "T.txt").unlink()
    with pytest.raises(DataError, match=r"T.txt: file must exist"):
        read_cycles(folder, rig)
    long_rig = load_rig_text(folder, RIG.replace('kind = "wide"', 'kind = "long"'))
    with pytest.raises(DataError, match="layout must be 'wide'"):
        read_cycles(folder, long_rig)


def load_rig_text(folder: Path, text: str) -> RigDescription:
    path = folder / "other.toml"
    path.write_text(text, encoding="utf-8")
    return load_rig(path)


def test_read_matrix_takes_the_first_row_as_width_and_ignores_trailing_blank_lines(tmp_path: Path) -> None:
    path = tmp_path / "m.txt"
    path.write_text("1,2,3\n4,5,6\n\n", encoding="utf-8")
    np.testing.assert_array_equal(read_matrix(path, delimiter=","), [[1, 2, 3], [4, 5, 6]])


UCI = data_root() / "uci-hydraulic"


def test_shared_cycles_are_none_when_the_data_folder_lacks_them(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("HYDROWATCH_DATA", str(tmp_path))
    assert shared_cycles("uci-hydraulic") is None


@pytest.mark.skipif(
    not (UCI / "profile.txt").is_file(),
    reason=f"the UCI hydraulic data is not at {UCI} (set HYDROWATCH_DATA to the shared data folder)",
)
def test_the_real_uci_files_import_as_2205_cycles_of_17_channels() -> None:
    loaded = shared_cycles("uci-hydraulic")
    assert loaded is not None
    rig, cycles = loaded
    assert cycles.values.shape == (2205, 17, 60) and np.isfinite(cycles.values).all()
    counts = {
        name: dict(zip(*np.unique(cycles.labels[name], return_counts=True), strict=True)) for name in rig.components
    }
    assert counts["cooler"] == {3.0: 732, 20.0: 732, 100.0: 741}  # documentation.txt's class distribution
    assert counts["valve"] == {73.0: 360, 80.0: 360, 90.0: 360, 100.0: 1125}
    assert counts["pump"] == {0.0: 1221, 1.0: 492, 2.0: 492}
    assert counts["accumulator"] == {90.0: 808, 100.0: 399, 115.0: 399, 130.0: 599}
    assert 130 < cycles.channel("PS1").mean() < 170 and 0 < cycles.channel("TS1").mean() < 80  # bar, °C
