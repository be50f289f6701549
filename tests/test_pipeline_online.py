"""Streaming scoring: batch/stream parity, gaps and NaN as invalid windows, the scorer service over loopback."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hydrowatch.health.plan import DataPlan
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.training.online import Chunk, OnlineScorer
from hydrowatch.training.options import TrainingSettings
from hydrowatch.training.reference import SensorReference
from hydrowatch.training.scoring import score_recording
from hydrowatch.training.trainer import train

STATES = ["healthy", "load_alert", "pump_leak_alert"]
PLAN = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=500)
COLUMNS = ("voltage", "flow", "speed", "torque")


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    seconds = PLAN.samples_per_state / 200 + 1
    grouped = {r.state: [r] for r in simulate_states(STATES, seconds=seconds, seed=0)}
    result = train(grouped, TrainingSettings(method="entropy", reference="bj", plan=PLAN))
    return result.bundle.save(tmp_path_factory.mktemp("bundle") / "model")


@pytest.fixture(scope="module")
def test_recordings() -> list:
    return list(simulate_states(STATES, seconds=20, seed=5))


def chunks(recording, machine: str, start: int, stop: int) -> Chunk:
    return Chunk(machine, recording.t[start:stop], {c: recording[c][start:stop] for c in COLUMNS})


def test_stream_matches_batch_whatever_the_chunks(bundle_dir: Path, test_recordings: list) -> None:
    from hydrowatch.training.bundle import ModelBundle

    bundle = ModelBundle.load(bundle_dir)
    scorer = OnlineScorer(bundle)
    verdicts = []
    n = len(test_recordings[0])
    sizes = [7, 20, 33]
    for k, start in enumerate(range(0, n, 20)):  # machines get chunks of different lengths in one update
        batch = []
        for i, r in enumerate(test_recordings):
            size = sizes[(i + k) % 3]
            stop = min(n, start + size) if i == 0 else min(n, start + 20)
            batch.append(chunks(r, r.state, start, stop) if i else chunks(r, r.state, start, start + 20))
        verdicts += scorer.update(batch)
    for r in test_recordings:
        offline = score_recording(bundle, r)["windows"]
        online = [v for v in verdicts if v.machine == r.state]
        assert len(online) == len(offline) >= 6
        for a, b in zip(online, offline):
            assert a.start_s == pytest.approx(b["start_s"])
            assert a.verdict.state == b["state"]
            assert a.verdict.probabilities == pytest.approx(b["probabilities"])
        assert sum(v.verdict.state == r.state for v in online) >= len(online) - 1


def test_narx_stream_step_equals_predict(test_recordings: list) -> None:
    r = test_recordings[0]
    ref = SensorReference(kind="narx", sensor="speed",
                          params={"input_delays": 3, "output_delays": 2, "hidden": 4, "max_iter": 3}).fit(
        r["voltage"][:1500], r["speed"][:1500])
    expected = r["speed"] - ref.model_.predict(r["voltage"], r["speed"])
    state, parts = [ref.initial_state()], []
    for i in range(0, len(r), 37):
        e, state = ref.step(r["voltage"][None, i:i + 37], r["speed"][None, i:i + 37], state)
        parts.append(e[0])
    got = np.concatenate(parts)
    assert np.isnan(got[:3]).all() and np.isfinite(got[3:]).all()
    np.testing.assert_allclose(got[3:], expected[3:], rtol=0, atol=1e-9)


def test_gap_nan_and_out_of_order_invalidate_the_window(bundle_dir: Path, test_recordings: list) -> None:
    from hydrowatch.training.bundle import ModelBundle

    scorer = OnlineScorer(ModelBundle.load(bundle_dir))
    r = test_recordings[0]
    speed = r["speed"].copy()
    speed[1550] = np.nan
    out = []
    for start in range(0, 3000, 100):
        if start == 700:
            continue  # a lost chunk: 0.5 s gap
        c = chunks(r, "m", start, start + 100)
        c.channels["speed"] = speed[start:start + 100]
        out += scorer.update([c])
    out += scorer.update([chunks(r, "m", 1000, 1100)])  # late: the past again
    reasons = [v.verdict.reason for v in out if v.verdict.state == "invalid"]
    assert any(x.startswith("gap of 0.500 s") for x in reasons)
    assert any(x == "NaN in speed at t=7.750 s" for x in reasons)
    assert any(x.startswith("late or out-of-order chunk") for x in reasons)
    valid = [v for v in out if v.verdict.state != "invalid"]
    assert valid and all(v.verdict.state == "healthy" for v in valid)
    for v in valid:  # no verdict of a window that holds the gap or the NaN
        assert not (v.start_s < 4.0 and v.end_s > 3.5) and not v.start_s <= 7.75 < v.end_s, (v.start_s, v.end_s)


def scorer_round_trip(model: Path, recordings: list, columns: tuple[str, ...], samples: int,
                      want: int) -> tuple[int, dict[str, list], object]:
    """Start the scorer service on ``model``, publish ``samples`` of each recording as 0.5 s chunks.

    Returns the exit code, the health rows per machine (until ``want`` rows) and the first kl message.
    """
    from hydrowatch.bus import BusSettings, Publisher, Subscriber, free_port, key, open_session, wait_alive
    from hydrowatch.io.codec import sensor_chunk_from_arrays
    from hydrowatch.report.fleet_table import verdict_rows

    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "services.scorer", "--model", str(model), "--fleet", "t",
                             "--bus-port", str(port)])
    got: dict[str, list] = {}
    try:
        with open_session(BusSettings(port=port)) as session, Publisher(session) as pub, \
                Subscriber(session, "hydro/t/*/health") as health, Subscriber(session, "hydro/t/*/kl") as kl:
            assert wait_alive(session, "scorer", "t", 1, timeout=90), "scorer did not come up"
            for start in range(0, samples, 100):
                for r in recordings:
                    channels = {c: r[c][start:start + 100] for c in columns}
                    pub.put(key("t", r.state, "sensors"), sensor_chunk_from_arrays(r.t[start:start + 100], channels))
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and sum(len(v) for v in got.values()) < want:
                message = health.recv(timeout=0.5)
                if message is not None:
                    got.setdefault(message.key.machine, []).extend(verdict_rows(message.batch))
            first_kl = kl.recv(timeout=5)
    finally:
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
    return code, got, first_kl


def test_scorer_service_over_loopback(bundle_dir: Path, test_recordings: list) -> None:
    code, got, first_kl = scorer_round_trip(bundle_dir, test_recordings[:2], COLUMNS, 2400, 6)
    assert code == 0
    assert set(got) == {"healthy", "load_alert"}
    for machine, rows in got.items():
        assert [row["state"] for row in rows].count(machine) >= len(rows) - 1
        assert rows[0]["window_end"] - rows[0]["window_start"] == pytest.approx(5.0)
        assert rows[0]["model_version"].startswith("sha256:")
    assert first_kl is not None and first_kl.batch.num_rows == 3 * len(STATES)
