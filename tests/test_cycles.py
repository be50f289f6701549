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


def _one_step_pressure(rng: np.random.Generator, share: np.ndarray, height: np.ndarray) -> np.ndarray:
    """One pressure at 150 bar with a load step of ``height`` bar down at sample 6 and back up at 14; a share
    ``share`` of each step is still unsettled in the sample that holds it. A second channel holds noise only."""
    n = len(share)
    pressure = np.full((n, 20), 150.0)
    pressure[:, 6:14] -= height[:, None]
    pressure[:, 6] += share * height
    pressure[:, 14] -= share * height
    return np.stack([pressure, rng.normal(0.0, 1.0, (n, 20))], axis=1) + rng.normal(0.0, 0.05, (n, 2, 20))


def test_shares_of_the_cycles_own_step_do_not_move_with_the_step_height() -> None:
    """``normalised``: the unsettled share of a step reads the same whatever the step's height (what an oil
    temperature or a load moves), where the plain value grows with it; a missing step stays finite."""
    rng = np.random.default_rng(4)
    share, height = np.full(60, 0.25), np.r_[np.full(30, 40.0), np.full(30, 44.0)]
    values = _one_step_pressure(rng, share, height)
    transients = LoadChangeTransients(reference=0, normalised=True).fit(values)
    np.testing.assert_array_equal(transients.steps_, [[0, 6], [0, 14]])  # the noise channel has no clear step
    x = transients.transform(values)
    plain, shares = x[:, : 2 * 2 * 3], x[:, 2 * 2 * 3 :].reshape(60, 2, 3)  # (channel, change, sample) then shares
    for change in range(2):
        np.testing.assert_allclose(shares[:, change, 1], 0.25, atol=0.01)  # the sample holding the change
        np.testing.assert_allclose(shares[:, change, 0], 1.0, atol=0.01)  # the sample before: the whole step
    unsettled = np.abs(plain[:, 1])  # channel 0, change at 6, its sample
    assert unsettled[30:].mean() / unsettled[:30].mean() == pytest.approx(1.1, rel=0.01)
    missing = values.copy()
    missing[0, 0, :] = 150.0  # a cycle where the load never changed
    missing_shares = transients.transform(missing)[0, 12:]
    assert np.all(np.isfinite(missing_shares)) and np.abs(missing_shares).max() < 0.1  # the step bounded, not 0
    back = LoadChangeTransients.from_state(transients.to_state())
    np.testing.assert_array_equal(back.transform(values), x)
    assert LoadChangeTransients(reference=0).fit(values).transform(values).shape == (60, 12)  # off by default
    with pytest.raises(ParameterError, match="clear_step"):
        LoadChangeTransients(reference=0, normalised=True, clear_step=0.0).fit(values)


def test_reduced_rank_decision_ignores_a_trailing_direction_that_a_new_condition_overturns() -> None:
    """Four ordered conditions along one channel; a second channel separates them pairwise by a small, precise
    offset that a new operating condition shifts. Plain LDA follows the offset, one discriminant does not;
    all ``n_classes - 1`` of them is plain LDA."""
    rng = np.random.default_rng(5)

    def cycles(labels: np.ndarray, shift: float) -> np.ndarray:
        n = len(labels)
        ordered = 4.0 * labels + rng.normal(0.0, 1.0, n)
        alternating = np.where(labels % 2 == 0, 0.1, -0.1) + shift + rng.normal(0.0, 0.05, n)
        return np.repeat(np.stack([ordered, alternating], axis=1)[:, :, None], 6, axis=2) + rng.normal(
            0.0, 0.01, (n, 2, 6))

    labels, later = np.repeat(np.arange(4.0), 100), np.repeat(np.arange(4.0), 50)
    values, shifted = cycles(labels, 0.0), cycles(later, -0.25)
    plain = ComponentClassifier(features="statistics", phases=1).fit(values, labels)
    one = ComponentClassifier(features="statistics", phases=1, discriminants=1).fit(values, labels)
    assert np.mean(plain.predict(shifted) == later) < 0.65
    assert np.mean(one.predict(shifted) == later) > 0.8
    np.testing.assert_allclose(one.predict_proba(shifted).sum(axis=1), 1.0)
    full = ComponentClassifier(features="statistics", phases=1, discriminants=3).fit(values, labels)
    np.testing.assert_array_equal(full.predict(shifted), plain.predict(shifted))
    np.testing.assert_allclose(full.predict_proba(shifted), plain.predict_proba(shifted), atol=1e-9)
    with pytest.raises(ParameterError, match="discriminants"):
        ComponentClassifier(discriminants=0).fit(values, labels)
