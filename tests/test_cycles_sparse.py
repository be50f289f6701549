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
