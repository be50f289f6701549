"""Valve commands: filtered white noise (study Eq. 3.21), test signals, duty cycles, replayed files."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy.stats import norm

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.plant.excitation import (
    FilteredNoiseCommand,
    chirp,
    duty_cycle,
    filtered_noise,
    parse_volts,
    ramp,
    read_command,
    sine,
    steps,
)


def test_filtered_noise_is_the_studys_low_pass_on_the_range():
    u = filtered_noise(600.0, (0.0, 4.0), seed=1)
    assert u.shape == (120_000,)
    assert u.min() == 0.0 and u.max() == 4.0
    assert u.mean() == pytest.approx(2.0, abs=0.05)
    clipped = np.mean((u == 0.0) | (u == 4.0))
    assert clipped == pytest.approx(2 * norm.sf(2.5), abs=0.004)  # ±2.5 σ span the range
    wide = filtered_noise(600.0, (1.0, 3.0), seed=2, sigmas=20.0)  # no clipping: the pure AR(1)
    x = wide - wide.mean()
    assert np.dot(x[1:], x[:-1]) / np.dot(x, x) == pytest.approx(0.9, abs=0.01)
    assert wide.std() == pytest.approx(1.0 / 20.0, rel=0.05)  # half-range / sigmas


def test_filtered_noise_is_seeded():
    a, b = filtered_noise(5.0, seed=7), filtered_noise(5.0, seed=7)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, filtered_noise(5.0, seed=8))
    assert filtered_noise(5.0, seed=np.random.default_rng(7)).shape == (1000,)
    with pytest.raises(ParameterError, match="pole"):
        filtered_noise(5.0, pole=1.0)


def test_filtered_noise_command_streams_the_same_low_pass_without_seams():
    one, two = FilteredNoiseCommand(1, seed=4), FilteredNoiseCommand(1, seed=4)
    np.testing.assert_array_equal(np.hstack([one.next(300), one.next(500)]), two.next(800))  # chunking: no seam
    fleet = FilteredNoiseCommand(3, (1.0, 3.0), seed=5)
    u = np.hstack([fleet.next(1000) for _ in range(40)])
    assert u.shape == (3, 40_000) and u.min() >= 1.0 and u.max() <= 3.0
    x = u[0] - u[0].mean()
    assert np.dot(x[1:], x[:-1]) / np.dot(x, x) == pytest.approx(0.9, abs=0.02)  # the study's pole
    assert not np.array_equal(u[0], u[1])  # every machine its own command
    with pytest.raises(ParameterError):
        FilteredNoiseCommand(2, (3.0, 1.0))


def test_steps_ramps_sines():
    s = steps(3.0, [1.0, 2.0, 3.0])
    assert s.shape == (600,) and list(s[[0, 199, 200, 399, 400, 599]]) == [1, 1, 2, 2, 3, 3]
    r = ramp(2.0, 0.0, 4.0)
    assert r[0] == 0.0 and r[-1] == 4.0 and np.allclose(np.diff(r), 4.0 / 399)
    w = sine(1.0, 5.0, offset=2.0, amplitude=0.5)
    assert w.max() == pytest.approx(2.5, abs=1e-3) and w.mean() == pytest.approx(2.0, abs=1e-9)
    with pytest.raises(ParameterError, match="Nyquist"):
        sine(1.0, 150.0)
    with pytest.raises(ParameterError, match="step levels"):
        steps(1.0, [])


def test_chirp_sweeps_its_frequency_band():
    c = chirp(10.0, 1.0, 3.0, offset=2.0, amplitude=1.0, method="linear")
    crossings = np.flatnonzero(np.diff(np.sign(c - 2.0)) != 0)
    assert len(crossings) == pytest.approx(40, abs=2)  # mean 2 Hz over 10 s, two crossings per cycle
    mid_t = (crossings[1:] + crossings[:-1]) / 2 / 200.0
    measured = 200.0 / (2.0 * np.diff(crossings))  # half a period between crossings
    np.testing.assert_allclose(measured, 1.0 + 0.2 * mid_t, rtol=0.1)  # linear sweep 1 → 3 Hz


def test_duty_cycle_holds_ramps_and_steps_inside_the_range():
    u = duty_cycle(600.0, (0.5, 3.5), seed=4)
    assert u.shape == (120_000,)
    assert u.min() >= 0.5 and u.max() <= 3.5
    d = np.diff(u)
    assert np.mean(d == 0.0) > 0.3  # holds
    assert np.sum(np.abs(d) > 0.05) >= 3  # steps
    assert np.mean((d != 0.0) & (np.abs(d) < 0.01)) > 0.1  # ramps
    np.testing.assert_array_equal(u, duty_cycle(600.0, (0.5, 3.5), seed=4))


def test_parse_volts():
    assert parse_volts("0:4") == (0.0, 4.0)
    assert parse_volts("-1.5:2") == (-1.5, 2.0)
    for bad in ("4:0", "0-4", "a:b", "1:2:3"):
        with pytest.raises(ParameterError, match="voltage range"):
            parse_volts(bad)


def test_read_command_from_csv_and_parquet(tmp_path):
    u = np.round(filtered_noise(2.0, seed=3), 6)
    t = np.arange(u.size) / 200.0
    csv = tmp_path / "cmd.csv"
    csv.write_text("t,voltage\n" + "\n".join(f"{a:.3f},{b}" for a, b in zip(t, u)) + "\n")
    np.testing.assert_allclose(read_command(csv), u)
    parquet = tmp_path / "cmd.parquet"
    pq.write_table(pa.table({"voltage": u}), parquet)
    np.testing.assert_array_equal(read_command(parquet), u)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("nocol.csv", "t,speed\n0,1\n0.005,2\n", r"nocol.csv: .*'voltage'"),
        ("nan.csv", "voltage\n1.0\n\n2.0\nnan\n", "finite. Got NaN/inf at row"),
        ("gap.csv", "t,voltage\n0,1\n0.005,1\n0.02,1\n", "Resample"),
        ("text.csv", "voltage\nhigh\nlow\n", "must be numeric"),
        ("cmd.txt", "voltage\n1\n", "suffix"),
        ("bad.parquet", "not parquet at all", "bad.parquet: command file must be a readable table"),
        ("none.csv", None, "none.csv: command file must exist"),
    ],
)
def test_read_command_refuses_bad_files(tmp_path, name, content, message):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    with pytest.raises(DataError, match=message):
        read_command(path)
