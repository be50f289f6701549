"""A fitted cycle classifier without pickle: the arrays of scikit-learn's LDA predict as it does, a classifier goes
through JSON and back predicting bit for bit the same, a cycles bundle is JSON and TOML only, and a bundle of the
old pickle format is refused with what to do."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
from sklearn.ensemble import ExtraTreesClassifier
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from test_rig_cycles_method import RIG, write_rig_folder

from hydrowatch.cycles import ComponentClassifier
from hydrowatch.cycles.linear import LinearDiscriminant
from hydrowatch.cycles.openset import OpenSetComponent
from hydrowatch.cycles.state import from_json_tree, to_json_tree
from hydrowatch.cycles.trees import CoveredVote, TreeForest
from hydrowatch.errors import DataError, ParameterError
from hydrowatch.io.rig_cycles import read_rig_data
from hydrowatch.methods.cycles import CyclesMethod
from hydrowatch.rig import load_rig
from hydrowatch.training import load_bundle
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.options import TrainingSettings


@pytest.fixture(scope="module")
def rig_cycles(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    root = tmp_path_factory.mktemp("state")
    (root / "rig.toml").write_text(RIG, encoding="utf-8")
    write_rig_folder(root / "train", np.tile([100.0, 100.0, 80.0, 60.0], 30), np.tile([0.0, 1.0, 1.0], 40), seed=4)
    rig = load_rig(root / "rig.toml")
    return root, read_rig_data(root / "train", rig)


@pytest.mark.parametrize("classes", [2, 3])
@pytest.mark.parametrize("scaled", [False, True])
def test_the_arrays_of_an_lda_predict_as_scikit_learn_does(classes: int, scaled: bool) -> None:
    rng = np.random.default_rng(classes)
    y = np.repeat(np.array(["a", "b", "c"][:classes]), 40)
    x = rng.normal(0, 1, (y.size, 5)) * [1, 10, 0.1, 1, 3] + (y[:, None] == "b") * [1, 0, 0.2, 0, 0] + (
        y[:, None] == "c") * [0, 5, 0, 1, 0]
    model = make_pipeline(StandardScaler(), LinearDiscriminantAnalysis()) if scaled else LinearDiscriminantAnalysis()
    model.fit(x, y)
    ours = LinearDiscriminant.from_fitted(model)
    test = rng.normal(0, 2, (50, 5))
    np.testing.assert_array_equal(ours.predict(test), model.predict(test))
    np.testing.assert_allclose(ours.predict_proba(test), model.predict_proba(test), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ours.transform(test), model.transform(test), rtol=1e-12, atol=1e-12)
    assert ours.transform(test).shape == (50, classes - 1)


@pytest.mark.parametrize("features", ["statistics", "transients", "entropy"])
def test_a_fitted_open_set_classifier_goes_through_json_unchanged(rig_cycles: tuple[Path, object],
                                                                  features: str) -> None:
    _, cycles = rig_cycles
    values, valve = cycles.values, np.array([f"{v:g}" for v in cycles.labels["valve"]])  # type: ignore[attr-defined]
    nuisance = cycles.labels["pump"][:, None]  # type: ignore[attr-defined]
    chosen = {"statistics": {"phases": 5}, "transients": {"channels": [0]}, "entropy": {"healthy": "100"}}[features]
    fitted = OpenSetComponent(ComponentClassifier(features=features, **chosen)).fit(values, valve, nuisance)
    text = json.dumps(to_json_tree(fitted.to_state()))
    back = OpenSetComponent.from_state(from_json_tree(json.loads(text), "test"))
    np.testing.assert_array_equal(back.predict(values), fitted.predict(values))
    np.testing.assert_array_equal(back.classifier_.predict_proba(values), fitted.classifier_.predict_proba(values))
    np.testing.assert_array_equal(back.novelty(values), fitted.novelty(values))
    assert back.classifier_.classes_.tolist() == ["100", "60", "80"]
    if features == "transients":
        assert back.classifier_.transients_ is not None and back.classifier_.transients_.changes_.tolist() == [5, 12]
    if features == "entropy":
        assert back.classifier_.entropy_ is not None and back.classifier.healthy == "100"
    assert back.classifier.features == features and back.classifier_.directions_ == fitted.classifier_.directions_


def test_step_shares_and_reduced_rank_go_through_json_and_a_state_from_before_them_loads_as_plain(
        rig_cycles: tuple[Path, object]) -> None:
    _, cycles = rig_cycles
    values, valve = cycles.values, np.array([f"{v:g}" for v in cycles.labels["valve"]])  # type: ignore[attr-defined]
    nuisance = cycles.labels["pump"][:, None]  # type: ignore[attr-defined]
    values = values.copy()
    values[:, 0, 5:12] += 30.0 - 0.3 * cycles.labels["valve"][:, None]  # type: ignore[attr-defined]  # every step 30 bar
    values[:, 0, 6] -= 3.0 * (valve == "80")  # valve 80: a tenth still unsettled 1 s on
    shares = OpenSetComponent(ComponentClassifier(features="transients", channels=[0], normalised=True,
                                                  discriminants=1)).fit(values, valve, nuisance)
    back = OpenSetComponent.from_state(from_json_tree(json.loads(json.dumps(to_json_tree(shares.to_state()))), "t"))
    assert back.classifier.normalised and back.classifier_.discriminants == 1
    assert back.classifier_.transients_ is not None and back.classifier_.transients_.steps_.shape == (2, 2)
    np.testing.assert_array_equal(back.classifier_.predict_proba(values), shares.classifier_.predict_proba(values))
    np.testing.assert_array_equal(back.predict(values), shares.predict(values))
    plain = OpenSetComponent(ComponentClassifier(features="transients", channels=[0])).fit(values, valve, nuisance)
    old = to_json_tree(plain.to_state())  # what a bundle saved before the two options holds
    for parameters in (old["classifier"], old["classifier_"]["parameters"]):
        del parameters["normalised"], parameters["discriminants"]
        del parameters["trees"], parameters["tree_weight"], parameters["coverage"]  # format 2 lacked these too
    del old["classifier_"]["priors_"], old["classifier_"]["vote_"]
    for key in ("normalised", "clear_step", "steps_", "typical_steps_"):
        del old["classifier_"]["transients_"][key]
    loaded = OpenSetComponent.from_state(from_json_tree(json.loads(json.dumps(old)), "old"))
    assert not loaded.classifier_.normalised and loaded.classifier_.discriminants is None
    assert loaded.classifier_.trees == 0 and loaded.classifier_.vote_ is None
    np.testing.assert_array_equal(loaded.classifier_.predict_proba(values), plain.classifier_.predict_proba(values))


def test_the_arrays_of_a_forest_predict_as_scikit_learn_does_and_vote_only_where_covered() -> None:
    rng = np.random.default_rng(7)
    level = np.repeat([0.0, 1.0], 60)  # another component's level: 0 and 1
    state = np.where(level == 0, np.tile(["a", "b"], 60), "a")  # at level 1 the training shows state a only
    x = rng.normal(0, 1, (120, 4)) + np.column_stack([10 * level, (state == "b") * 2.0, np.zeros(120), level])
    forest = ExtraTreesClassifier(n_estimators=15, random_state=0, n_jobs=1).fit(x, state)
    test = rng.normal(0, 1, (40, 4)) + np.column_stack([10 * np.repeat([0.0, 1.0], 20), np.zeros((40, 3))])
    np.testing.assert_allclose(TreeForest.from_fitted(forest).predict_proba(test), forest.predict_proba(test),
                               atol=1e-6)
    vote = CoveredVote.fit(x, state, level[:, None], trees=15, weight=1.25, coverage=10)
    assert vote.covered[0].tolist() == [True, False]  # level 1 lacks state b
    covered = vote.covered_cycles(test)
    assert covered[:20].all() and not covered[20:].any()
    linear = np.tile([0.9, 0.1], (40, 1))
    voted = vote.combine(linear, test)
    np.testing.assert_array_equal(voted[20:], linear[20:])  # not covered: the linear decision alone
    np.testing.assert_allclose(voted[:20], (linear[:20] + 1.25 * vote.forest.predict_proba(test[:20])) / 2.25)
    back = CoveredVote.from_state(from_json_tree(json.loads(json.dumps(to_json_tree(vote.to_state()))), "t"))
    np.testing.assert_array_equal(back.combine(linear, test), voted)


def test_a_classifier_with_the_trees_vote_goes_through_json_unchanged(rig_cycles: tuple[Path, object]) -> None:
    _, cycles = rig_cycles
    values, valve = cycles.values, np.array([f"{v:g}" for v in cycles.labels["valve"]])  # type: ignore[attr-defined]
    nuisance = cycles.labels["pump"][:, None]  # type: ignore[attr-defined]
    fitted = ComponentClassifier(features="statistics", phases=5, trees=10, tree_weight=1.25).fit(
        values, valve, nuisance)
    assert fitted.vote_ is not None and fitted.vote_.covered[0].all()  # every pump level has every valve state
    back = ComponentClassifier.from_state(from_json_tree(json.loads(json.dumps(to_json_tree(fitted.to_state()))), "t"))
    np.testing.assert_array_equal(back.predict_proba(values), fitted.predict_proba(values))
    assert back.trees == 10 and back.tree_weight == 1.25 and back.coverage == 10


def test_a_cycles_bundle_holds_no_pickle_and_loads_what_it_saved(rig_cycles: tuple[Path, object]) -> None:
    root, cycles = rig_cycles
    rig = load_rig(root / "rig.toml")
    fitted = CyclesMethod.fit_cycles(RIG, rig, cycles, TrainingSettings(method="cycles"))  # type: ignore[arg-type]
    bundle = ModelBundle(fitted.method, fitted.manifest)
    bundle.save(root / "a")
    bundle.save(root / "b")
    files = sorted(p.name for p in (root / "a" / "cycles").iterdir())
    assert files == ["model.json", "rig.toml"]
    stored = json.loads((root / "a" / "cycles" / "model.json").read_text())
    assert stored["format"] == 3 and set(stored["models"]) == {"valve", "pump"}
    loaded = load_bundle(root / "a")
    assert loaded.version == load_bundle(root / "b").version == bundle.version  # the same bytes each save
    values = cycles.values  # type: ignore[attr-defined]
    before, after = fitted.method.judge_cycles(values), loaded.health_method.judge_cycles(values)  # type: ignore
    assert before == after


def test_an_old_pickled_or_broken_cycles_bundle_is_refused_clearly(rig_cycles: tuple[Path, object]) -> None:
    root, _ = rig_cycles
    if not (root / "a" / "manifest.json").is_file():
        pytest.skip("needs the bundle of test_a_cycles_bundle_holds_no_pickle_and_loads_what_it_saved")
    old = root / "old"
    (old / "cycles").mkdir(parents=True)
    (old / "manifest.json").write_text((root / "a" / "manifest.json").read_text())
    (old / "cycles" / "rig.toml").write_text(RIG)
    (old / "cycles" / "model.pkl").write_bytes(pickle.dumps({"models": {}, "features": {}}))
    with pytest.raises(DataError, match=r"stores its classifiers as a pickle \(model.pkl.*Train it again with "
                                        r"`hydrowatch train --rig tiny-cycles"):
        load_bundle(old)
    stored = json.loads((root / "a" / "cycles" / "model.json").read_text())
    (old / "cycles" / "model.json").write_text(json.dumps({**stored, "format": 4}))
    with pytest.raises(DataError, match=r"model.json must be of format 1, 2 or 3. Got 4"):
        load_bundle(old)
    stored["models"]["valve"]["thresholds_"]["__array__"]["data"] = "not base64!"
    (old / "cycles" / "model.json").write_text(json.dumps(stored))
    with pytest.raises(DataError, match=r"models.valve.thresholds_ must be an array of dtype, shape and base64"):
        load_bundle(old)
    with pytest.raises(ParameterError, match="stored without pickle. Got dtype object"):
        to_json_tree({"x": np.array([None, 1])})
