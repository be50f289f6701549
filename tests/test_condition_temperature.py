"""Warm oil: leakage referred to 40 °C with the temperature channel, and what a machine without one sees."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.condition import ConditionModel
from hydrowatch.plant import PlantSimulator
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.faults import level_severity, state_parameters

CHANNELS = ("voltage", "flow", "speed", "torque", "temperature")
STATES = ("healthy", "pump_leak_warning", "pump_leak_alert", "motor_leak_warning", "motor_leak_alert")


def _windows(command: np.ndarray, seed: int, oil_c: float = 40.0) -> dict[str, np.ndarray]:
    effects = {"thermal_drift": {"T_start": oil_c, "T_end": oil_c}} if oil_c != 40.0 else None
    sim = PlantSimulator([state_parameters(s) for s in STATES], effects, seed=seed)
    sim.settle(float(command[0]))
    out = sim.step(np.broadcast_to(command, (len(STATES), command.size)))
    n = command.size // 1000 * 1000
    return {s: np.stack([out[c][i, :n].reshape(-1, 1000) for c in CHANNELS], axis=-1) for i, s in enumerate(STATES)}


@pytest.fixture(scope="module")
def model_and_warm():
    train = _windows(filtered_noise(40, (0, 4), seed=1), seed=2)
    warm = _windows(filtered_noise(30, (0, 4), seed=3), seed=4, oil_c=50.0)
    return ConditionModel().fit(train), warm


def test_leakage_is_referred_to_40_C_with_the_temperature_channel(model_and_warm):
    model, warm = model_and_warm
    for state in ("motor_leak_warning", "pump_leak_warning"):
        fault = state.rsplit("_", 1)[0]
        s = model.features_.severities(warm[state])[fault]
        assert np.allclose(s, level_severity(fault, "warning"), rtol=0.03), state
        s_blind = model.features_.severities(warm[state][:, :, :4])[fault]  # ×1.49 leak at 50 °C, more severe
        assert np.all(s_blind > 1.3 * level_severity(fault, "warning")), state


def test_warm_machines_read_their_own_state(model_and_warm):
    model, warm = model_and_warm
    for state, w in warm.items():
        assert np.all(model.predict(w) == state), state
    # Without the channel a warm healthy machine still reads healthy (its base leaks are small), but a
    # warning leak has really grown to alert size: the verdict describes the machine as it runs now.
    blind = model.predict(warm["motor_leak_warning"][:, :, :4])
    assert np.all(blind != "motor_leak_warning")
    assert np.all(model.predict(warm["healthy"][:, :, :4]) == "healthy")


def test_a_missing_temperature_reading_makes_the_window_invalid(model_and_warm):
    model, warm = model_and_warm
    w = warm["healthy"][:2].copy()
    w[0, 5:9, 4] = np.nan
    assert [v.state for v in model.judge(w)] == ["invalid", "healthy"]
    w[0, :, 4] = np.inf  # a broken reading, not an unknown temperature (all NaN): invalid
    assert [v.state for v in model.judge(w)] == ["invalid", "healthy"]


def test_without_the_channel_the_boxes_allow_for_the_oil_range(model_and_warm):
    """Oil 5 K warm and no temperature channel: leaks are read within ±22 % (exp(±0.04·5)), not outside every box."""
    model = model_and_warm[0]
    warm = _windows(filtered_noise(30, (0, 4), seed=5), seed=6, oil_c=45.0)
    blind = {s: w[:, :, :4] for s, w in warm.items()}
    unknown_oil = {s: w.copy() for s, w in warm.items()}
    for w in unknown_oil.values():
        w[:, :, 4] = np.nan  # a temperature channel all NaN: the same as none
    for state in ("healthy", "motor_leak_warning", "motor_leak_alert", "pump_leak_alert"):
        assert np.all(model.predict(blind[state], smoothing=12) == state), state
        np.testing.assert_array_equal(model.predict(unknown_oil[state], smoothing=12), model.predict(blind[state],
                                                                                                   smoothing=12))
    assert model.judge(unknown_oil["healthy"][:1])[0].state == "healthy"  # all NaN is not a gap
    model.features_.oil_range = 0.0  # the boxes of 40 °C oil: a warm alert's leakage lies past its band
    try:
        assert np.mean(model.predict(blind["motor_leak_alert"], smoothing=12) == "motor_leak_alert") <= 0.5
    finally:
        model.features_.oil_range = 5.0


def test_the_oil_box_widens_the_total_leakage_of_the_path():
    from hydrowatch.condition.oil import leakage_range, oil_box
    from hydrowatch.plant import PlantParameters

    p = PlantParameters()
    c_ref = p.Dp * p.omega_p / p.Pc
    f_lo, f_hi = leakage_range(0.04, 5.0)
    assert (f_lo, f_hi) == pytest.approx((np.exp(-0.2), np.exp(0.2)))
    box = oil_box({"motor_leak": (0.3, 0.4), "load": (-0.1, 0.1)}, p, (f_lo, f_hi))
    c0 = p.Ctm / c_ref  # a motor leak of severity s at leakage factor f reads (c0 + s)·f − c0 at f = 1
    assert box["motor_leak"] == pytest.approx(((c0 + 0.3) * f_lo - c0, (c0 + 0.4) * f_hi - c0))
    assert box["load"] == (-0.1, 0.1)  # not a leakage


def test_the_motor_leakage_tells_the_oil_that_separates_a_pump_leak_warning_from_its_alert(model_and_warm):
    """Without the channel, a warning on oil 5 K warm and an alert on oil 5 K cold leak alike (×1.22 and ×0.82) on
    the supply; the healthy motor's own leakage, wetted by the same oil, tells the two apart (oil.motor_factors)."""
    import hydrowatch.condition.oil as oil
    from hydrowatch.condition.estimates import severity_standard_error

    model = model_and_warm[0]
    warm = _windows(filtered_noise(30, (0, 4), seed=7), seed=8, oil_c=45.0)["pump_leak_warning"][:, :, :4]
    cold = _windows(filtered_noise(30, (0, 4), seed=9), seed=10, oil_c=35.0)["pump_leak_alert"][:, :, :4]
    assert np.mean(model.predict(warm) == "pump_leak_warning") >= 0.9
    assert np.mean(model.predict(cold) == "pump_leak_alert") >= 0.9
    est = model.features_._estimates(warm)[1][0].estimates
    se = severity_standard_error(est.mse["motor"], est.curvature["motor_leak"], 999 // 8)
    low, high = oil.motor_factors(est.severity["motor_leak"], se, model.features_.nominal_,
                                  oil.leakage_range(0.04, 5.0))
    assert np.median(low) < np.exp(0.2) <= np.median(high) and np.all(low > 1.0)  # the warm oil, not the cold
    spread = oil.FACTOR_SPREAD
    oil.FACTOR_SPREAD = 10.0  # every window allowed the whole ±5 K: the two meet
    try:
        both = np.concatenate([model.predict(warm) == "pump_leak_warning", model.predict(cold) == "pump_leak_alert"])
        assert np.mean(both) < 0.8
    finally:
        oil.FACTOR_SPREAD = spread
