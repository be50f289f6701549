"""The compiled kernel: its inlined integrator is classical RK4 over the right-hand side, effects that
are switched on but do nothing leave the nominal path bit for bit, a sample's sensors do not depend on the
command (the kernel takes them from the interval's first RK4 stage), and it runs beside other threads."""

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from hydrowatch.plant import CHANNELS, PlantParameters, PlantSimulator
from hydrowatch.plant.dynamics import (
    EXP_ZERO,
    N_COEF,
    N_LOAD,
    N_ODE,
    PL,
    PS,
    TANH_ONE,
    _stribeck,
    _tanh,
    coefficients,
    derivatives,
    rates,
)
from hydrowatch.plant.effects import EFFECT_OFFSET, effect_row
from hydrowatch.plant.kernel import CHANNELS_OUT, _advance_compiled, _region, _rk4_from_outlined, _step_past_kink

INERT = {  # every effect here is on, with the setting at which its physics vanishes exactly
    "stribeck_friction": {"Tc": 0.0, "Ts": 0.0},
    "quadratic_drag": {"Kd": 0.0},
    "valve_saturation": {"x_max": 1.0},  # the spool stays inside ±1 for commands up to 4 V
    "valve_hysteresis": {"r": 0.0},
    "transport_delay": {"tau": 0.0},
    "pump_ripple": {"a1": 0.0, "a2": 0.0},
    "thermal_drift": {"T_start": 40.0, "T_end": 40.0},
}


