import numpy as np
import pytest

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.health.features import RelativeEntropyFeatures
from hydrowatch.health.plan import DataPlan, split_state
from hydrowatch.health.streaming import EntropyWindow, MachineWindow
from hydrowatch.health.synthetic import STUDY_STATES, synthetic_errors
from hydrowatch.health.windows import invalid_reasons, n_windows, sliding_windows, window_starts


def test_window_layout():
    assert n_windows(999, 1000, 1000) == 0
    assert n_windows(2500, 1000, 1000) == 2
    np.testing.assert_array_equal(window_starts(2500, 1000, 500), [0, 500, 1000, 1500])
    x = np.arange(10.0)
    np.testing.assert_array_equal(sliding_windows(x, 4, 3), [[0, 1, 2, 3], [3, 4, 5, 6], [6, 7, 8, 9]])
    assert sliding_windows(x, 20, 1).shape == (0, 20)
    with pytest.raises(ParameterError, match="hop must be an integer >= 1"):
        n_windows(10, 4, 0)


def test_invalid_reasons():
    w = np.array([[1.0, 2.0, 3.0], [1.0, np.nan, 3.0], [2.0, 2.0, 2.0]])
    r = invalid_reasons(w)
    assert r[0] is None and "1 NaN/inf" in r[1] and "constant" in r[2]


@pytest.fixture(scope="module")
def fitted():
    base = {s: synthetic_errors(s, 20_000, seed=i) for i, s in enumerate(STUDY_STATES[:3])}
    return {f"{d}-{hop}": RelativeEntropyFeatures(distribution=d, window=400, hop=hop).fit(base)
            for d, hop in (("gaussian", 400), ("gaussian", 150), ("gaussian", 530), ("mixture", 400))}, base


@pytest.mark.parametrize("key", ["gaussian-400", "gaussian-150", "gaussian-530", "mixture-400"])
def test_streaming_equals_batch_exactly(fitted, key):
    models, _ = fitted
    for features in [models[key]]:
        errors = synthetic_errors("load_alert", 2300, seed=7)
        errors[1250, 1] = np.nan  # one invalid window for speed
        batch = features.window_entropies(errors)
        machine = MachineWindow(features, keep=100)
        assert machine.last() is None and machine.since(0) == []
        rng = np.random.default_rng(0)
        i = 0
        while i < errors.shape[0]:  # uneven chunks, as messages arrive
            n = int(rng.integers(1, 180))
            machine.update(errors[i : i + n])
            i += n
        results = machine.since(0)
        assert len(results) == batch.shape[0] == machine.n_windows
        for k, r in enumerate(results):
            assert r.index == k and r.start == k * features.hop and r.stop == r.start + features.window
            np.testing.assert_array_equal(r.entropies, batch[k])  # bit for bit, NaN in the same places
        reasons = features.window_reasons(errors)
        assert [r.reason for r in results] == reasons
        assert any(r is not None and r.startswith("speed:") for r in reasons)
        assert machine.last() is not None and machine.last().index == len(results) - 1


def test_reading_changes_nothing_and_keep_bounds_history(fitted):
    models, _ = fitted
    features = models["gaussian-400"]
    window = EntropyWindow(features, "torque", keep=2)
    window.update(synthetic_errors("healthy", 1700, seed=3)[:, 2])
    assert window.n_windows == 4 and window.n_samples == 1700
    first = window.last()
    assert window.last() is first and window.since(0) == window.since(0)
    assert [r.index for r in window.since(0)] == [2, 3]
    assert first is not None and first.features.shape == (3,)
    with pytest.raises(DataError, match="1-D"):
        window.update(np.zeros((3, 2)))
    with pytest.raises(ParameterError, match="sensor must be one of"):
        EntropyWindow(features, "pressure")


def test_data_plan_defaults_and_split():
    plan = DataPlan()
    assert plan.samples_per_state == 250_000 and plan.classifier_samples == 200_000
    split = split_state(260_000)
    assert (split.reference, split.base, split.classifier) == (slice(0, 10_000), slice(10_000, 50_000),
                                                              slice(50_000, 250_000))
    overlapping = DataPlan(classifier_windows=10, window=1000, hop=500)
    assert overlapping.classifier_samples == 5500
    with pytest.raises(DataError, match="at least 250000 samples"):
        split_state(100_000)
    with pytest.raises(ParameterError, match="hop must be an integer >= 1"):
        DataPlan(hop=0)
