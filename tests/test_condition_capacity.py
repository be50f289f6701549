"""The pump's capacity from the machine's own history (issue 15): the pressure at the pump's limit, the pool's
regression that tells a capacity from a leak, and the machine's median."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hydrowatch.condition.capacity import (
    CAPACITY_STEP,
    MIN_LIMITED,
    PUMP_LIMIT,
    PUMP_LIMITED,
    MachineCapacity,
    capacity_error,
    capacity_errors,
    corrected,
    limit_ratio,
    limited_share,
)
from hydrowatch.condition.degradation import DETERMINED_STEP, degradation_index, window_degradation
from hydrowatch.condition.degradation_stream import DegradationStream
from hydrowatch.condition.estimates import parity_estimates, window_signals
from hydrowatch.condition.parity import BLOCK
from hydrowatch.plant import PlantSimulator
from hydrowatch.plant.excitation import duty_cycle
from hydrowatch.plant.faults import fault_parameters, level_severity
from hydrowatch.plant.parameters import PlantParameters

W = 1000
SENSORS = ("flow", "speed", "torque")


def _run(p: PlantParameters, u: np.ndarray, seed: int) -> dict[str, np.ndarray]:
    sim = PlantSimulator([p], None, seed=seed)
    sim.settle(float(u[0]))
    out = sim.step(u[None, :])
    n = u.size // W * W
    return {c: v[0, :n].reshape(-1, W) for c, v in out.items() if v.ndim == 2}


def _windows(out: dict[str, np.ndarray]) -> np.ndarray:
    return np.stack([out[c] for c in ("voltage", "flow", "speed", "torque")], axis=-1)


def test_the_limit_ratio_is_the_cracking_pressure_over_the_simulated_supply_pressure_at_the_limit():
    """A pump leak at its alert on the nominal unit at 3.5 V: the pump at its limit (relief shut); healthy at 1 V:
    the relief open, no sample at the limit."""
    nominal = PlantParameters()
    s = level_severity("pump_leak", "alert", nominal)
    for severity, volts, at_limit in ((s, 3.5, True), (0.0, 1.0, False)):
        out = _run(fault_parameters(nominal, "pump_leak", severity), np.full(2 * W, volts), seed=4)
        sig = window_signals(_windows(out), SENSORS, nominal)
        ratio = limit_ratio(sig.spool, sig.load_pressure, nominal, np.full(2, severity), sig.leak)
        if not at_limit:
            assert np.isnan(ratio).all()
            continue
        ps = out["supply_pressure"] * 1e5  # bar -> Pa
        truth = nominal.Pc / np.array([row[row < nominal.Pc].mean() for row in ps])
        assert truth.min() > 1.05  # the relief is shut: the pressure sags below cracking
        np.testing.assert_allclose(ratio, truth, rtol=0.01)


def test_a_pool_tells_a_capacity_from_a_leak_only_when_its_windows_meet_the_limit_at_different_pressures():
    rng = np.random.default_rng(3)
    k = np.arange(60, dtype=np.float64)
    ratio = rng.uniform(1.1, 1.9, k.size)
    severity = 0.2 + 0.004 * k - 0.3 * ratio + rng.normal(0.0, 0.005, k.size)  # capacity 1.3x theta0's
    usable = np.ones(k.size, dtype=bool)
    assert capacity_error(severity, ratio, usable) == pytest.approx(0.3, abs=1.5 * CAPACITY_STEP)
    # the leak's own trend alone (a capacity that is right) reads 0
    assert capacity_error(0.2 + 0.004 * k + rng.normal(0.0, 0.005, k.size), ratio, usable) == pytest.approx(
        0.0, abs=1.5 * CAPACITY_STEP)
    # one pressure for every window: a capacity and a leak read alike
    flat = np.full(k.size, 1.5) + rng.normal(0.0, 1e-3, k.size)
    assert np.isnan(capacity_error(0.2 + 0.004 * k - 0.3 * flat + rng.normal(0.0, 0.005, k.size), flat, usable))
    fewer = usable.copy()
    fewer[MIN_LIMITED - 1:] = False
    assert np.isnan(capacity_error(severity, ratio, fewer))
    assert np.isnan(capacity_error(severity, np.where(k < 50, np.nan, ratio), usable))  # never at the limit


def test_the_machines_capacity_is_the_median_of_its_pools_and_none_before_the_first():
    machine = MachineCapacity()
    got = [machine.add(q) for q in (np.nan, 0.3, 0.5, 0.31, np.nan, 0.8)]
    np.testing.assert_array_equal(got, [np.nan, 0.3, 0.3, 0.31, 0.31, 0.31])  # 0.8 is clipped to the bound, 0.5
    q = capacity_errors(np.zeros(30), np.full(30, np.nan), np.ones(30, dtype=bool), pool=10)
    assert np.isnan(q).all()  # never at the limit: never determined


def test_a_corrected_severity_reads_the_index_of_the_true_capacity():
    """θ0's capacity 0.8 × the unit's: a window at the limit at Ps = Pc / 1.4 fits ŝ = s − q·1.4, q = 0.25."""
    unit = PlantParameters()
    theta0 = unit.replace(Dp=unit.Dp * 0.8)
    q, ratio, s = 0.25, 1.4, 0.4 * level_severity("pump_leak", "alert", unit)
    s_theta0 = s * unit.Dp / theta0.Dp  # the unit's leak on theta0's severity scale (Cref scales with Dp)
    fitted = s_theta0 - q * ratio
    back = corrected(np.array([fitted]), np.array([ratio]), q)
    assert back[0] == pytest.approx(s, rel=1e-12)
    assert float(degradation_index("pump_leak", back[0], theta0.replace(Dp=theta0.Dp * (1 + q)))) == pytest.approx(
        float(degradation_index("pump_leak", s, unit)), rel=1e-9)


def test_on_a_simulated_duty_cycle_the_pool_finds_the_capacity_commissioning_missed():
    """θ0 with the pump's capacity 0.75 × the unit's (what commissioning left on a pump that outdelivers its valve,
    seed 2055): 5 minutes of duty cycle with the pump leak at its warning put the pump at its limit at several
    commands; the pool's q̂ is the capacity's error, 1/0.75 − 1 = 0.333."""
    unit = PlantParameters()
    worn = fault_parameters(unit, "pump_leak", level_severity("pump_leak", "warning", unit))
    theta0 = unit.replace(Dp=unit.Dp * 0.75)
    out = _run(worn, duty_cycle(300, (0.5, 3.5), seed=5), seed=6)
    est = parity_estimates(window_signals(_windows(out), SENSORS, theta0), theta0)
    usable = est.curvature["pump_leak"] * DETERMINED_STEP**2 >= est.mse["pump_leak"]
    assert np.isfinite(est.severity[PUMP_LIMIT]).sum() >= MIN_LIMITED
    q = capacity_errors(est.severity["pump_leak"], est.severity[PUMP_LIMIT], usable, pool=60)
    assert np.isfinite(q[-1]) and q[-1] == pytest.approx(1 / 0.75 - 1, abs=0.02)
    # the index: read on the history's capacity every window that has one reads the warning (0.5); read on θ0's, the
    # windows scatter with their command (0.13-0.60, measured); a capacity not known at commissioning: no index
    # until the history determines it
    valid = np.ones(q.size, dtype=bool)
    blocks, relations = (W - 1) // BLOCK, ("load", "motor", "valve")
    found = window_degradation(est, valid, theta0, blocks, relations, capacity_known=False).history("pump_leak")
    first = int(np.argmax(np.isfinite(q)))
    assert np.isnan(found[:first]).all() and np.isfinite(found[first:]).sum() >= 25
    assert np.nanmax(np.abs(found - 0.5)) < 0.03
    # online, window by window (the scorer's DegradationStream), the same
    unit_model = SimpleNamespace(relations_=relations, nominal_=theta0, window=W, capacity_known_=False)
    batch = window_degradation(est, valid, theta0, blocks, relations, capacity_known=False)
    stream = DegradationStream(unit_model)  # type: ignore[arg-type]
    for i in range(q.size):
        online = stream.update(*({k: float(v[i]) for k, v in part.items()}
                                 for part in (est.severity, est.mse, est.curvature)))
        assert online == batch.window(i, measured=True), i
    as_commissioned = window_degradation(est, valid, theta0, blocks, relations).history("pump_leak")  # known
    assert np.nanmax(as_commissioned) - np.nanmin(as_commissioned) > 0.3
    # and with θ0 right, nothing to correct
    est = parity_estimates(window_signals(_windows(out), SENSORS, unit), unit)
    usable = est.curvature["pump_leak"] * DETERMINED_STEP**2 >= est.mse["pump_leak"]
    q = capacity_errors(est.severity["pump_leak"], est.severity[PUMP_LIMIT], usable, pool=60)
    assert abs(q[-1]) <= 0.01


def test_the_limited_share_is_the_simulated_share_of_samples_with_the_relief_shut_below_cracking():
    """Known truth: the simulator's own supply pressure. A duty cycle up to 4.5 V on the nominal unit meets the
    pump's limit in some windows and not in others; each window's share of samples below the cracking pressure
    (what lessens its say in which valve-side part wears) is the simulated one."""
    nominal = PlantParameters()
    out = _run(nominal, duty_cycle(60.0, (0.5, 4.5), seed=6), seed=7)
    sig = window_signals(_windows(out), SENSORS, nominal)
    share = limited_share(sig.spool, sig.load_pressure, nominal, sig.leak)
    truth = np.mean(out["supply_pressure"] * 1e5 < nominal.Pc, axis=1)
    assert (truth > 0.5).any() and (truth < 0.05).any()  # both kinds of window
    np.testing.assert_allclose(share, truth, atol=0.05)
    est = parity_estimates(sig, nominal)
    np.testing.assert_array_equal(est.severity[PUMP_LIMITED], share)  # what the estimates carry
