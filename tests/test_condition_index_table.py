"""pump_leak's history re-read on the machine's latest pump capacity (issue 15, hydrowatch.condition.index_table):
exact against the index read directly on that capacity, and on a real history whose forecast it mends."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hydrowatch.condition.brake import rounded, with_brake
from hydrowatch.condition.capacity import corrected, with_capacity
from hydrowatch.condition.degradation_series import Degradation
from hydrowatch.condition.forecast import part_forecast
from hydrowatch.condition.forecast_stream import ForecastStream
from hydrowatch.condition.index_table import LeakReading, degradation_index, reread_leak, unit_indices
from hydrowatch.plant.faults import FAULTS, level_severity
from hydrowatch.plant.parameters import PlantParameters

CASE = Path(__file__).parent / "data" / "leak_capacity_reread.json"


def test_a_leak_history_is_reread_exactly_on_the_capacity_of_its_latest_reading():
    theta0 = PlantParameters()
    n = 8
    s = np.linspace(0.2, 1.2, n) * level_severity("pump_leak", "warning", theta0)
    ratio = np.array([1.1, 0.0, 1.3, 1.2, 0.0, 1.15, 1.25, 1.05])  # 0: the pump never met its limit there
    brake = rounded(np.array([1.0, 1.0, 1.05, 1.05, 1.0, 0.97, 1.0, 1.05]))
    q = np.array([-0.05, -0.05, -0.01, np.nan, 0.08, 0.08, 0.08, 0.09])
    read = np.full(n, np.nan)  # as the windows were read then: each on its own q̂
    for i in np.flatnonzero(np.isfinite(q)):
        read[i] = unit_indices("pump_leak", corrected(s[i:i + 1][None], ratio[i:i + 1], q[i]), theta0,
                               brake[i:i + 1], q[i:i + 1])[0, 0]
    read[3] = 0.4  # a value without a reading: kept
    read[7] = np.nan  # the latest reading has no value: the capacity of the latest window with one (0.08) counts
    out = reread_leak(read, s, ratio, brake, q, theta0)
    for i in (0, 1, 2):  # read on another capacity: the index on 0.08, computed directly
        on = with_brake(with_capacity(theta0, 0.08), float(brake[i]))
        assert out[i] == pytest.approx(float(degradation_index("pump_leak", (s[i] + 0.08 * ratio[i]) / 1.08, on)),
                                       rel=1e-12)
        # it moved where the window met the pump's limit; elsewhere the capacity only rescales the severity and the
        # table alike
        assert abs(out[i] - read[i]) > 1e-3 if ratio[i] > 0.0 else abs(out[i] - read[i]) < 1e-3
    assert out[3] == 0.4 and np.array_equal(out[4:7], read[4:7]) and np.isnan(out[7])
    # the same through a LeakReading, and up to an earlier window (its latest capacity then: -0.01)
    leak = LeakReading(theta0, s, ratio, brake, q)
    assert np.array_equal(leak.reread(read), out, equal_nan=True)
    early = leak.reread(read[:3])
    assert early[2] == read[2] and early[0] != read[0]


def _case() -> tuple[dict, np.ndarray, Degradation]:
    case = json.loads(CASE.read_text())
    t = np.append(case["t_s"], case["now_s"])  # the machine's now: its window whose true index passes 0.5
    value = np.append(case["index"], np.nan)
    reading = [np.append(case[k], np.nan) for k in ("severity", "limit_ratio", "brake", "capacity")]
    leak = LeakReading(PlantParameters.from_dict(case["nominal"]), *reading)
    d = Degradation({"pump_leak": value}, {"pump_leak": value}, {"pump_leak": value},
                    {"pump_leak": np.isfinite(value)}, leak=leak)
    return case, t, d


def test_a_leak_forecast_reads_its_history_on_the_latest_capacity_offline_and_online():
    # regular unit 2106/3 (stop 62-63): commissioning left its pump's capacity undetermined (+0.080 of θ0's); the
    # first pools read -0.05 to -0.01, later ones 0.08-0.09; its history as read then forecast the alert 28.2 % late
    case, t, d = _case()
    remaining = case["remaining_s"]
    assert sorted(set(case["capacity"])) == [-0.05, -0.01, 0.08, 0.09] and case["capacity"][-1] == 0.08
    as_read = part_forecast(t, Degradation(d.value, d.low, d.high, d.measured), "pump_leak")
    assert as_read.alert_in_s > 1.2 * remaining
    reread = part_forecast(t, d, "pump_leak")
    assert reread.alert_in_s == pytest.approx(remaining, rel=0.05)
    assert reread.ci95[0] <= remaining <= reread.ci95[1]
    history = d.history("pump_leak")
    early = np.array(case["capacity"]) < 0.0
    assert np.all(history[:-1][early] > np.array(case["index"])[early])  # read low on too small a capacity
    # online: the scorer's history of the same windows (each window's reading travels with its index)
    stream = ForecastStream()
    for i in range(t.size):
        stream.update(float(t[i]), d.window(i, measured=True))
    online = stream.get()["pump_leak"]
    assert online.alert_in_s == pytest.approx(reread.alert_in_s, rel=1e-6)
    assert online.ci95 == pytest.approx(reread.ci95, rel=1e-6)
    assert stream.nbytes > ForecastStream().nbytes  # the readings' ring


def test_windows_read_on_another_commissioning_are_not_reread():
    # the machine's model changed (a new θ0): the windows read on the old one keep their values
    case, t, d = _case()
    history = d.history("pump_leak")
    stream = ForecastStream()
    other = {**case["nominal"], "Kr": case["nominal"]["Kr"] * 1.1}
    for i in range(t.size):
        window = d.window(i, measured=True)
        if i < 40 and "pump_leak" in window:  # the first 40 windows read on another θ0
            window["pump_leak"]["reading"] = {**window["pump_leak"]["reading"],
                                              "nominal": PlantParameters.from_dict(other)}
        stream.update(float(t[i]), window)
    online = stream.history()[1][:, FAULTS.index("pump_leak")]
    assert np.allclose(online[:40], np.array(case["index"])[:40], atol=1e-6)  # as read
    assert np.allclose(online[40:], history[40:], atol=1e-6, equal_nan=True)
