"""Greedy channel selection and its validation score, on scores and cycles whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.cycles.sparse import greedy_channels, validation_score
from hydrowatch.errors import ParameterError


def test_greedy_selection_adds_the_best_channel_each_step_and_breaks_ties_by_index() -> None:
    worth = {0: 0.1, 1: 0.5, 2: 0.3, 3: 0.5}
    steps = greedy_channels(lambda chs: sum(worth[c] for c in chs) - 0.2 * (2 in chs and 3 in chs), 4, 3)
    assert [chs for chs, _ in steps] == [(1,), (1, 3), (1, 3, 0)]  # (1, 3, 2) ties at 1.1 after its penalty: 0 wins
    assert [round(s, 6) for _, s in steps] == [0.5, 1.0, 1.1]
    with pytest.raises(ParameterError, match="size"):
        greedy_channels(lambda chs: 0.0, 4, 5)


def test_the_validation_score_rewards_the_channel_that_carries_the_condition() -> None:
    rng = np.random.default_rng(0)
    labels = np.tile(np.repeat([0.0, 1.0], 20), 5)  # blocks of 20 cycles, in recording order
    values = rng.normal(0.0, 1.0, (labels.size, 3, 12))
    values[:, 1, :] += 3.0 * labels[:, None]  # only channel 1 knows the condition
    scores = [validation_score(values, {"c": labels}, (c,)) for c in range(3)]
    assert scores[1] > 0.95 and max(scores[0], scores[2]) < 0.75
    both = validation_score(values, {"c": labels, "d": 1.0 - labels}, (1, 2))
    assert both > 0.9
    assert greedy_channels(lambda chs: validation_score(values, {"c": labels}, chs), 3, 1)[0][0] == (1,)


def test_the_validation_score_of_transients_reads_the_load_changes_of_the_reference() -> None:
    rng = np.random.default_rng(3)
    labels = np.tile(np.repeat([0.0, 1.0], 20), 4)
    step = np.zeros((labels.size, 20))
    step[:, 5:15] = 1.0
    pressure = 100.0 + 50.0 * step
    pressure[:, 5] -= 10.0 + 5.0 * labels  # the condition leaves more of the step unsettled
    flat = np.zeros_like(pressure)
    values = np.stack([pressure, flat], axis=1) + rng.normal(0.0, 0.3, (labels.size, 2, 20))
    nuisance = {"c": np.zeros((labels.size, 1))}
    assert validation_score(values, {"c": labels}, [0], "transients", reference=0, nuisance=nuisance) > 0.95
    # the flat channel alone knows nothing, though the reference still finds the load changes
    assert validation_score(values, {"c": labels}, [1], "transients", reference=0, nuisance=nuisance) < 0.75
