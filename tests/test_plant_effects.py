"""Each catalog effect changes the outputs in the regime plant-model.md names (noise off)."""

import numpy as np
import pytest

from hydrowatch.errors import ParameterError
from hydrowatch.plant import CHANNELS, EFFECT_IDS, EFFECTS, PlantParameters, parse_effects, resolve_effects, simulate
from hydrowatch.plant.effects import EFFECT_OFFSET, EFFECT_WIDTH, effect_row
from hydrowatch.plant.simulator import linear_modes

FS = 200.0


def run(u, effects=None, parameters=None, settle=True):
    return simulate(np.asarray(u, dtype=float), parameters, effects, noise=False, settle=settle)


def steady(u: float, effects=None) -> dict[str, float]:
    rec = run(np.full(60, u), effects)
    return {k: rec[k][-1] for k in CHANNELS}


def test_catalog_parsing_and_validation():
    assert set(EFFECTS) == set(EFFECT_IDS) and len(EFFECT_IDS) == 12
    parsed = parse_effects("stribeck_friction:Ts=0.4; sensor_lowpass:sensor=speed,tau=0.05;transport_delay")
    assert parsed["stribeck_friction"] == {"Tc": 0.1, "Ts": 0.4, "omega_st": 5.0, "omega_eps": 2.0}
    assert parsed["sensor_lowpass"] == {"sensor": 1.0, "tau": 0.05} and parsed["transport_delay"] == {"tau": 0.01}
    assert parse_effects("") == {} == resolve_effects(None)
    for text, message in [
        ("windage", "effect id must be one of"),
        ("quadratic_drag:Kq=1", "unknown \\['Kq'\\]"),
        ("transport_delay:tau=0.2", "must be in \\[0, 0.05\\] s"),
        ("transport_delay:tau=fast", "must be a number"),
        ("valve_deadband:0.1", "must look like"),
        ("stribeck_friction:Tc=0.5,Ts=0.2", "must be >= Tc"),
        ("sensor_lowpass:sensor=1.5", "must be 0, 1 or 2"),
    ]:
        with pytest.raises(ParameterError, match=message):
            parse_effects(text)
    row = effect_row({"valve_saturation": {"x_max": 0.5}})
    assert row.shape == (EFFECT_WIDTH,) and row.sum() == 1.5 and row[EFFECT_OFFSET["valve_saturation"] + 1] == 0.5
    for spec in EFFECTS.values():  # every default sits inside its documented range
        for default, unit, description, lower, upper in spec.parameters.values():
            assert lower <= default <= upper and unit and description


def test_all_effects_combine_and_stay_finite():
    u = np.clip(np.cumsum(np.random.default_rng(0).normal(0, 0.2, 1000)), -5, 5)
    everything = {effect_id: {} for effect_id in EFFECT_IDS}
    rec = run(u, everything)
    nominal = run(u)
    for k in CHANNELS:
        assert np.all(np.isfinite(rec[k])) and not np.allclose(rec[k], nominal[k])


def test_stribeck_friction_matters_at_low_speed():
    low, high = steady(0.2), steady(3.0)
    low_f, high_f = steady(0.2, {"stribeck_friction": {}}), steady(3.0, {"stribeck_friction": {}})
    low_change = 1 - low_f["speed"] / low["speed"]
    assert low_change > 0.02 and low_change > 3 * (1 - high_f["speed"] / high["speed"])
    start = np.r_[np.zeros(20), np.full(80, 1.0)]  # a start from rest: breakaway delays it
    error = run(start, {"stribeck_friction": {"Ts": 0.6}})["speed"] - run(start)["speed"]
    assert error.min() < -0.1 and abs(error[-1]) < 0.5 * abs(error.min())


def test_quadratic_drag_grows_with_speed_squared():
    drag = {"quadratic_drag": {}}
    added = {u: steady(u, drag)["torque"] - steady(u)["torque"] for u in (1.0, 3.0)}
    speed = {u: steady(u, drag)["speed"] for u in (1.0, 3.0)}
    assert added[3.0] > 0.5  # N·m
    assert added[3.0] / added[1.0] == pytest.approx((speed[3.0] / speed[1.0]) ** 2, rel=0.1)


def test_valve_deadband_matters_near_zero_command():
    band = {"valve_deadband": {}}
    assert steady(0.2)["flow"] > 0.3 and abs(steady(0.2, band)["flow"]) < 1e-9  # inside the overlap: no flow
    assert 1 - steady(1.0, band)["flow"] / steady(1.0)["flow"] > 0.15
    assert 1 - steady(3.0, band)["flow"] / steady(3.0)["flow"] < 0.05


def test_valve_saturation_flattens_only_high_commands():
    u = 0.2 + 1.7 * np.abs(np.sin(np.linspace(0, 6, 600)))  # 0.2–1.9 V
    sat = {"valve_saturation": {}}
    for k in CHANNELS:
        assert np.array_equal(run(u, sat)[k], run(u)[k])
    assert 1 - steady(4.0, sat)["flow"] / steady(4.0)["flow"] > 0.1
    assert steady(5.0, sat)["flow"] == pytest.approx(steady(4.0, sat)["flow"], rel=1e-3)  # flat top


