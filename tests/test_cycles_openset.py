"""Open set for cycles: a condition never trained on reads unknown, the known ones do not."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.cycles import ComponentClassifier, ordered_split
from hydrowatch.cycles.openset import UNKNOWN, OpenSetComponent
from hydrowatch.errors import NotFittedError, ParameterError


def _cycles(rng: np.random.Generator, levels: np.ndarray) -> np.ndarray:
    """Two channels of 12 samples: the condition sets channel 0's level and channel 1's slope."""
    t = np.arange(12.0)
    first = levels[:, None] + rng.normal(0.0, 1.0, (levels.size, 12))
    second = 0.1 * levels[:, None] * t / 11 + rng.normal(0.0, 1.0, (levels.size, 12))
    return np.stack([first, second], axis=1)


def test_a_condition_never_trained_on_reads_unknown_and_the_known_ones_do_not() -> None:
    rng = np.random.default_rng(0)
    labels = np.tile(np.repeat([0.0, 10.0, 20.0], 30), 3)
    values = _cycles(rng, labels)
    train, test = ordered_split(labels)
    model = OpenSetComponent(ComponentClassifier(phases=4)).fit(values[train], labels[train])
    assert model.thresholds_.shape == (3,) and np.all(model.thresholds_ > 0)
    known = model.predict(values[test])
    assert np.mean(known == labels[test]) > 0.97 and np.mean(known == UNKNOWN) < 0.03
    unseen = model.predict(_cycles(rng, np.full(50, 45.0)))
    assert np.mean(unseen == UNKNOWN) > 0.95
    assert np.all(model.novelty(values[test][known != UNKNOWN]) <= 1.0)
    assert not hasattr(model.classifier, "model_")  # the given classifier is copied, never fitted


def test_the_open_set_refuses_bad_settings_and_use_before_fit() -> None:
    values = _cycles(np.random.default_rng(1), np.repeat([0.0, 10.0], 10))
    with pytest.raises(NotFittedError):
        OpenSetComponent(ComponentClassifier()).predict(values)
    with pytest.raises(ParameterError, match="quantile"):
        OpenSetComponent(ComponentClassifier(phases=4), quantile=0.0).fit(values, np.repeat([0.0, 10.0], 10))
