"""Per-cycle features, honest splits, load-change transients, nuisance projection and the component
classifier, on synthetic cycles whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.cycles import (
    ComponentClassifier,
    LoadChangeTransients,
    NuisanceProjection,
    cycle_statistics,
    load_changes,
    ordered_split,
    random_folds,
    statistic_names,
)
from hydrowatch.errors import NotFittedError, ParameterError


def test_cycle_statistics_are_mean_spread_extremes_slope_and_phase_means() -> None:
    ramp = np.arange(6.0)  # 0..5 at 2 Hz: slope 2 per second
    values = np.stack([ramp, np.full(6, 3.0)])[None]  # one cycle, two channels
    x = cycle_statistics(values, grid_hz=2.0, phases=3)
    assert x.shape == (1, 2 * 8)
    np.testing.assert_allclose(x[0, :8], [2.5, np.std(ramp), 0.0, 5.0, 2.0, 0.5, 2.5, 4.5])
    np.testing.assert_allclose(x[0, 8:], [3.0, 0.0, 3.0, 3.0, 0.0, 3.0, 3.0, 3.0])
    assert statistic_names(["P", "T"], phases=3)[4:6] == ["P.slope", "P.phase1"] and len(statistic_names(["P"], 3)) == 8
    with pytest.raises(ParameterError, match="phases must divide the 6 samples"):
        cycle_statistics(values, 2.0, phases=4)
    with pytest.raises(ParameterError, match=r"shape \(cycles, channels, samples\)"):
        cycle_statistics(values[0], 2.0)


def test_the_honest_split_trains_on_each_classs_first_cycles() -> None:
    labels = np.array([0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0])  # class 0: 16 cycles, 1: 4
    train, test = ordered_split(labels, 0.7)
    assert list(test[labels[test] == 0]) == [15, 16, 17, 18, 19] and list(test[labels[test] == 1]) == [12, 13]
    assert len(np.intersect1d(train, test)) == 0 and len(train) + len(test) == 20
    assert all(train[labels[train] == v].max() < test[labels[test] == v].min() for v in (0, 1))
    with pytest.raises(ParameterError, match="at least 2 cycles"):
        ordered_split(np.array([0, 0, 1]))
    with pytest.raises(ParameterError, match="train_fraction"):
        ordered_split(labels, 1.0)


def test_random_folds_test_every_cycle_once() -> None:
    folds = list(random_folds(23, 5, seed=1))
    tested = np.concatenate([test for _, test in folds])
    assert len(folds) == 5 and sorted(tested) == list(range(23))
    assert all(len(np.intersect1d(train, test)) == 0 and len(train) + len(test) == 23 for train, test in folds)
    with pytest.raises(ParameterError, match="folds"):
        next(random_folds(3, 5))


def test_load_changes_are_found_once_each_and_transients_measure_the_unsettled_share() -> None:
    profile = np.array([0.0, 0.0, 10.0, 20.0, 20.0, 20.0, 5.0, 5.0])
    np.testing.assert_array_equal(load_changes(profile, 3.0), [2, 6])  # 2 and 3 are one change
    with pytest.raises(ParameterError, match="threshold"):
        load_changes(profile, 0.0)
    rng = np.random.default_rng(0)
    values = _two_pressures(rng, np.full(40, 0.2), np.zeros(40))
    transients = LoadChangeTransients(reference=0, before=1, after=2, settle=(2, 4), channels=[0]).fit(values)
    np.testing.assert_array_equal(transients.changes_, [5, 15])
    x = transients.transform(values)
    assert x.shape == (40, 2 * 3)
    np.testing.assert_allclose(x.mean(axis=0), [-50.0, -10.0, 0.0, 50.0, 10.0, 0.0], atol=0.3)
    with pytest.raises(NotFittedError):
        LoadChangeTransients().transform(values)
    with pytest.raises(ParameterError, match="no such change"):
        LoadChangeTransients(reference=1, threshold=100.0).fit(values)
    with pytest.raises(ParameterError, match="channels must be indices"):
        LoadChangeTransients(channels=[2]).fit(values)
    np.testing.assert_array_equal(LoadChangeTransients(reference=1).fit(values).transform(values).shape, (40, 12))


def test_the_nuisance_projection_removes_what_another_component_moves() -> None:
    rng = np.random.default_rng(1)
    labels = np.repeat([0, 1], 200)
    nuisance = rng.integers(0, 2, 400).astype(float)
    features = np.stack(
        [
            labels + rng.normal(0, 0.3, 400),
            5 * nuisance + rng.normal(0, 0.3, 400),
            labels + 5 * nuisance + rng.normal(0, 0.3, 400),
        ],
        axis=1,
    )
    z = NuisanceProjection(directions=1).fit(features, labels, nuisance[:, None]).transform(features)
    for value in (0, 1):
        members = labels == value
        shift = z[members & (nuisance == 1)].mean(axis=0) - z[members & (nuisance == 0)].mean(axis=0)
        assert np.abs(shift).max() < 0.1  # nuisance gone
    assert z[labels == 1, 0].mean() - z[labels == 0, 0].mean() > 1.0  # the class signal stays
    kept = NuisanceProjection(directions=0).fit(features, labels, nuisance[:, None]).transform(features)
    np.testing.assert_allclose(kept, (features - features.mean(0)) / features.std(0))
    with pytest.raises(NotFittedError):
        NuisanceProjection().transform(features)
    with pytest.raises(ParameterError, match="min_group"):
        NuisanceProjection(directions=1, min_group=1000).fit(features, labels, nuisance[:, None])


def _two_pressures(rng: np.random.Generator, tau: np.ndarray, nuisance: np.ndarray) -> np.ndarray:
    """Two pressures with a load step at sample 5 and back at 15. The judged component leaves a share
    ``tau`` of the first one's step unsettled in the step's first sample; another component's
    condition (``nuisance``) moves both pressures' levels and transients."""
    step = np.zeros((len(tau), 20))
    step[:, 5:15] = 1.0
    a, b = 100.0 + 50.0 * step, 80.0 + 30.0 * step
    unsettled_a, unsettled_b = 50.0 * tau + 8.0 * nuisance, 6.0 + 8.0 * nuisance
    a[:, 5] -= unsettled_a
    a[:, 15] += unsettled_a
    b[:, 5] -= unsettled_b
    b[:, 15] += unsettled_b
    a += 20.0 * nuisance[:, None]
    b += 10.0 * nuisance[:, None]
    return np.stack([a, b], axis=1) + rng.normal(0.0, 0.3, (len(tau), 2, 20))


