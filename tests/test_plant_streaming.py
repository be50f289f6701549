"""Streaming: chunked runs equal one long run bit for bit, constant memory, seeding, settle, batches."""

import numpy as np
import pytest

from hydrowatch.errors import ParameterError
from hydrowatch.plant import CHANNELS, PlantParameters, PlantSimulator

STATEFUL = {
    "transport_delay": {"tau": 0.0125},  # 2.5 samples: the interval is split inside
    "valve_hysteresis": {},
    "sensor_lowpass": {"sensor": 0},
    "thermal_drift": {"tau": 30.0},
    "gear_backlash": {},
    "pump_ripple": {},
    "entrained_air": {},
}


def command(n: int, seed: int = 5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(np.cumsum(rng.normal(0, 0.15, n)), -4, 4)  # bipolar: reversals for the backlash


def run_chunked(sim: PlantSimulator, u: np.ndarray, cuts: list[int], change_at: int | None = None) -> dict:
    parts = []
    for a, b in zip([0, *cuts], [*cuts, len(u)]):
        if change_at == a:
            sim.set_parameters(0, PlantParameters(TL=13.0, Ctm=1e-12))
        parts.append(sim.step(u[a:b]))
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def test_chunked_run_equals_one_long_run_bit_for_bit():
    u = command(900)
    one = PlantSimulator(PlantParameters(), STATEFUL, seed=4)
    one_part = one.step(u[:300])
    one.set_parameters(0, PlantParameters(TL=13.0, Ctm=1e-12))
    whole = {k: np.concatenate([one_part[k], v]) for k, v in one.step(u[300:]).items()}
    chunked = run_chunked(PlantSimulator(PlantParameters(), STATEFUL, seed=4), u, [1, 7, 150, 300, 301, 640], 300)
    for k in whole:
        assert np.array_equal(whole[k], chunked[k]), k
    assert whole["temperature"][-1] == pytest.approx(40 + 20 * (1 - np.exp(-899 / 200 / 30)), rel=1e-6)


def test_memory_is_constant_and_time_continues():
    sim = PlantSimulator(PlantParameters(), noise=False)
    width = sim.state.shape
    for _ in range(20):
        out = sim.step(np.full(100, 1.0))
    assert sim.state.shape == width and out["t"].shape == (100,)
    assert out["t"][-1] == pytest.approx(1999 / 200) and sim.time == pytest.approx(10.0)


def test_seeded_noise_is_reproducible_and_has_the_parameter_sigma():
    u = np.full(4000, 2.0)
    a = PlantSimulator(PlantParameters(), seed=1).step(u)
    b = PlantSimulator(PlantParameters(), seed=1).step(u)
    c = PlantSimulator(PlantParameters(), seed=2).step(u)
    assert np.array_equal(a["flow"], b["flow"]) and not np.array_equal(a["flow"], c["flow"])
    clean = PlantSimulator(PlantParameters(), noise=False).step(u)
    late = slice(1000, None)
    assert np.std(a["torque"][late] - clean["torque"][late]) == pytest.approx(0.15, rel=0.08)
    assert np.std(a["flow"][late] - clean["flow"][late]) == pytest.approx(0.03, rel=0.08)
    assert np.array_equal(a["supply_pressure"], clean["supply_pressure"])  # pressure channels are noise-free
    sim = PlantSimulator(PlantParameters(), seed=9)
    first = sim.step(u[:50])
    sim.reset()
    assert np.array_equal(sim.step(u[:50])["speed"], first["speed"])


def test_batched_machines_equal_machines_run_alone():
    params = [PlantParameters(), PlantParameters(TL=12.0), PlantParameters(Kc=0.8)]
    effects = [None, {"stribeck_friction": {}}, {"transport_delay": {"tau": 0.02}}]
    u = np.stack([command(400, s) for s in range(3)])
    fleet = PlantSimulator(params, effects, seed=[10, 11, 12]).step(u)
    for m in range(3):
        alone = PlantSimulator(params[m], effects[m], seed=10 + m).step(u[m])
        for k in CHANNELS:
            assert np.array_equal(fleet[k][m], alone[k]), (m, k)
    shared = PlantSimulator(params, seed=3).step(u[0])  # one command drives all machines
    assert shared["speed"].shape == (3, 400)
    with pytest.raises(ParameterError, match="one per machine"):
        PlantSimulator(params, seed=[1, 2])


def test_settle_reaches_steady_state_without_advancing_time():
    sim = PlantSimulator(PlantParameters(), {"thermal_drift": {}}, noise=False)
    sim.settle(2.0)
    assert sim.time == 0.0 and sim.state[0, 7] == 40.0
    out = sim.step(np.full(20, 2.0))
    assert np.ptp(out["speed"]) < 1e-4 and out["speed"][0] == pytest.approx(8.85, rel=0.01)
    fleet = PlantSimulator([PlantParameters()] * 2, noise=False)
    fleet.settle(np.array([1.0, 3.0]))
    speeds = fleet.step(np.array([[1.0], [3.0]]))["speed"][:, 0]
    assert speeds[1] > 2.5 * speeds[0]
