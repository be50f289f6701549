"""Sparse sensors: missing channels filled with each health state's own parameters keep its fault visible."""

from __future__ import annotations

import numpy as np
import pytest
from test_condition_model import windows_of

from hydrowatch.condition import ConditionFeatures, ConditionModel
from hydrowatch.condition.estimates import fill_faults
from hydrowatch.plant.excitation import duty_cycle, filtered_noise
from hydrowatch.plant.faults import STUDY_STATES


@pytest.fixture(scope="module")
def data():
    return (windows_of(STUDY_STATES, filtered_noise(40, (0, 4), seed=1), seed=2),
            windows_of(STUDY_STATES, duty_cycle(60, (0, 4), seed=3), seed=4))


def test_fills_use_only_the_parameters_they_need():
    assert fill_faults(("flow", "speed", "torque")) == ()
    assert fill_faults(("flow", "speed")) == ("load",)
    assert fill_faults(("speed", "torque")) == ("motor_leak",)
    assert fill_faults(("torque",)) == ("load", "motor_leak")


@pytest.mark.parametrize("sensors", [("flow", "speed"), ("speed", "torque"), ("speed",)])
def test_a_fault_behind_a_missing_sensor_is_still_seen(data, sensors):
    train, duty = data
    model = ConditionModel(features=ConditionFeatures(sensors=sensors)).fit(train)
    assert model.features_.relations_ == (("valve",) if len(sensors) == 1 else ("motor", "valve") if
                                          "torque" not in sensors else ("load", "valve"))
    assert not model.pools_open_set()  # pooling serves the decision only with a sensor missing
    truth = np.concatenate([[s] * len(w) for s, w in duty.items()])
    pred = np.concatenate([model.predict(w) for w in duty.values()])
    pooled = np.concatenate([model.predict(w, smoothing=12) for w in duty.values()])
    # Nominal fills (round 2) read 43 % (speed alone) and 71 % (two sensors) on the study's 7 states. These
    # windows carry no oil temperature, so the leak boxes allow ±5 K of it (condition/oil.py): per window
    # that costs speed alone 98.8 -> 82.1 % and speed + torque 100 -> 90.5 %; pooled (the default) nothing.
    assert np.mean(pred == truth) >= 0.8, sensors
    assert np.mean(pooled == truth) >= 0.95, sensors
