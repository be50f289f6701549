import pickle

import numpy as np
import pytest

from hydrowatch.errors import DataError, NotFittedError
from hydrowatch.health.classifier import HealthClassifier, stratified_split
from hydrowatch.health.features import RelativeEntropyFeatures
from hydrowatch.health.metrics import accuracy, confusion_matrix, expected_calibration_error, per_class_recall
from hydrowatch.health.model import HealthModel
from hydrowatch.health.openset import OpenSetRule
from hydrowatch.health.synthetic import STUDY_STATES, synthetic_errors
from hydrowatch.health.verdict import judge
from hydrowatch.verdict import INVALID, UNKNOWN, Verdict, VerdictSmoother


@pytest.fixture(scope="module")
def model():
    base = {s: synthetic_errors(s, 20_000, seed=i) for i, s in enumerate(STUDY_STATES)}
    windows = {s: synthetic_errors(s, 200_000, seed=100 + i) for i, s in enumerate(STUDY_STATES)}
    return HealthModel().fit(base, windows)


def test_classifier_accuracy_confusion_and_calibration(model):
    r = model.report_
    assert r["windows"] == 1400 and r["states"] == list(STUDY_STATES)
    assert r["test_accuracy"] >= 0.99
    cm = np.array(r["confusion_matrix"])
    assert cm.shape == (7, 7) and cm.sum() == 7 * 30  # 15 % of 200 windows per state
    assert np.trace(cm) >= 0.99 * cm.sum() and np.all(cm.sum(axis=1) == 30)
    assert r["ece"] < 0.02
    clf = model.classifier_
    assert {k: v.size for k, v in clf.split_.items()} == {"train": 980, "validation": 210, "test": 210}
    assert 1 <= clf.best_epoch_ <= clf.n_epochs_ <= clf.max_epochs


def test_fresh_known_windows_and_open_set(model):
    known_pred, known_true = [], []
    for i, s in enumerate(STUDY_STATES):
        _, verdicts = model.score(synthetic_errors(s, 40_000, seed=500 + i))
        known_pred += [v.state for v in verdicts]
        known_true += [s] * len(verdicts)
    known_pred_arr = np.array(known_pred)
    assert accuracy(known_true, known_pred_arr) >= 0.99
    assert np.mean(known_pred_arr == UNKNOWN) <= 0.01  # the rule costs known states at most 1 point
    starts, verdicts = model.score(synthetic_errors("valve_leak", 100_000, seed=900))
    assert starts.tolist() == list(range(0, 100_000, 1000))
    unknown = np.mean([v.state == UNKNOWN for v in verdicts])
    assert unknown >= 0.90
    assert all(v.novelty is not None and v.novelty > 1.0 for v in verdicts if v.state == UNKNOWN)
    # without the open-set rule the unseen fault is forced into a known state
    forced = judge(model.features_.transform(synthetic_errors("valve_leak", 10_000, seed=901)), model.classifier_)
    assert all(v.state in STUDY_STATES for v in forced)


def test_invalid_windows_get_a_reason(model):
    errors = synthetic_errors("healthy", 3000, seed=11)
    errors[1500:1510, 2] = np.nan
    errors[2000:, 0] = 0.25  # stuck flow sensor in the third window
    _, verdicts = model.score(errors)
    assert verdicts[0].state == "healthy" and verdicts[0].probability is not None
    assert verdicts[1].state == INVALID and verdicts[1].reason.startswith("torque: 10 NaN")
    assert verdicts[2].state == INVALID and "constant" in verdicts[2].reason
    assert verdicts[1].to_dict() == {"state": INVALID, "probability": None, "probabilities": {},
                                     "reason": verdicts[1].reason}


def test_save_load_round_trip(model, tmp_path):
    model.save(tmp_path / "m")
    loaded = HealthModel.load(tmp_path / "m")
    errors = synthetic_errors("pump_leak_alert", 5000, seed=3)
    _, a = model.score(errors)
    _, b = loaded.score(errors)
    assert a == b
    X = model.features_.transform(errors)
    np.testing.assert_array_equal(model.classifier_.predict_proba(X), loaded.classifier_.predict_proba(X))
    assert loaded.classifier_.temperature_ == model.classifier_.temperature_
    np.testing.assert_array_equal(loaded.open_set_.thresholds_, model.open_set_.thresholds_)
    with pytest.raises(DataError, match="Missing"):
        HealthModel.load(tmp_path / "nothing")
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(DataError, match="classifier file"):
        HealthClassifier.load(tmp_path / "bad.npz")