def test_the_classifier_judges_later_cycles_under_another_components_new_condition() -> None:
    """The accumulator's situation in miniature: class 0 is trained only without the nuisance and tested
    only with it (recording order: class 0, class 1 with and without, then both with)."""
    rng = np.random.default_rng(2)
    labels = np.r_[np.zeros(200), np.ones(200), np.zeros(90), np.ones(90)]
    nuisance = np.r_[np.zeros(200), np.arange(200) % 2, np.ones(180)]
    values = _two_pressures(rng, np.where(labels == 1, 0.3, 0.2) + rng.normal(0.0, 0.02, labels.size), nuisance)
    train, test = ordered_split(labels)
    assert nuisance[test].min() == 1.0 and nuisance[train][labels[train] == 0].mean() < 0.05
    other = nuisance[:, None]
    for features in ("statistics", "transients"):
        model = ComponentClassifier(features=features, phases=4).fit(values[train], labels[train], other[train])
        assert np.mean(model.predict(values[test]) == labels[test]) > 0.95, features
        probabilities = model.predict_proba(values[test])
        assert probabilities.shape == (len(test), 2) and np.allclose(probabilities.sum(axis=1), 1.0)
    assert model.directions_ in model.validation_ and set(model.validation_) == {0, 1, 2, 3, 4, 6, 8, 10}
    assert max(model.validation_.values()) == model.validation_[model.directions_]
    fixed = ComponentClassifier(features="transients", directions=1).fit(values[train], labels[train], other[train])
    assert fixed.directions_ == 1 and not hasattr(fixed, "validation_")
    with pytest.raises(NotFittedError):
        ComponentClassifier().predict(values)
    with pytest.raises(ParameterError, match="features must be one of"):
        ComponentClassifier(features="wavelets").fit(values, labels)
