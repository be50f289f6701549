"""Condition model: trained on the identification command, right on a working duty cycle."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.condition import ConditionFeatures, ConditionModel, windows_from_recording
from hydrowatch.errors import DataError, NotFittedError
from hydrowatch.plant import PlantSimulator, simulate
from hydrowatch.plant.excitation import duty_cycle, filtered_noise
from hydrowatch.plant.faults import STUDY_STATES, state_parameters

CHANNELS = ("voltage", "flow", "speed", "torque")


def windows_of(states, command: np.ndarray, seed: int) -> dict[str, np.ndarray]:
    """Raw 4-channel windows of one simulated machine per state, all under one command (shared by tests)."""
    sim = PlantSimulator([state_parameters(s) for s in states], seed=seed)
    sim.settle(float(command[0]))
    out = sim.step(command)
    n = command.size // 1000 * 1000
    return {s: np.stack([out[c][i, :n].reshape(-1, 1000) for c in CHANNELS], axis=-1) for i, s in enumerate(states)}


@pytest.fixture(scope="module")
def model_and_data():
    train = windows_of(STUDY_STATES, filtered_noise(60, (0, 4), seed=1), seed=2)
    duty = windows_of(STUDY_STATES, duty_cycle(80, (0, 4), seed=3), seed=4)
    unseen = windows_of(("valve_coil_alert", "relief_spring_alert"), filtered_noise(30, (0, 4), seed=5), seed=6)
    return ConditionModel().fit(train), train, duty, unseen


def test_verdicts_hold_on_a_duty_cycle(model_and_data):
    model, _, duty, _ = model_and_data
    truth = np.concatenate([[s] * len(w) for s, w in duty.items()])
    pred = np.concatenate([model.predict(w) for w in duty.values()])
    assert np.mean(pred == truth) >= 0.92  # this short cycle 94.6 % (87.5 % before the level box); study ~30 %


def test_level_box_tells_look_alike_valve_faults_apart_in_a_hold():
    states = ("healthy", "valve_coil_warning", "relief_spring_warning", "valve_leak_warning", "pump_leak_warning")
    train = windows_of(states, filtered_noise(40, (0, 4), seed=7), seed=8)
    holds = np.concatenate([np.full(2000, v) for v in (0.8, 1.4, 2.8, 3.3)])
    test = windows_of(states, holds, seed=9)  # windows 1, 3, 5, 7: pure 5 s holds after each step
    banded = ConditionModel(features=ConditionFeatures(level_weight=0.0)).fit(train)
    levelled = ConditionModel().fit(train)
    acc = {name: np.mean(np.concatenate([m.predict(w[1::2]) == s for s, w in test.items()]))
           for name, m in (("band", banded), ("level", levelled))}
    assert acc["level"] == 1.0 and acc["band"] < 0.9  # band boxes of the look-alikes tie in a hold


def test_unseen_faults_read_unknown(model_and_data):
    model, train, _, unseen = model_and_data
    assert np.mean(np.concatenate([model.predict(w) for w in unseen.values()]) == "unknown") >= 0.9
    known = np.concatenate([model.predict(w[-4:]) for w in train.values()])
    assert np.mean(known == "unknown") == 0.0


def test_features_have_the_relative_entropy_layout(model_and_data):
    model, train, _, _ = model_and_data
    f = model.features_
    X = f.transform(train["load_alert"][:3])
    assert X.shape == (3, len(f.relations_) * len(STUDY_STATES))
    own = X.reshape(3, len(f.relations_), -1)[:, :, STUDY_STATES.index("load_alert")]
    assert np.all(own < 1.5) and np.all(X >= 1.0 - 1e-12)  # a window's own state explains it


def test_invalid_windows_get_a_reason_and_nan_features(model_and_data):
    model, train, _, _ = model_and_data
    w = train["healthy"][:3].copy()
    w[0, 10:20, 1] = np.nan
    w[1, :, 3] = 5.0
    reasons = model.features_.window_reasons(w)
    assert reasons[0].startswith("flow") and "stuck" in reasons[1] and reasons[2] is None
    assert np.isnan(model.features_.transform(w)[:2]).all()
    assert [v.state for v in model.judge(w)][:2] == ["invalid", "invalid"]


def test_save_load_round_trip(model_and_data, tmp_path):
    model, _, duty, _ = model_and_data
    model.save(tmp_path / "m")
    again = ConditionModel.load(tmp_path / "m")
    w = duty["pump_leak_alert"][:5]
    np.testing.assert_array_equal(again.predict(w), model.predict(w))
    assert again.features_.get_params() == model.features_.get_params()


def test_windows_from_recording_and_errors():
    rec = simulate(filtered_noise(10, (0, 4), seed=1), seed=2)
    w = windows_from_recording(rec, 1000, 500)
    assert w.shape == (3, 1000, 5)  # the simulator records the oil temperature
    np.testing.assert_array_equal(w[1, :, 2], rec["speed"][500:1500])
    np.testing.assert_array_equal(w[:, :, 4], 40.0)
    assert windows_from_recording(rec, 1000, 500, temperature=False).shape == (3, 1000, 4)
    with pytest.raises(NotFittedError):
        ConditionFeatures().transform(w)
    with pytest.raises(DataError, match="healthy"):
        ConditionFeatures().fit({"load_alert": w})
    with pytest.raises(DataError, match="shape"):
        ConditionFeatures().fit({"healthy": w[:, :, :3]})
    with pytest.raises(DataError, match="temperature"):
        windows_from_recording(rec.__class__(rec.t, {c: rec[c] for c in CHANNELS}), 1000, 500, temperature=True)