def test_estimator_contract(model):
    for template in (HealthClassifier(hidden=7), RelativeEntropyFeatures(window=500), OpenSetRule(margin=2.0)):
        params = template.get_params()
        assert type(template)(**params).get_params() == params
    with pytest.raises(NotFittedError, match="HealthClassifier must be fitted"):
        HealthClassifier().predict(np.zeros((1, 21)))
    with pytest.raises(NotFittedError, match="RelativeEntropyFeatures must be fitted"):
        RelativeEntropyFeatures().transform(np.zeros((1000, 3)))
    with pytest.raises(NotFittedError, match="OpenSetRule must be fitted"):
        OpenSetRule().score(np.zeros((1, 21)))
    with pytest.raises(NotFittedError, match="HealthModel must be fitted"):
        HealthModel().score(np.zeros((1000, 3)))
    clf = pickle.loads(pickle.dumps(model.classifier_))
    X = model.features_.transform(synthetic_errors("healthy", 2000, seed=4))
    np.testing.assert_array_equal(clf.predict_proba(X), model.classifier_.predict_proba(X))
    assert model.classifier_.get_params() == HealthClassifier().get_params()  # fit did not change them
    with pytest.raises(DataError, match="must be finite"):
        HealthClassifier().fit(np.full((10, 2), np.nan), ["a"] * 10)


def test_log_transform_is_an_option_and_seeds_are_deterministic(model):
    X = model.features_.transform(synthetic_errors("load_warning", 4000, seed=8))
    rng = np.random.default_rng(0)
    Xs = np.abs(rng.normal(1.0, 0.3, (120, 4))) * np.repeat([[1, 1, 1, 1], [3, 3, 3, 3], [9, 9, 9, 9]], 40, axis=0)
    ys = np.repeat(["a", "b", "c"], 40)
    a = HealthClassifier(log_features=False, max_epochs=200, random_state=1).fit(Xs, ys)
    b = HealthClassifier(log_features=False, max_epochs=200, random_state=1).fit(Xs, ys)
    np.testing.assert_array_equal(a.W1_, b.W1_)
    assert a.test_accuracy_ >= 0.9
    assert not np.allclose(a.feature_mean_, HealthClassifier(max_epochs=5).fit(Xs, ys).feature_mean_)
    assert model.classifier_.predict(X).tolist() == ["load_warning"] * 4


def test_stratified_split_fractions():
    y = np.repeat(["a", "b"], 200)
    parts = stratified_split(y, (0.7, 0.15, 0.15), seed=3)
    assert [parts[k].size for k in ("train", "validation", "test")] == [280, 60, 60]
    assert np.unique(np.concatenate(list(parts.values()))).size == 400
    assert np.sum(y[parts["test"]] == "a") == 30


def test_verdict_smoother():
    probs = lambda a: {"healthy": a, "load_alert": 1 - a}  # noqa: E731
    smoother = VerdictSmoother(n_windows=3)
    assert smoother.get() is None
    smoother.update(Verdict("healthy", 0.9, probs(0.9)))
    smoother.update(Verdict(INVALID, None, {}, "gap"))
    smoother.update(Verdict("load_alert", 0.8, probs(0.2)))
    smoother.update(Verdict("healthy", 0.7, probs(0.7)))
    out = smoother.get()
    assert out is not None and out.state == "healthy" and out.probability == pytest.approx(0.6)
    assert smoother.get() == out  # reading changes nothing
    smoother.update(Verdict(UNKNOWN, None, probs(0.5)))
    smoother.update(Verdict(UNKNOWN, None, probs(0.5)))
    last = smoother.get()
    assert last is not None and last.state == UNKNOWN and last.probability == pytest.approx(2 / 3)
    assert last.probabilities["healthy"] == pytest.approx(0.7 / 3)


def test_metrics():
    t = ["a", "a", "b", "b", "c"]
    p = ["a", "b", "b", "b", UNKNOWN]
    assert accuracy(t, p) == pytest.approx(0.6)
    np.testing.assert_array_equal(confusion_matrix(t, p, ["a", "b", "c", UNKNOWN]),
                                  [[1, 1, 0, 0], [0, 2, 0, 0], [0, 0, 0, 1], [0, 0, 0, 0]])
    assert per_class_recall(t, p, ["a", "b", "c"]) == {"a": 0.5, "b": 1.0, "c": 0.0}
    proba = np.array([[0.9, 0.1], [0.6, 0.4], [0.3, 0.7]])
    # bins: 0.9 correct, 0.6 wrong, 0.7 correct -> (|1-0.9| + |0-0.6| + |1-0.7|) / 3
    assert expected_calibration_error(proba, np.array([0, 1, 1]), n_bins=10) == pytest.approx(1.0 / 3)
    with pytest.raises(DataError, match="same length"):
        accuracy(["a"], ["a", "b"])
