"""What the model expected a window's sensors to read (``…/expected``, ``expected_window`` v1): healthy windows read
as expected, a fault departs in its own sensor, the message round-trips, each method says its source (issue 16)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hydrowatch.errors import ParameterError
from hydrowatch.expected import block_means, expected_windows
from hydrowatch.health.plan import DataPlan
from hydrowatch.io.codec import decode_batch, encode_batch
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.schemas import EXPECTED_WINDOW, validate
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.messages import expected_batch
from hydrowatch.training.online import Chunk, OnlineScorer, WindowVerdict
from hydrowatch.training.options import TrainingSettings
from hydrowatch.training.trainer import train

STATES = ["healthy", "load_alert", "pump_leak_alert"]
COLUMNS = ("voltage", "flow", "speed", "torque")


def _bundle(method: str, tmp: Path, **settings: object) -> ModelBundle:
    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    grouped = {r.state: [r] for r in simulate_states(STATES, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    return train(grouped, TrainingSettings(method=method, plan=plan, **settings)).bundle  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def parity_bundle(tmp_path_factory: pytest.TempPathFactory) -> ModelBundle:
    return _bundle("parity", tmp_path_factory.mktemp("parity"))


@pytest.fixture(scope="module")
def judged(parity_bundle: ModelBundle) -> dict[str, list[WindowVerdict]]:
    """Each state streamed in 0.1 s chunks (20 s, another seed than training) through the scorer's driver."""
    scorer = OnlineScorer(parity_bundle, expected=True)
    out: dict[str, list[WindowVerdict]] = {s: [] for s in STATES}
    recordings = list(simulate_states(STATES, seconds=20, seed=5))
    for start in range(0, len(recordings[0]), 20):
        for item in scorer.update([Chunk(r.state, r.t[start:start + 20], {c: r[c][start:start + 20] for c in COLUMNS})
                                   for r in recordings]):
            out[item.machine].append(item)
    return out


def _gap(item: WindowVerdict, sensor: str) -> float:
    """RMS of measured − expected over the window's points, relative to the measured points' standard deviation."""
    assert item.expected is not None
    e = item.expected[sensor]
    return float(np.sqrt(np.mean((e.measured - e.expected) ** 2)) / np.std(e.measured))


def test_a_healthy_window_reads_as_the_parity_relations_expected(judged: dict[str, list[WindowVerdict]]) -> None:
    healthy = judged["healthy"]
    assert len(healthy) == 4  # 20 s of 5 s windows
    for item in healthy:
        assert item.expected is not None and set(item.expected) == {"flow", "speed", "torque"}
        assert {s: e.source for s, e in item.expected.items()} == {
            "flow": "valve relation", "speed": "motor relation", "torque": "load relation"}
        assert all(e.measured.shape == e.expected.shape == (50,) for e in item.expected.values())
        for sensor in ("flow", "speed", "torque"):
            assert _gap(item, sensor) < 0.1, sensor  # measured 0.01-0.05 (docstring of condition/predictions.py)


def test_a_fault_departs_from_the_expectation_in_its_own_sensor(judged: dict[str, list[WindowVerdict]]) -> None:
    for item in judged["load_alert"]:  # the load relation of a healthy unit asks far less torque
        assert _gap(item, "torque") > 3.0 and _gap(item, "flow") < 0.1
        assert np.mean(item.expected["torque"].measured) > 1.5 * np.mean(item.expected["torque"].expected)  # type: ignore[index]
    for item in judged["pump_leak_alert"]:  # a leaking pump delivers less flow than the valve relation expects
        assert _gap(item, "flow") > 1.0 and _gap(item, "torque") < 0.1
        assert np.mean(item.expected["flow"].measured) < np.mean(item.expected["flow"].expected)  # type: ignore[index]


def test_the_expected_window_message_round_trips(judged: dict[str, list[WindowVerdict]]) -> None:
    item = judged["load_alert"][-1]
    batch = expected_batch(item, "sha256:abc")
    assert batch is not None
    validate(batch, EXPECTED_WINDOW, require_metadata=True)
    wire = encode_batch(batch)
    assert len(wire) < 4000  # 3 sensors x 2 x 50 float32 points and the schema
    back = decode_batch(wire, EXPECTED_WINDOW).to_pylist()
    assert [r["sensor"] for r in back] == ["flow", "speed", "torque"]
    assert [r["unit"] for r in back] == ["L/min", "rad/s", "N·m"]
    for r in back:
        e = item.expected[r["sensor"]]  # type: ignore[index]
        assert r["window_start"] == item.start_s and r["window_end"] == item.end_s
        assert r["step"] == pytest.approx(0.1) and r["model_version"] == "sha256:abc" and r["source"] == e.source
        assert r["window_start"] + len(r["measured"]) * r["step"] == pytest.approx(r["window_end"])
        np.testing.assert_allclose(r["measured"], e.measured, rtol=1e-6)  # float32 on the wire
        np.testing.assert_allclose(r["expected"], e.expected, rtol=1e-6)


def test_no_message_without_expectations() -> None:
    from hydrowatch.verdict import INVALID, Verdict

    assert expected_batch(WindowVerdict("f/m", 0.0, 5.0, Verdict("healthy", 1.0)), "v") is None
    assert expected_batch(WindowVerdict("f/m", 0.0, 5.0, Verdict(INVALID, None, {}, "gap")), "v") is None


def test_the_scorer_asks_for_expectations_only_when_told(parity_bundle: ModelBundle) -> None:
    r = next(iter(simulate_states(["healthy"], seconds=6, seed=9)))
    chunk = Chunk("f/m", r.t, {c: r[c] for c in COLUMNS})
    assert [v.expected for v in OnlineScorer(parity_bundle).update([chunk])] == [None]
    assert OnlineScorer(parity_bundle, expected=True).update([chunk])[0].expected is not None


def test_the_entropy_method_expects_its_reference_models_one_step_predictions(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    bundle = _bundle("entropy", tmp_path_factory.mktemp("entropy"), reference="bj")
    r = next(iter(simulate_states(["healthy"], seconds=12, seed=5)))
    items = OnlineScorer(bundle, expected=True).update([Chunk("f/m", r.t, {c: r[c] for c in COLUMNS})])
    assert items and all(i.expected is not None for i in items)
    for item in items:
        assert {s: e.source for s, e in item.expected.items()} == {  # type: ignore[union-attr]
            s: "bj reference model" for s in ("flow", "speed", "torque")}
        # the window's measured points are the recording's own samples, averaged over 0.1 s
        first = int(round((item.start_s - r.t[0]) * 200))
        np.testing.assert_allclose(item.expected["speed"].measured,  # type: ignore[index]
                                   block_means(r["speed"][None, first:first + 1000])[0], rtol=1e-9)
        for sensor in ("flow", "speed", "torque"):
            assert _gap(item, sensor) < 0.1, sensor  # one step ahead of a healthy unit


def test_points_are_block_means_and_a_window_with_nan_leaves_its_sensor_out() -> None:
    x = np.arange(2 * 45, dtype=float).reshape(2, 45)
    np.testing.assert_array_equal(block_means(x, 20), [[9.5, 29.5], [54.5, 74.5]])
    y = x.copy()
    y[1, 3] = np.nan
    found = expected_windows({"flow": x}, {"flow": y}, {"flow": "valve relation"}, step=20)
    assert list(found[0]) == ["flow"] and found[1] == {}
    with pytest.raises(ParameterError, match="step must be an integer >= 1"):
        block_means(x, 0)
