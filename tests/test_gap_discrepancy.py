"""The saved model's output-discrepancy stage (issue 6): `gap --save-model` writes the `unidentified`
corrections and `simulate --nominal` applies them, reproducing the improved held-out fit."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hydrowatch.cli import main
from hydrowatch.errors import ParameterError
from hydrowatch.gap import Discrepancy, GapModel, load_model, read_model
from hydrowatch.gap.align import align
from hydrowatch.gap.discrepancy import MODEL_SCHEMA, SensorCorrection, model_from_config
from hydrowatch.gap.locate import nrmse
from hydrowatch.io import read_recording, write_recording
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import PlantSimulator, simulate
from hydrowatch.recording import SENSORS, Recording

SETTINGS = {"pump_speed": 183.26, "rate_scale": 2.0}


def heating_brake(seconds: float, rise: float, seed: int, chunk: int = 20) -> Recording:
    """A recording with physics the catalog does not hold: the load torque T_L grows linearly over the
    run by ``rise`` (a brake heating up), inside the plant dynamics (speed and flow feel it too).

    The plant (calibrated parameters ×0.8…1.2) is stepped in 0.1 s chunks, T_L updated before each.
    """
    rng = np.random.default_rng(seed)
    nominal = PlantParameters()
    plant = nominal.replace(Kq=nominal.Kq * rng.uniform(0.8, 1.2), TL=nominal.TL * rng.uniform(0.8, 1.2),
                            Ctm=nominal.Ctm * rng.uniform(0.8, 1.2))
    u = filtered_noise(seconds, (0.0, 4.0), seed=seed)
    sim = PlantSimulator(plant, None, noise=True, seed=seed)
    sim.settle(float(u[0]))
    parts = []
    for k in range(0, u.size, chunk):
        sim.set_parameters(0, plant.replace(TL=plant.TL * (1.0 + rise * k / u.size)))
        parts.append(sim.step(u[k:k + chunk]))
    channels = {name: np.concatenate([p[name] for p in parts]) for name in ("t", "voltage", *SENSORS)}
    return Recording(channels.pop("t"), channels, {"source": "heating brake"})


def test_discrepancy_round_trips_and_refuses_unknown_terms() -> None:
    d = Discrepancy((SensorCorrection("torque", {"t": 0.1, "ω·|ω|": -0.002}, SETTINGS),))
    again = Discrepancy.from_config(json.loads(json.dumps(d.to_config())), pump_speed=1.0)
    assert again == d
    assert d.to_config()["torque"]["unit"] == "N·m"
    with pytest.raises(ParameterError, match="correction terms must be finite coefficients of library terms"):
        Discrepancy.from_config({"torque": {"terms": {"ω³": 1.0}}}, pump_speed=183.26)
    with pytest.raises(ParameterError, match="correction sensor must be one of"):
        Discrepancy.from_config({"pressure": {"terms": {"t": 1.0}}}, pump_speed=183.26)
    # an older model without library settings still loads: ωp from the parameters, the rate scale per command
    old = Discrepancy.from_config({"flow": {"terms": {"u": 0.5}}}, pump_speed=183.26)
    assert old.corrections[0].settings == {"pump_speed": 183.26}


def test_discrepancy_is_computed_on_the_noise_free_twin() -> None:
    u = filtered_noise(4.0, (0.0, 4.0), seed=3)
    d = Discrepancy((SensorCorrection("torque", {"t": 0.5, "ω·|ω|": 0.01}, SETTINGS),
                     SensorCorrection("flow", {"max(0.5 V − u, 0)": -2.0}, SETTINGS)))
    model = GapModel(PlantParameters(), {}, d)
    plain = GapModel(PlantParameters(), {}).simulate(u, noise=True, seed=9)
    corrected = model.simulate(u, noise=True, seed=9)
    clean = simulate(u, noise=False)
    tt = clean.t - clean.t[0]
    expected = 0.5 * tt + 0.01 * clean["speed"] * np.abs(clean["speed"])
    np.testing.assert_allclose(corrected["torque"] - plain["torque"], expected, atol=1e-9)
    np.testing.assert_allclose(corrected["flow"] - plain["flow"], -2.0 * np.maximum(0.5 - u, 0.0), atol=1e-9)
    np.testing.assert_array_equal(corrected["speed"], plain["speed"])
    assert corrected.meta["discrepancy"]["torque"]["terms"] == {"t": 0.5, "ω·|ω|": 0.01}


def test_load_model_reads_flat_parameters_and_refuses_bad_files(tmp_path) -> None:
    flat = tmp_path / "flat.json"
    flat.write_text(json.dumps({"TL": 4.0}))
    model = load_model(flat)
    assert model.parameters.TL == 4.0 and model.effects == {} and model.discrepancy is None
    assert read_model(flat)[0].TL == 4.0
    with pytest.raises(ParameterError, match="model file must exist"):
        load_model(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    with pytest.raises(ParameterError, match="must hold a JSON object"):
        load_model(bad)
    saved = model_from_config({"schema": MODEL_SCHEMA, "parameters": PlantParameters().to_dict(), "effects": {},
                               "corrections": {"speed": {"terms": {"t": 0.01}, "library": SETTINGS}}})
    assert saved.discrepancy is not None and saved.discrepancy.corrections[0].sensor == "speed"


def test_saved_correction_reproduces_the_improved_held_out_fit(tmp_path) -> None:
    """A non-catalog torque term: gap names no catalog effect, saves the correction; simulate with the
    saved model (the recording's command replayed) then fits the held-out data as the report claims."""
    rec = heating_brake(15.0, rise=0.4, seed=3)
    data = write_recording(rec, tmp_path / "rig.parquet")
    report_path, model_path = tmp_path / "gap.json", tmp_path / "model.json"
    assert main(["gap", "--real", str(data), "--report", str(report_path), "--save-model", str(model_path),
                 "--effects", "quadratic_drag,sensor_lowpass"]) == 0
    report = json.loads(report_path.read_text())
    assert report["mismatch"] is True
    assert {e["id"] for e in report["effects"]} == {"unidentified"}  # never a catalog effect
    model = json.loads(model_path.read_text())
    corrected = set(model["corrections"])
    assert "torque" in corrected
    aligned = align(rec)

    def held_out_fit(path) -> dict[str, float]:
        out = tmp_path / path.stem
        assert main(["simulate", "--out", str(out), "--states", "healthy", "--command", str(data), "--nominal",
                     str(path), "--no-noise"]) == 0
        sim = read_recording(out / "healthy.mcap")
        return {s: nrmse(aligned.measured[i], sim[s], aligned.holdout_mask) for i, s in enumerate(SENSORS)}

    with_correction = held_out_fit(model_path)
    stripped = tmp_path / "stripped.json"
    stripped.write_text(json.dumps({k: v for k, v in model.items() if k != "corrections"}))
    without = held_out_fit(stripped)
    for s in SENSORS:
        # the simulator with the saved model reproduces the report's final fit ...
        assert with_correction[s] == pytest.approx(report["fit"]["after"][s], rel=0.02, abs=1e-4)
        # ... and without its correction the catalog model's (the calibrated one: nothing was named)
        assert without[s] == pytest.approx(report["fit"]["calibrated"][s], rel=0.05)
    gain = 1 - with_correction["torque"] / without["torque"]
    claimed = 1 - report["fit"]["after"]["torque"] / report["fit"]["calibrated"]["torque"]
    assert gain > 0.3 and gain == pytest.approx(claimed, abs=0.03)