def command(n: int, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(np.cumsum(rng.normal(0, 0.1, n)) + 2.0, 0.0, 4.0)


def test_effects_switched_on_at_their_null_setting_leave_the_nominal_run_bit_for_bit():
    u = command(600)
    nominal = PlantSimulator(PlantParameters(), seed=8).step(u)
    inert = PlantSimulator(PlantParameters(), INERT, seed=8).step(u)
    for k in (*CHANNELS, "temperature"):
        assert np.array_equal(nominal[k], inert[k]), k
    live = PlantSimulator(PlantParameters(), {"quadratic_drag": {}}, seed=8).step(u)
    assert np.max(np.abs(live["torque"] - nominal["torque"])) > 0.3  # the branch is really taken when on


def test_kernel_step_is_classical_rk4_over_the_array_right_hand_side():
    """From a settled 2 V state, a 2.6 V step stays in one smooth piece (spool open, relief open)."""
    p, fs, substeps, n = PlantParameters(), 200.0, 10, 40
    sim = PlantSimulator(p, noise=False, substeps=substeps)
    sim.settle(2.0)
    y = sim.state[0, :N_ODE].copy()
    out = sim.step(np.full(n, 2.6))
    coef, row = np.empty(N_COEF + N_LOAD), effect_row(None)
    coefficients(p.as_array(), coef)
    k1, k2, k3, k4 = (np.empty(N_ODE) for _ in range(4))
    sensors = np.empty(3)
    h = (1.0 / fs) / substeps
    flow = np.empty(n)
    for k in range(n):
        rates(coef, row, y, 0.0, 0.0, True, k1, sensors)
        flow[k] = sensors[0]
        for _ in range(substeps):
            rates(coef, row, y, 2.6, 0.0, True, k1, sensors)
            rates(coef, row, y + 0.5 * h * k1, 2.6, 0.0, True, k2, sensors)
            rates(coef, row, y + 0.5 * h * k2, 2.6, 0.0, True, k3, sensors)
            rates(coef, row, y + h * k3, 2.6, 0.0, True, k4, sensors)
            y = y + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            assert y[PS] > p.Pc and 0.0 <= abs(y[PL]) < y[PS]  # no kink, no projection
    assert np.ptp(flow) > 0.5  # a real transient, L/min
    assert np.array_equal(out["flow"], flow)
    assert np.array_equal(sim.state[0, :N_ODE], y)


LIVE = {  # every effect on at a magnitude where it acts
    "stribeck_friction": {"Tc": 0.2, "Ts": 1.0},
    "quadratic_drag": {"Kd": 0.03},
    "valve_deadband": {"d": 0.1},
    "valve_saturation": {"x_max": 0.5},
    "entrained_air": {"alpha": 0.05},
    "pump_ripple": {"a1": 0.1, "a2": 0.05},
    "thermal_drift": {"T_start": 35.0, "T_end": 70.0, "tau": 100.0},
    "gear_backlash": {"b": 0.02},
    "shaft_compliance": {"G": 800.0},
}


def test_the_sensors_of_a_state_do_not_depend_on_the_command():
    """The kernel reads sample k's sensors from the right-hand side evaluated with the interval's command (its
    first RK4 stage, issue 12 item 5): the same numbers only while the command moves nothing but the spool's
    acceleration. Every effect, states across the range, commands −4 and 3.7 V: the same sensors bit for bit."""
    p = PlantParameters()
    rng = np.random.default_rng(7)
    coef = np.empty(N_COEF + N_LOAD)
    coefficients(p.as_array(), coef)
    ds, sensors = np.empty(N_ODE), np.empty(3)
    for effects in (None, *({k: v} for k, v in LIVE.items()), LIVE, {"sensor_lowpass": {"sensor": 2.0}}):
        row = effect_row(effects)
        for _ in range(20):
            y = np.array([rng.uniform(-1, 1), rng.normal(0, 50), rng.uniform(0, 2.2e7), rng.uniform(-1e7, 1e7),
                          rng.normal(0, 100), rng.normal(0, 30), rng.normal(0, 0.03), rng.uniform(30, 70),
                          rng.normal(0, 5)])
            read = []
            for u in (-4.0, 3.7):
                rates(coef, row, y, u, 1.3, True, ds, sensors)
                read.append(sensors.copy())
            assert np.array_equal(read[0], read[1]), effects
            assert np.all(np.isfinite(read[0]))


def test_settling_ends_once_the_state_stops_changing_with_the_same_state_and_outputs():
    """Settling (clock stopped, constant command, no noise) stops at the first sample that leaves the state unchanged
    bit for bit and repeats that sample's outputs (issue 12, item 5): the same state and every output as settling one
    sample per call, for machines that reach that point (nominal, backlash, hysteresis) and one whose play operator
    and a second command level keep it moving."""
    machines = [PlantParameters(), PlantParameters(TL=14.0), PlantParameters(Kq=PlantParameters().Kq * 1.2)]
    effects = [None, {"gear_backlash": {"b": 0.02}}, {"valve_hysteresis": {"r": 0.2}}]
    n = 600
    levels = np.array([[2.2] * n, [-1.5] * n, [0.7] * (n // 2) + [1.9] * (n // 2)])
    whole = PlantSimulator(machines, effects, noise=False)
    whole_out = np.empty((3, n, CHANNELS_OUT))
    one = PlantSimulator(machines, effects, noise=False)
    one_out = np.empty_like(whole_out)
    no_noise = np.empty((0, 0, 3))
    state = whole._state
    _advance_compiled(whole._params, whole._effects, state, levels, no_noise, whole_out, 200.0, 0.0, 10, False)
    sample = np.empty((3, 1, CHANNELS_OUT))
    for k in range(n):
        _advance_compiled(one._params, one._effects, one._state, levels[:, k : k + 1].copy(), no_noise, sample,
                          200.0, 0.0, 10, False)
        one_out[:, k] = sample[:, 0]
    assert np.array_equal(state, one._state)
    assert np.array_equal(whole_out, one_out)
    assert np.ptp(whole_out[2, :, 0]) > 1.0  # the last machine really moves (flow, L/min)


def test_simulators_in_threads_equal_serial_runs():
    """The kernel releases the GIL (nogil), so a service can step plants beside its bus threads."""
    assert _advance_compiled.targetoptions.get("nogil") is True
    u = command(400, seed=4)
    machines = [PlantParameters(TL=10.0 + m) for m in range(4)]

    def run(m: int) -> dict[str, np.ndarray]:
        return PlantSimulator(machines[m], {"gear_backlash": {}} if m % 2 else None, seed=m).step(u)

    serial = [run(m) for m in range(4)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        threaded = list(pool.map(run, range(4)))
    for m in range(4):
        for k in CHANNELS:
            assert np.array_equal(serial[m][k], threaded[m][k]), (m, k)


def _bits(values: np.ndarray) -> np.ndarray:
    return np.asarray(values, dtype=np.float64).view(np.int64)


def test_tanh_and_exp_shortcuts_are_libm_bit_for_bit():
    """The right-hand side skips libm's tanh where it is ±1 (|x| ≥ TANH_ONE) and exp where it underflows to 0
    (issue 12, item 5): the same floats as math.tanh / math.exp on both sides of each threshold, ±0, ±inf and NaN."""
    x = np.concatenate([np.linspace(-30.0, 30.0, 60001), [TANH_ONE, np.nextafter(TANH_ONE, 0.0), -TANH_ONE, 0.0, -0.0,
                                                          1e300, -1e300, np.inf, -np.inf]])
    assert np.array_equal(_bits([_tanh(v) for v in x]), _bits([math.tanh(v) for v in x]))
    assert math.isnan(_tanh(math.nan))
    below = np.linspace(EXP_ZERO - 5.0, EXP_ZERO + 5.0, 1001)
    assert all(math.exp(v) == 0.0 for v in below if v < EXP_ZERO)  # the threshold the Stribeck term relies on
    row = effect_row({"stribeck_friction": {"Tc": 0.2, "Ts": 1.0, "omega_st": 0.5, "omega_eps": 0.5}})
    for wm in (0.0, 1e-3, 0.3, 11.0, 13.6, 13.7, 20.0, 40.0, -40.0):  # exp(−(ωm/ωst)²) underflows from ωm ≈ 13.65 rad/s
        tc, ts, w_st, w_eps = (row[EFFECT_OFFSET["stribeck_friction"] + i] for i in range(1, 5))
        plain = (tc + (ts - tc) * math.exp(-((wm / w_st) ** 2))) * math.tanh(wm / w_eps)
        assert _bits([_stribeck(row, wm)]) == _bits([plain]), wm


def test_the_kink_bisection_returns_the_step_to_the_kink_from_the_same_first_stage():
    """A step whose spool passes zero: the bisection's state past the kink is the RK4 step of the returned length
    from the same state and first stage, bit for bit, it has left the region and 2**-12 of a step less has not
    (issue 12, item 5: the bisection reuses the step's first stage and its last trial step)."""
    p = PlantParameters()
    coef = np.empty(N_COEF + N_LOAD)
    coefficients(p.as_array(), coef)
    row = effect_row(None)
    y = (2e-4, -1.0, 1.5e7, 2e6, 50.0, 0.0, 0.0, 40.0, 0.0)  # x > 0 moving down: through zero in 0.2 ms
    h, t, u = 5e-4, 0.0, 0.0
    code = _region(coef, row, y)
    k1 = derivatives(coef, row, y, u, t, True)[0]
    whole = _rk4_from_outlined(coef, row, y, k1, u, t, h, True)
    assert _region(coef, row, whole) != code
    done, past = _step_past_kink(coef, row, y, k1, whole, u, t, h, True, code)
    assert 0.0 < done < h
    assert _bits(past).tolist() == _bits(_rk4_from_outlined(coef, row, y, k1, u, t, done, True)).tolist()
    assert _region(coef, row, past) != code
    assert _region(coef, row, _rk4_from_outlined(coef, row, y, k1, u, t, done - h / 4096, True)) == code
