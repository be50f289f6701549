"""Probabilities of the parity rule: a temperature floor at the relations' model error, and a prior
that lets ``healthy`` win the ties of windows that do not load a part (docs/command-invariance.md,
"Calibration")."""

from __future__ import annotations

import numpy as np
import pytest
from test_condition_accuracy import STATES, run

from hydrowatch.condition import ConditionModel
from hydrowatch.condition.model import ParityRule
from hydrowatch.errors import ParameterError
from hydrowatch.plant.excitation import duty_cycle, filtered_noise
from hydrowatch.plant.faults import state_parameters


@pytest.fixture(scope="module")
def healthy_last():
    """A model trained with ``healthy`` as the last state, and a healthy machine's duty-cycle windows."""
    order = (*STATES[1:], STATES[0])
    train = dict(zip(order, run([state_parameters(s) for s in order], filtered_noise(40, (0, 4), seed=7), 8)))
    healthy = run([state_parameters("healthy")], duty_cycle(120, (0, 4), seed=41), seed=43)[0]
    return ConditionModel().fit(train), healthy


def test_the_prior_gives_healthy_even_odds_against_all_faults():
    rule = ParityRule().fit(np.ones((2, 6)), ["healthy", "fault_b"], ["fault_a", "fault_b", "healthy"])
    np.testing.assert_allclose(np.exp(rule.log_prior()), [0.25, 0.25, 0.5])
    tie = rule.predict_proba(np.ones((1, 6)))  # every state explains the window exactly
    np.testing.assert_allclose(tie, [[0.25, 0.25, 0.5]])
    assert rule.temperature_ >= 0.1  # perfectly separated training windows: the floor
    uniform = ParityRule(healthy_prior=None).fit(np.ones((2, 6)), ["healthy", "fault_b"],
                                                 ["fault_a", "fault_b", "healthy"])
    np.testing.assert_allclose(uniform.predict_proba(np.ones((1, 6))), [[1 / 3] * 3])
    with pytest.raises(ParameterError, match="healthy_prior"):
        ParityRule(healthy_prior=1.0)
    with pytest.raises(ParameterError, match="min_temperature"):
        ParityRule(min_temperature=0.0)


def test_a_rule_saved_without_the_prior_loads_as_it_was():
    old = ParityRule.from_dict({"params": {"level_weight": 1.0}, "classes": ["healthy", "x"], "temperature": 0.02})
    assert old.healthy_prior is None and old.temperature_ == 0.02
    new = ParityRule.from_dict(ParityRule().fit(np.ones((1, 4)), ["x"], ["healthy", "x"]).to_dict())
    assert new.healthy_prior == 0.5 and new.temperature_ >= 0.1


def test_healthy_wins_unloaded_windows_whatever_the_order_of_states(healthy_last):
    model, windows = healthy_last
    assert model.decision_.classes_[-1] == "healthy"
    ratios = model.features_.transform_with_levels(windows)
    p = model.decision_.predict_proba(ratios)
    reads = model.decision_.classes_[p.argmax(axis=1)]
    # Measured: 24 windows, every one read healthy with p = 0.50: in this cycle the five faults explain
    # every window as well as healthy does (each is a tie). With a uniform prior all 24 went to the
    # first state in the list, a fault, with p(healthy) = 1/6.
    assert np.mean(reads == "healthy") >= 0.95
    assert p[:, -1].mean() >= 0.45
    uniform = ParityRule.from_dict({**model.decision_.to_dict(), "params": {"healthy_prior": None}})
    q = uniform.predict_proba(ratios)
    tied = np.isclose(q[:, -1], q.max(axis=1)) & (q[:, -1] < 0.5)
    assert tied.any()  # such windows exist in this duty cycle
    assert np.all(uniform.classes_[q[tied].argmax(axis=1)] != "healthy")
