"""Component relations: per-window parameter estimates hold whatever the command does."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.condition import parity
from hydrowatch.plant import PlantParameters, PlantSimulator
from hydrowatch.plant.excitation import duty_cycle, filtered_noise
from hydrowatch.plant.faults import level_severity, state_parameters

STATES = ("healthy", "load_warning", "motor_leak_alert", "valve_coil_warning", "relief_spring_alert")


def _windows(command: np.ndarray, seed: int, noise: bool = True) -> dict[str, dict[str, np.ndarray]]:
    sim = PlantSimulator([state_parameters(s) for s in STATES], noise=noise, seed=seed)
    sim.settle(float(command[0]))
    out = sim.step(command)
    n = command.size // 1000 * 1000
    return {s: {c: out[c][i, :n].reshape(-1, 1000) for c in ("voltage", "flow", "speed", "torque",
                                                              "supply_pressure", "load_pressure")}
            for i, s in enumerate(STATES)}


@pytest.fixture(scope="module")
def runs() -> dict[str, dict[str, dict[str, np.ndarray]]]:
    return {"noise": _windows(filtered_noise(20, (0, 4), seed=1), 2),
            "duty": _windows(duty_cycle(40, (0, 4), seed=3, segment_seconds=(2, 8)), 4)}


def test_spool_model_and_load_pressure_match_the_plant():
    p = PlantParameters()
    w = _windows(filtered_noise(10, (0, 4), seed=5), 6, noise=False)["healthy"]
    pl = parity.load_pressure(w["speed"], w["torque"], p)
    assert np.sqrt(np.mean((pl - w["load_pressure"] * 1e5) ** 2)) < 0.3e5  # < 0.3 bar of a ~15 bar swing
    x = parity.spool_position(w["voltage"], p)
    m = x.shape[0]
    ps, ql = parity.supply_and_valve_flow(p.Kq * x, pl, p, np.full(m, p.Cp + p.Cpl + p.Cvl), np.full(m, p.Pc))
    assert np.sqrt(np.mean((ps - w["supply_pressure"] * 1e5)[:, 200:] ** 2)) < 0.5e5  # from the command alone
    assert np.sqrt(np.mean((ql * 6e4 - w["flow"])[:, 200:] ** 2)) < 0.05  # L/min
    predicted = p.Kq * x * np.sqrt(np.maximum(w["supply_pressure"] * 1e5 - w["load_pressure"] * 1e5, 0.0))
    assert np.sqrt(np.mean((predicted * 6e4 - w["flow"]) ** 2)) < 0.01  # L/min, noiseless


@pytest.mark.parametrize("command", ["noise", "duty"])
def test_load_and_motor_estimates_do_not_depend_on_the_command(runs, command):
    p = PlantParameters()
    for state in STATES:
        w = runs[command][state]
        s_load, _, _ = parity.load_relation(w["speed"], w["torque"], p)
        pl = parity.load_pressure(w["speed"], w["torque"], p)
        s_motor, rms, _ = parity.motor_relation(w["flow"] / 6e4, w["speed"], pl, p)
        expect_load = level_severity("load", "warning") if state == "load_warning" else 0.0
        expect_motor = level_severity("motor_leak", "alert") if state == "motor_leak_alert" else 0.0
        assert np.abs(s_load - expect_load).max() < 0.02, state  # holds near standstill: ~0.01
        assert np.abs(s_motor - expect_motor).max() < 0.01, state
        assert rms.mean() < 0.02  # L/min: the motor relation leaves sensor noise only


@pytest.mark.parametrize("command", ["noise", "duty"])
def test_the_true_valve_hypothesis_explains_the_window(runs, command):
    p = PlantParameters()
    for state, fault in (("valve_coil_warning", "valve_coil"), ("relief_spring_alert", "relief_spring")):
        w = runs[command][state]
        pl = parity.load_pressure(w["speed"], w["torque"], p)
        x = parity.spool_position(w["voltage"], p)
        s, rms = parity.valve_relation(w["flow"] / 6e4, x, pl, p, fault)
        level = fault and state.rsplit("_", 1)[1]
        assert np.abs(s - level_severity(fault, level)).max() < 0.03, state
        assert rms.max() < 0.05  # L/min, flow noise is 0.03
