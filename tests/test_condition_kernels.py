"""Compiled valve-relation kernels: same residuals as the array code, exact fits where the maths allows."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.condition import load_fill, parity
from hydrowatch.plant import PlantParameters, PlantSimulator
from hydrowatch.plant.excitation import duty_cycle
from hydrowatch.plant.faults import state_parameters

STATES = ("healthy", "valve_leak_alert", "pump_leak_warning", "relief_spring_alert")


@pytest.fixture(scope="module")
def signals() -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    command = duty_cycle(30, (0, 4), seed=3, segment_seconds=(2, 6))
    sim = PlantSimulator([state_parameters(s) for s in STATES], seed=4)
    sim.settle(float(command[0]))
    out = sim.step(command)
    p = PlantParameters()
    w = {c: out[c][:, :30 * 200].reshape(len(STATES), -1, 1000) for c in ("voltage", "flow", "speed", "torque")}
    res = {}
    for i, s in enumerate(STATES):
        pl = parity.load_pressure(w["speed"][i], w["torque"][i], p)
        res[s] = (w["flow"][i] / 6e4, parity.spool_position(w["voltage"][i], p), pl, w["speed"][i])
    return res


@pytest.mark.parametrize("fault", [None, *parity.VALVE_HYPOTHESES])
def test_kernel_mse_matches_the_array_residual(signals, fault):
    p = PlantParameters()
    flow, spool, pl, _ = signals["relief_spring_alert"]
    s = np.linspace(0.0, 0.4, flow.shape[0])
    leak = np.linspace(1.0, 1.5, flow.shape[0])[:, None]  # warm oil: leakages scaled per window
    expect = np.mean(parity.valve_residual(flow, spool, pl, p, fault, s, leak) ** 2, axis=1)
    np.testing.assert_allclose(parity.valve_mse(flow, spool, pl, p, fault, s, leak), expect, rtol=1e-9)


def test_valve_leak_fit_is_the_least_squares_minimum(signals):
    p = PlantParameters()
    flow, spool, pl, _ = signals["valve_leak_alert"]
    s, mse, curvature = parity.valve_fit(flow, spool, pl, p, "valve_leak")
    for h in (-0.05, 0.05):  # the residual is linear in s: MSE(s + h) = MSE(s) + curvature·h², exactly
        np.testing.assert_allclose(parity.valve_mse(flow, spool, pl, p, "valve_leak", s + h), mse + curvature * h * h,
                                   rtol=1e-6)
    assert np.all(np.abs(s[1:] - s[0]) < 0.01)  # one machine, one severity whatever the command did


def test_nonlinear_fit_is_a_minimum_with_its_curvature(signals):
    p = PlantParameters()
    for state, fault in (("pump_leak_warning", "pump_leak"), ("relief_spring_alert", "relief_spring")):
        flow, spool, pl, _ = signals[state]
        s, mse, curvature = parity.valve_fit(flow, spool, pl, p, fault)
        lo, hi = parity.SEVERITY_LIMITS[fault]
        for h in (-0.01, 0.01):
            near = parity.valve_mse(flow, spool, pl, p, fault, s + h)
            inside = (s + h > lo) & (s + h < hi)
            assert np.all(near[inside] >= mse[inside] * (1 - 1e-9)), state
        # At most the secant one local grid step (grid 7) either side, where that side is inside the limits.
        step = 2.0 * (hi - lo) / 6 / 6
        secants = []
        for h in (-step, step):
            inside = (s + h > lo) & (s + h < hi)
            secant = (parity.valve_mse(flow, spool, pl, p, fault, np.clip(s + h, lo, hi)) - mse) / h**2
            assert np.all(curvature[inside] <= secant[inside] * (1 + 1e-6) + 1e-12), state
            secants.append(np.where(inside, secant, np.nan))
        # Near the fit it is the local curvature, below it only where the cost flattens within the step.
        second = (parity.valve_mse(flow, spool, pl, p, fault, s + 1e-3) + parity.valve_mse(flow, spool, pl, p, fault,
                                                                                            s - 1e-3) - 2 * mse) / 2e-6
        well_posed = curvature > 1e-3 * curvature.max()  # holds near standstill barely excite the valve
        assert np.all(curvature[well_posed] <= 1.3 * second[well_posed]), state
        both = np.isfinite(secants[0]) & np.isfinite(secants[1]) & well_posed
        similar = both & (np.abs(secants[0] - secants[1]) < 0.35 * np.fmax(secants[0], secants[1]))
        assert similar.sum() >= 2, state
        assert np.all(curvature[similar] >= 0.6 * second[similar]), state
        if fault == "pump_leak":  # the low hold (0.6 V): the relief is open, the cost flat below the fit
            assert np.any(curvature < 0.2 * second), state


def test_speed_from_torque_recovers_the_gearbox_speed():
    p = PlantParameters()
    sim = PlantSimulator([p], noise=False, seed=1)
    command = duty_cycle(20, (0.5, 4), seed=8, segment_seconds=(2, 6))
    sim.settle(float(command[0]))
    out = sim.step(command)
    torque = out["torque"].reshape(-1, 1000)
    true = out["speed"].reshape(-1, 1000)
    est = load_fill.speed_from_torque(torque, p)
    # After the first 0.5 s (the load time constant JL/BL = 0.25 s forgets the start), in % of full speed.
    error = np.abs(est - true)[:, 100:]
    assert np.max(error) < 0.03 * true.max() and np.percentile(error, 99) < 0.005 * true.max()  # steps: ~1 sample


@pytest.fixture(scope="module")
def worn_reliefs() -> list[tuple[float, tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Five minutes of the working duty cycle on four units whose relief spring is worn 0, 3, 6 and 10 %: each
    hold at 3.4 V pushes the supply pressure near the cracking pressure, where the relief barely opens."""
    p = PlantParameters()
    severities = (0.0, 0.03, 0.06, 0.1)
    command = duty_cycle(300, (0.5, 3.5), seed=11)
    sim = PlantSimulator([p.replace(Pc=p.Pc * (1 - s)) for s in severities], seed=5)
    sim.settle(float(command[0]))
    out = sim.step(command)
    runs = []
    for i, s in enumerate(severities):
        w = {c: out[c][i, :300 * 200].reshape(-1, 1000) for c in ("voltage", "flow", "speed", "torque")}
        pl = parity.load_pressure(w["speed"], w["torque"], p)
        runs.append((s, (w["flow"] / 6e4, parity.spool_position(w["voltage"], p), pl)))
    return runs


def test_a_relief_fit_finds_the_valley_past_a_flat_stretch(worn_reliefs):
    """Where the relief stays shut for every severity up to its true one, the cost is flat there and the minimum is
    a valley just past the stretch's end, narrower than the local grid's step. The search stopped on the stretch
    (at its first point, −0.5) in 2 of 60 windows of each worn unit, with 100–1400× the true severity's MSE."""
    p = PlantParameters()
    for s, (flow, spool, pl) in worn_reliefs:
        fit, mse, _ = parity.valve_fit(flow, spool, pl, p, "relief_spring")
        truth = parity.valve_mse(flow, spool, pl, p, "relief_spring", np.full(flow.shape[0], s))
        assert np.all(mse <= 1.02 * truth), (s, np.max(mse / truth))
        assert np.all(np.abs(fit - s) < 0.02), (s, fit.min(), fit.max())