def test_valve_hysteresis_error_follows_the_direction_of_change():
    t = np.arange(4000) / FS
    u = 1 + 2 * np.interp(t, [0, 10, 20], [0, 1, 0])  # slow triangle 1 → 3 → 1 V
    error = run(u, {"valve_hysteresis": {}})["speed"] - run(u)["speed"]
    rising, falling = error[500:1900], error[2500:3900]
    assert rising.max() < -0.3 and falling.min() > 0.3  # 0.1 V play ≈ 0.44 rad/s, sign by direction


def test_transport_delay_is_a_pure_dead_time_on_all_sensors():
    u = 2 + 1.5 * np.sin(2 * np.pi * 1.3 * np.arange(800) / FS)
    nominal = run(u)
    delayed = run(u, {"transport_delay": {"tau": 0.02}})  # exactly 4 samples
    for k in CHANNELS:
        assert np.allclose(delayed[k][100:], nominal[k][96:-4], rtol=1e-9, atol=1e-9), k

    def phase_lag(f: float) -> float:
        v = 2 + np.sin(2 * np.pi * f * np.arange(2000) / FS)
        ref, lag = run(v)["speed"][400:], run(v, {"transport_delay": {"tau": 0.0125}})["speed"][400:]
        basis = np.exp(-2j * np.pi * f * np.arange(400, 2000) / FS)
        return float(np.angle(np.sum(ref * basis) / np.sum(lag * basis)))

    assert phase_lag(2.0) == pytest.approx(2 * np.pi * 2.0 * 0.0125, rel=0.02)
    assert phase_lag(6.0) == pytest.approx(2 * np.pi * 6.0 * 0.0125, rel=0.02)  # linear in frequency


def test_entrained_air_softens_the_resonance_more_at_low_pressure():
    air = {"entrained_air": {}}
    ratio = {}
    for pc in (70e5, 30e5):
        p = PlantParameters(Pc=pc, TL=4.0)
        ratio[pc] = linear_modes(1.0, p, air)[0][0] / linear_modes(1.0, p)[0][0]
    assert ratio[70e5] < 0.99 and ratio[30e5] < ratio[70e5] - 0.03


def test_pump_ripple_adds_lines_at_the_shaft_frequency():
    n = 4000
    u = np.full(n, 3.8)  # pump-limited: the relief valve is closed, the ripple reaches the motor
    window = np.hanning(n)
    freq = np.fft.rfftfreq(n, 1 / FS)
    shaft_hz = PlantParameters().omega_p / (2 * np.pi)

    def line(flow: np.ndarray, f: float) -> float:
        spectrum = np.abs(np.fft.rfft((flow - flow.mean()) * window))
        return float(spectrum[np.abs(freq - f) < 0.3].max() / np.median(spectrum))

    rippled = run(u, {"pump_ripple": {}})["flow"][:]
    assert np.ptp(run(u)["flow"]) < 1e-9 and np.ptp(rippled) > 0.02
    assert line(rippled, shaft_hz) > 100 and line(rippled, 2 * shaft_hz) > 20


def test_thermal_drift_warms_the_oil_and_drifts_the_error_slowly():
    u = np.full(int(600 * FS), 2.0)
    warm = run(u, {"thermal_drift": {}})
    nominal = run(u[:10])
    assert warm["temperature"][0] == 40.0
    assert warm["temperature"][-1] == pytest.approx(40 + 20 * (1 - np.exp(-1)), rel=1e-3)
    drift = warm["speed"] - nominal["speed"][-1]
    assert abs(drift[0]) < 1e-6 and drift[-1] < -0.1 and np.all(np.diff(drift[::200]) < 0)
    assert np.all(run(u[:10])["temperature"] == 40.0)


def test_gear_backlash_shows_at_reversals():
    t = np.arange(2000) / FS
    u = 2 * np.sin(2 * np.pi * 0.5 * t)
    nominal = run(u)
    error = np.abs(run(u, {"gear_backlash": {}})["torque"] - nominal["torque"])
    moving = np.abs(nominal["speed"])
    assert error[moving < 1].max() > 2.0 and error[moving > 5].max() < 0.1 * error[moving < 1].max()


def test_shaft_compliance_adds_a_lightly_damped_resonance():
    f0, z0 = linear_modes(2.0)
    f1, z1 = linear_modes(2.0, effects={"shaft_compliance": {}})
    assert len(f1) == len(f0) + 1 and z1.min() < 0.2
    assert np.all(np.isin(np.round(f0[1:], 6), np.round(f1, 6)))  # the spool mode is untouched


def test_sensor_lowpass_changes_its_sensor_only():
    u = 2 + np.sin(2 * np.pi * 5 * np.arange(800) / FS)
    nominal = run(u)
    filtered = run(u, {"sensor_lowpass": {"sensor": 2, "tau": 0.02}})
    for k in ("flow", "speed", "supply_pressure", "load_pressure"):
        assert np.array_equal(filtered[k], nominal[k])
    # first-order gain at 5 Hz: 1/sqrt(1 + (2π·5·0.02)²) = 0.85
    assert np.ptp(filtered["torque"][400:]) / np.ptp(nominal["torque"][400:]) == pytest.approx(0.85, abs=0.03)
