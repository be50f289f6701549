"""Nominal plant model: parameters, steady states, resonance and integrator accuracy (plant-model.md)."""

import math

import numpy as np
import pytest

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.plant import (
    CHANNELS,
    DEFAULT_SUBSTEPS,
    PARAMETER_NAMES,
    REFERENCE_SUBSTEPS,
    PlantParameters,
    PlantSimulator,
    simulate,
    zero_flow_supply_pressure,
)
from hydrowatch.plant.kernel import _NOISE
from hydrowatch.plant.parameters import PARAMETER_INDEX
from hydrowatch.plant.simulator import linear_modes


def filtered_noise(n: int, lo: float = 0.0, hi: float = 4.0, seed: int = 3) -> np.ndarray:
    """Identification input of plant-model.md: y(t) = 0.9·y(t−1) + 0.1·w(t), scaled onto [lo, hi]."""
    w = np.random.default_rng(seed).standard_normal(n)
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = 0.9 * y[k - 1] + 0.1 * w[k]
    return lo + (y - y.min()) / (y.max() - y.min()) * (hi - lo)


def test_defaults_are_the_spec_table():
    p = PlantParameters()
    assert p.Dp == pytest.approx(3.5e-6 / (2 * math.pi))
    assert p.omega_p == pytest.approx(183.26, rel=1e-4)
    assert p.Kq * math.sqrt(70e5) * 60000 == pytest.approx(10.0, rel=1e-3)  # 10 L/min at 70 bar
    assert (p.Pc, p.Vs, p.beta_e, p.Vt, p.N, p.eta, p.JL, p.TL, p.Cpl) == (70e5, 2e-4, 1e9, 1e-4, 5, 0.95, 0.05, 10, 0)
    assert PARAMETER_NAMES[-1] == "Cpl" and len(PARAMETER_NAMES) == 29
    assert np.array_equal(p.as_array()[PARAMETER_INDEX["TL"]], 10.0)
    assert _NOISE == PARAMETER_INDEX["noise_flow"] == PARAMETER_INDEX["noise_torque"] - 2


def test_invalid_parameters_are_refused(tmp_path):
    with pytest.raises(ParameterError, match="'Vs' must be finite and > 0. Got -0.001"):
        PlantParameters(Vs=-1e-3)
    with pytest.raises(ParameterError, match="'Ctm' must be finite"):
        PlantParameters(Ctm=float("nan"))
    with pytest.raises(ParameterError, match="'Pc'"):
        PlantParameters(Pc=0.0)
    with pytest.raises(ParameterError, match="'eta'"):
        PlantParameters().replace(eta=1.2)
    with pytest.raises(ParameterError, match="unknown \\['Kv'\\]"):
        PlantParameters.from_dict({"Kv": 1.0})
    with pytest.raises(ParameterError, match="must be a real number"):
        PlantParameters(TL="ten")  # type: ignore[arg-type]
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ParameterError, match="valid JSON"):
        PlantParameters.from_json(bad)


def test_json_round_trip(tmp_path):
    p = PlantParameters().replace(TL=12.5, Cpl=3e-12)
    path = tmp_path / "nominal.json"
    text = p.to_json(path)
    assert PlantParameters.from_json(path) == p == PlantParameters.from_json(text)
    assert PlantParameters.from_dict({"TL": 12.5, "Cpl": 3e-12}) == p


def test_steady_speed_at_2_volts_is_the_spec_value():
    rec = simulate(np.full(200, 2.0), noise=False)
    assert rec["speed"][-1] == pytest.approx(8.85, rel=0.01)
    # The steady state also balances the motor equation: torque = TL·tanh + BL·ωg.
    assert rec["torque"][-1] == pytest.approx(10 * math.tanh(rec["speed"][-1] / 0.2) + 0.2 * rec["speed"][-1], rel=1e-6)


def test_pump_limits_flow_above_three_and_a_half_volts():
    steady = {u: simulate(np.full(100, u), noise=False) for u in (2.0, 3.0, 4.0, 5.0)}
    flow = {u: r["flow"][-1] for u, r in steady.items()}
    supply = {u: r["supply_pressure"][-1] for u, r in steady.items()}
    assert flow[3.0] - flow[2.0] > 1.5  # valve-limited: about 1.6 L/min per volt
    assert flow[5.0] - flow[4.0] < 0.1  # pump-limited: flat
    assert supply[2.0] > 70.0 > supply[4.0] + 10.0  # relief open below, supply pressure sags above
    p = PlantParameters()
    assert flow[5.0] < p.Dp * p.omega_p * 60000


def test_rest_state_and_hydraulic_resonance():
    p = PlantParameters()
    sim = PlantSimulator(p, noise=False)
    assert sim.state[0, 2] == pytest.approx(zero_flow_supply_pressure(p)) and sim.state[0, 2] > p.Pc
    frequency, damping = linear_modes(2.0)
    assert frequency[0] == pytest.approx(28.0, abs=1.0)  # motor + load on the oil spring
    assert frequency[1] == pytest.approx(60.0, rel=1e-3) and damping[1] == pytest.approx(0.7, rel=1e-3)  # spool


def test_default_integrator_agrees_with_rk4_at_10_khz():
    """Relative error = max |y − y_ref| / std(y_ref) per channel, filtered-noise 0–4 V, 20 s."""
    command = filtered_noise(4000)
    runs = {}
    for substeps in (DEFAULT_SUBSTEPS, REFERENCE_SUBSTEPS):
        runs[substeps] = PlantSimulator(PlantParameters(), noise=False, substeps=substeps).step(command)
    assert REFERENCE_SUBSTEPS * 200 == 10000
    for channel in CHANNELS:
        ref = runs[REFERENCE_SUBSTEPS][channel]
        error = np.max(np.abs(runs[DEFAULT_SUBSTEPS][channel] - ref)) / np.std(ref)
        assert error < 1e-3, channel


def test_simulate_returns_a_recording_with_meta():
    rec = simulate(filtered_noise(400), seed=11, meta={"machine": "m1"})
    assert set(rec.channels) == {"voltage", *CHANNELS, "temperature"}
    assert rec.meta["seed"] == 11 and rec.meta["machine"] == "m1" and rec.meta["parameters"]["TL"] == 10.0
    assert np.allclose(np.diff(rec.t), 1 / 200) and np.all(rec["temperature"] == 40.0)
    assert isinstance(simulate(np.ones(5)).meta["seed"], int)
    with pytest.raises(DataError, match="voltage must be finite"):
        simulate(np.array([1.0, np.nan]))
    with pytest.raises(DataError, match="shape"):
        PlantSimulator([PlantParameters()] * 2).step(np.ones((3, 4)))
