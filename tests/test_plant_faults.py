"""Health states: the algebraic steady state, fault scales and the calibrated warning/alert levels."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.errors import ParameterError
from hydrowatch.plant.faults import (
    EXTENDED_STATES,
    FAULTS,
    LEVEL_BANDS,
    STUDY_STATES,
    fault_parameters,
    level_for_speed_drop,
    level_severity,
    parse_state,
    random_state_parameters,
    severity_for_speed_drop,
    speed_drop,
    state_name,
    state_parameters,
)
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import PlantSimulator
from hydrowatch.plant.steady import steady_curve, steady_speed, steady_state


def _simulated_steady(params: list[PlantParameters], voltage: float) -> dict[str, np.ndarray]:
    """Sensors after a long noiseless run at a constant command, one row per machine."""
    sim = PlantSimulator(params, noise=False, seed=0)
    sim.settle(voltage, seconds=6.0)
    out = sim.step(np.full((len(params), 40), voltage))
    return {k: v[:, -1] for k, v in out.items()}


def test_nominal_speed_at_2_volts_is_the_documented_value():
    assert steady_speed(2.0) == pytest.approx(8.85, abs=0.01)
    state = steady_state(2.0)
    assert state.relief_open  # the pump delivers more than the motor takes at 2 V
    assert 70e5 < state.supply_pressure_pa < 73e5
    assert state.sensors()["load_pressure"] == pytest.approx(19.8, abs=0.2)  # bar


def test_supply_sags_above_three_and_a_half_volts():
    low, high = steady_state(3.0), steady_state(4.0)
    assert low.relief_open and not high.relief_open
    assert high.supply_pressure_pa < 0.9 * PlantParameters().Pc
    curve = steady_curve(np.array([3.0, 3.5, 4.0, 4.5]))
    gains = np.diff(curve["speed"]) / 0.5
    assert gains[0] > 3.0 and gains[-1] < 0.5  # flow saturates: the static gain collapses


def test_negative_command_mirrors_positive():
    pos, neg = steady_state(1.5), steady_state(-1.5)
    assert neg.speed == pytest.approx(-pos.speed, rel=1e-12)
    assert neg.load_pressure_pa == pytest.approx(-pos.load_pressure_pa, rel=1e-12)
    assert neg.supply_pressure_pa == pytest.approx(pos.supply_pressure_pa, rel=1e-12)
    assert steady_state(0.0).speed == 0.0


@pytest.mark.parametrize("voltage", [0.5, 2.0, 3.2, 4.0])
def test_steady_state_agrees_with_long_simulation(voltage):
    states = ("healthy", "load_alert", "pump_leak_alert", "valve_leak_warning", "relief_spring_alert")
    params = [state_parameters(s) for s in states]
    sim = _simulated_steady(params, voltage)
    for i, p in enumerate(params):
        expected = steady_state(voltage, p).sensors()
        for channel in ("flow", "speed", "torque", "supply_pressure"):
            assert sim[channel][i] == pytest.approx(expected[channel], rel=2e-3), (states[i], channel)


def test_warning_and_alert_drop_the_simulated_speed_by_15_and_30_percent():
    params = [state_parameters(s) for s in EXTENDED_STATES]
    speed = _simulated_steady(params, 2.0)["speed"]
    drops = 1.0 - speed / speed[0]
    for state, drop in zip(EXTENDED_STATES[1:], drops[1:]):
        target = 0.15 if state.endswith("_warning") else 0.30
        assert drop == pytest.approx(target, abs=0.005), state


def test_each_fault_moves_its_documented_parameter():
    p = PlantParameters()
    c_ref = p.Dp * p.omega_p / p.Pc
    assert fault_parameters(p, "load", 0.5).TL == pytest.approx(15.0)
    assert fault_parameters(p, "pump_leak", 0.2).Cpl == pytest.approx(0.2 * c_ref)
    assert fault_parameters(p, "motor_leak", 0.2).Ctm == pytest.approx(p.Ctm + 0.2 * c_ref)
    assert fault_parameters(p, "valve_leak", 0.2).Cvx == pytest.approx(0.2 * c_ref)
    assert fault_parameters(p, "valve_coil", 0.25).Kc == pytest.approx(0.75)
    assert fault_parameters(p, "relief_spring", 0.25).Pc == pytest.approx(52.5e5)
    with pytest.raises(ParameterError, match="severity of fault 'valve_coil'"):
        fault_parameters(p, "valve_coil", 1.5)
    with pytest.raises(ParameterError, match="fault must be one of"):
        fault_parameters(p, "gearbox", 0.1)


@pytest.mark.parametrize("fault", FAULTS)
def test_speed_drop_rises_with_severity(fault):
    top = level_severity(fault, "alert")
    drops = [speed_drop(fault, s) for s in np.linspace(0.0, top, 12)]
    assert drops[0] == 0.0
    assert np.all(np.diff(drops) >= -1e-12)
    assert drops[-1] == pytest.approx(0.30, abs=1e-9)


def test_relief_spring_reaches_both_levels_by_lowering_the_supply_pressure():
    warning, alert = (state_parameters(f"relief_spring_{lvl}") for lvl in ("warning", "alert"))
    assert 0.0 < level_severity("relief_spring", "warning") < level_severity("relief_spring", "alert") < 1.0
    assert steady_state(2.0, alert).supply_pressure_pa < steady_state(2.0, warning).supply_pressure_pa < 70e5


def test_unreachable_drop_is_refused_not_faked():
    with pytest.raises(ParameterError, match="physics reaches no more"):
        severity_for_speed_drop("relief_spring", 0.999)
    with pytest.raises(ParameterError, match=r"fraction in \(0, 1\)"):
        severity_for_speed_drop("load", 1.2)


def test_levels_are_recomputed_for_other_nominal_parameters():
    heavy = PlantParameters(TL=12.0)
    s_nominal, s_heavy = level_severity("load", "warning"), level_severity("load", "warning", heavy)
    assert s_heavy != pytest.approx(s_nominal, rel=1e-3)
    assert speed_drop("load", s_heavy, heavy) == pytest.approx(0.15, abs=1e-9)
    assert state_parameters("load_warning", heavy).TL == pytest.approx(12.0 * (1 + s_heavy))


def test_state_names():
    assert len(STUDY_STATES) == 7 and len(EXTENDED_STATES) == 13
    assert set(STUDY_STATES) <= set(EXTENDED_STATES)
    assert parse_state("healthy") == (None, None)
    assert parse_state("pump_leak_alert") == ("pump_leak", "alert")
    assert all(state_name(*parse_state(s)) == s for s in EXTENDED_STATES)
    with pytest.raises(ParameterError, match="motor_leak_warning"):
        parse_state("motor_leak_critical")
    assert state_parameters("healthy") == PlantParameters()


def test_random_severities_fall_inside_the_level_bands():
    rng = np.random.default_rng(5)
    for state in ("motor_leak_warning", "valve_coil_alert"):
        lo, hi = LEVEL_BANDS[state.rsplit("_", 1)[1]]
        for _ in range(3):
            params, drop = random_state_parameters(state, rng)
            assert lo <= drop <= hi
            assert 1.0 - steady_speed(2.0, params) / steady_speed(2.0) == pytest.approx(drop, abs=1e-9)
    assert random_state_parameters("healthy", rng) == (PlantParameters(), 0.0)


def test_nearest_level_of_a_speed_drop():
    assert [level_for_speed_drop(d) for d in (0.0, 0.07, 0.08, 0.2, 0.23, 0.4)] == [
        None, None, "warning", "warning", "alert", "alert"]
