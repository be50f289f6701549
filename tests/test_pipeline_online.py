"""Streaming scoring: batch/stream parity (pooled or not), gaps and NaN as invalid windows, the scorer service."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from hydrowatch.condition import parity, severity_search, supply, windows_from_recording
from hydrowatch.condition.stream import ConditionStream, judge_streams
from hydrowatch.errors import ParameterError
from hydrowatch.health.plan import DataPlan
from hydrowatch.io.codec import sensor_chunk_from_arrays
from hydrowatch.methods.entropy.reference import SensorReference
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.training.online import Chunk, OnlineScorer, chunks_from_batches
from hydrowatch.training.options import TrainingSettings
from hydrowatch.training.scoring import score_recording
from hydrowatch.training.trainer import train

STATES = ["healthy", "load_alert", "pump_leak_alert"]
PLAN = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=500)
COLUMNS = ("voltage", "flow", "speed", "torque")
RAW = (*COLUMNS, "temperature")


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    seconds = PLAN.samples_per_state / 200 + 1
    grouped = {r.state: [r] for r in simulate_states(STATES, seconds=seconds, seed=0)}
    result = train(grouped, TrainingSettings(method="entropy", reference="bj", plan=PLAN))
    return result.bundle.save(tmp_path_factory.mktemp("bundle") / "model")


@pytest.fixture(scope="module")
def test_recordings() -> list:
    return list(simulate_states(STATES, seconds=20, seed=5))


@pytest.fixture(scope="module")
def parity_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    grouped = {r.state: [r] for r in simulate_states(STATES, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    result = train(grouped, TrainingSettings(method="parity", plan=plan))
    return result.bundle.save(tmp_path_factory.mktemp("parity") / "model")


@pytest.fixture(scope="module")
def fleet() -> list:
    """Six machines, 40 s each (8 windows): each health state twice, other seeds."""
    return list(simulate_states(STATES, seconds=40, seed=6)) + list(simulate_states(STATES, seconds=40, seed=7))


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
                      want: int, extra: tuple[str, ...] = (),
                      skip: frozenset[tuple[int, int]] = frozenset(),
                      forecasts: list | None = None, want_forecasts: int = 0) -> tuple[int, dict[str, list], object]:
    """Start the scorer service on ``model`` (more arguments: ``extra``), publish ``samples`` of each recording as
    0.5 s chunks; the chunks ``skip`` names (recording index, first sample) stay off the bus, in the history.

    Returns the exit code, the health rows per machine (until ``want`` rows) and the first kl message; the forecast
    messages received meanwhile (until ``want_forecasts`` of them, then any more within 1 s) are appended to
    ``forecasts`` when given.
    """
    from hydrowatch.bus import BusSettings, Publisher, Subscriber, free_port, key, open_session, wait_alive
    from hydrowatch.bus.history import ChunkHistory, HistoryServer
    from hydrowatch.io.codec import encode_batch, sensor_chunk_from_arrays
    from hydrowatch.report.fleet_table import verdict_rows

    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "services.scorer", "--model", str(model), "--fleet", "t",
                             "--bus-port", str(port), "--no-stagger", *extra])
    got: dict[str, list] = {}
    try:
        history = ChunkHistory()
        with open_session(BusSettings(port=port)) as session, Publisher(session) as pub, \
                HistoryServer(session, "hydro/t/*/sensors", history), \
                Subscriber(session, "hydro/t/*/health") as health, Subscriber(session, "hydro/t/*/kl") as kl, \
                Subscriber(session, "hydro/t/*/forecast") as forecast:
            assert wait_alive(session, "scorer", "t", 1, timeout=90), "scorer did not come up"
            for start in range(0, samples, 100):
                for i, r in enumerate(recordings):
                    channels = {c: r[c][start:start + 100] for c in columns}
                    payload = encode_batch(sensor_chunk_from_arrays(r.t[start:start + 100], channels))
                    history.add(key("t", r.state, "sensors"), float(r.t[start]), payload)
                    if (i, start) not in skip:
                        pub.put_payload(key("t", r.state, "sensors"), payload)
            # the scorer works through what was published at its own pace: wait while it makes progress, and give
            # up after 30 s without a health message (a fixed 30 s failed on a loaded machine: 26 of 120 windows)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and sum(len(v) for v in got.values()) < want:
                message = health.recv(timeout=0.5)
                if message is not None:
                    got.setdefault(message.key.machine, []).extend(verdict_rows(message.batch))
                    deadline = time.monotonic() + 30
            first_kl = kl.recv(timeout=5)
            # the scorer makes every forecast an update falls due for before it publishes them: on a loaded machine,
            # whose updates hold many windows, seconds after the update's health messages (3 of 10 came within 1 s)
            deadline = time.monotonic() + 30
            while forecasts is not None and len(forecasts) < want_forecasts and time.monotonic() < deadline:
                message = forecast.recv(timeout=0.5)
                if message is not None:
                    forecasts.append(message)
                    deadline = time.monotonic() + 30
            while forecasts is not None and (message := forecast.recv(timeout=1.0)) is not None:
                forecasts.append(message)
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


def feed_fleet(scorer: OnlineScorer, recordings: list, stagger: int = 0) -> list:
    """Every machine's chunks as record batches (chunks_from_batches), of 7, 20 or 33 samples by machine and step;
    machine i joins ``i * stagger`` samples of updates late, so windows close in different updates."""
    sizes = [7, 20, 33]
    pos = [-i * stagger for i in range(len(recordings))]
    out = []
    for k in range(10_000):
        names, batches = [], []
        for i, r in enumerate(recordings):
            n = sizes[(i + k) % 3]
            a, b = max(pos[i], 0), min(pos[i] + n, len(r))
            pos[i] += n
            if b > a:
                names.append(f"m{i}")
                batches.append(sensor_chunk_from_arrays(r.t[a:b], {c: r[c][a:b] for c in RAW}))
        if not batches:
            return out
        out += scorer.update(chunks_from_batches(names, batches, scorer.columns))
    raise AssertionError("the recordings never ended")


@pytest.mark.parametrize("smoothing, batch, stagger, phased", [(1, 64, 0, False), (3, 2, 130, False),
                                                                (2, 64, 0, True)])
def test_parity_fleet_stream_equals_batch_pooled_or_not(parity_dir: Path, fleet: list, smoothing: int, batch: int,
                                                       stagger: int, phased: bool) -> None:
    from hydrowatch.training.bundle import ModelBundle

    bundle = ModelBundle.load(parity_dir)
    model = bundle.condition
    assert model is not None
    scorer = OnlineScorer(bundle, smoothing=smoothing, batch=batch, stagger=phased)
    got = feed_fleet(scorer, fleet, stagger)
    assert scorer.samples == sum(len(r) for r in fleet)
    phases = set()
    for i, r in enumerate(fleet):
        phase = zlib.crc32(f"m{i}".encode()) % bundle.hop if phased else 0  # the scorer's own window phase
        phases.add(phase)
        raw = windows_from_recording(r.slice(phase, len(r)), bundle.window, bundle.hop, temperature=True)
        verdicts, band = model.judge_with_scores(raw, smoothing)
        online = [v for v in got if v.machine == f"m{i}"]
        assert len(online) == len(verdicts) == (len(r) - phase) // bundle.window >= 7
        for k, (a, b) in enumerate(zip(online, verdicts)):
            assert a.start_s == pytest.approx(float(r.t[phase + k * bundle.window]), abs=1e-9)
            assert a.end_s - a.start_s == pytest.approx(5.0)
            assert a.verdict.state == b.state and a.verdict.novelty == pytest.approx(b.novelty, rel=1e-12)
            assert a.verdict.probabilities == pytest.approx(b.probabilities, rel=1e-12, abs=1e-15)
            np.testing.assert_allclose(a.scores.reshape(-1), band[k], rtol=1e-12)
        assert sum(v.verdict.state == r.state for v in online) >= len(online) - 1
    assert len(phases) == (len(fleet) if phased else 1)


def test_a_machine_without_the_temperature_channel_is_pooled_with_the_oil_range(parity_dir: Path, fleet: list) -> None:
    """A temperature bundle, chunks without temperature: the same verdicts as the batch of 4-channel windows (the
    leak boxes widened by the oil's range, condition/oil.py), pooled over the boxes of those windows."""
    from hydrowatch.training.bundle import ModelBundle

    bundle = ModelBundle.load(parity_dir)
    assert bundle.manifest.get("temperature") and bundle.condition is not None
    r = fleet[2]
    scorer = OnlineScorer(bundle, smoothing=4)
    out = []
    for a in range(0, len(r) - 99, 100):
        out += scorer.update([Chunk("m", r.t[a:a + 100], {c: r[c][a:a + 100] for c in COLUMNS})])
    raw = windows_from_recording(r, bundle.window, bundle.hop, temperature=False)
    verdicts, _ = bundle.condition.judge_with_scores(raw, 4)
    assert len(out) == len(verdicts) >= 5
    for a, b in zip(out, verdicts):
        assert a.verdict.state == b.state
        assert a.verdict.probabilities == pytest.approx(b.probabilities, rel=1e-12, abs=1e-15)


def test_pooled_history_survives_a_break_and_the_window_is_invalid(parity_dir: Path, fleet: list) -> None:
    from hydrowatch.training.bundle import ModelBundle

    bundle = ModelBundle.load(parity_dir)
    r = fleet[1]
    scorer = OnlineScorer(bundle, smoothing=4)
    flow = r["flow"].copy()
    flow[2500] = np.nan
    out = []
    for a in range(0, 5000, 100):
        channels = {**{c: r[c][a:a + 100] for c in RAW}, "flow": flow[a:a + 100]}
        out += scorer.update([Chunk("m", r.t[a:a + 100], channels)])
    assert [v.verdict.state for v in out] == [r.state, r.state, "invalid", r.state, r.state]
    assert out[2].verdict.reason == f"NaN in flow at t={r.t[2500]:.3f} s" and out[2].start_s == pytest.approx(r.t[2000])
    assert out[3].start_s == pytest.approx(r.t[2501])  # the stream restarts after the NaN sample
    stream = ConditionStream(bundle.condition, n_windows=4)  # the last verdict pools all four valid windows
    for a in (0, 1000, 2501, 3501):
        stream.update(np.stack([r[c][a:a + 1000] for c in RAW], axis=1))
    assert out[-1].verdict.probabilities == pytest.approx(stream.get().probabilities, rel=1e-12)


def test_judge_streams_equals_each_streams_get(parity_dir: Path, fleet: list) -> None:
    from hydrowatch.training.bundle import ModelBundle

    model = ModelBundle.load(parity_dir).condition
    assert model is not None
    streams = [ConditionStream(model, n_windows=n) for n in (3, 3, 1)]
    for s, r in zip(streams, fleet):
        for w in windows_from_recording(r, 1000, 1000, temperature=True)[:4]:
            s.update(w)
    for n, group in ((3, streams[:2]), (1, streams[2:])):
        evidence = [s.evidence() for s in group]
        batched = judge_streams(model, n, [e for e in evidence if e is not None])
        for s, v in zip(group, batched):
            assert v == s.get()


def test_smoothing_is_checked_and_scores_pool(bundle_dir: Path, parity_dir: Path, fleet: list) -> None:
    from hydrowatch.training.bundle import ModelBundle

    entropy = ModelBundle.load(bundle_dir)
    with pytest.raises(ParameterError, match="smoothing must be 1 for an entropy bundle"):
        OnlineScorer(entropy, smoothing=3)
    with pytest.raises(ParameterError, match="smoothing must be an integer >= 1"):
        score_recording(entropy, fleet[0], smoothing=2)
    bundle = ModelBundle.load(parity_dir)
    with pytest.raises(ParameterError, match="smoothing must be an integer >= 1"):
        OnlineScorer(bundle, smoothing=0)
    r = fleet[2]
    pooled = score_recording(bundle, r, smoothing=4)["windows"]
    assert bundle.condition is not None
    batch = bundle.condition.judge(windows_from_recording(r, 1000, 1000, temperature=True), 4)
    assert [w["state"] for w in pooled] == [v.state for v in batch] and pooled[3]["probabilities"] == \
        pytest.approx(batch[3].probabilities)


def test_score_pools_twelve_windows_for_parity_and_none_for_entropy_by_default(
        bundle_dir: Path, parity_dir: Path, fleet: list, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from hydrowatch.cli import main
    from hydrowatch.io import write_recording
    from hydrowatch.training.bundle import ModelBundle
    from hydrowatch.training.scoring import smoothing_for

    parity, entropy = ModelBundle.load(parity_dir), ModelBundle.load(bundle_dir)
    assert (smoothing_for(parity), smoothing_for(entropy), smoothing_for(parity, 1)) == (12, 1, 1)
    path = write_recording(fleet[2], tmp_path / "machine.parquet")
    capsys.readouterr()
    assert main(["score", "--model", str(parity_dir), "--data", str(path), "--json"]) == 0
    default = json.loads(capsys.readouterr().out)["windows"]
    pooled = score_recording(parity, fleet[2], smoothing=12)["windows"]
    assert [w["probabilities"] for w in default] == [w["probabilities"] for w in pooled]
    assert main(["score", "--model", str(bundle_dir), "--data", str(path), "--json"]) == 0  # entropy: per window


def test_spool_filter_cache_and_compiled_kernel_equal_the_direct_computation() -> None:
    """Speed-only changes: the cached spool filter and the kernels' numpy error model change no result."""
    from scipy.signal import cont2discrete, lfilter, lfilter_zi

    p = PlantParameters()
    rng = np.random.default_rng(1)
    u = np.clip(2.0 + np.cumsum(rng.normal(0, 0.05, (3, 401)), axis=1), 0, 4)
    wv, zv = p.omega_v, p.zeta_v
    ad, bd, *_ = cont2discrete((np.array([[0.0, 1.0], [-wv * wv, -2 * zv * wv]]), np.array([[0.0], [wv * wv]]),
                                np.array([[1.0, 0.0]]), np.zeros((1, 1))), 1 / 200, "zoh")
    den = np.array([1.0, -np.trace(ad), np.linalg.det(ad)])
    num = np.array([0.0, bd[0, 0], (ad @ bd[:, 0])[0] - np.trace(ad) * bd[0, 0]])
    x = u * p.Kc / p.u_max
    direct = lfilter(num, den, x, axis=-1, zi=lfilter_zi(num, den)[None, :] * x[:, :1])[0]
    spool = parity.spool_position(u, p)
    np.testing.assert_allclose(spool, direct, rtol=1e-12, atol=1e-15)
    # the compiled valve fit against its own Python source (Python's error model) on short windows
    pl = 40e5 + 5e5 * np.sin(np.linspace(0, 6, 401))[None] * np.ones((3, 1))
    g = np.ascontiguousarray(p.Kq * spool)
    q = np.ascontiguousarray(supply.M3S_TO_LPM ** -1 * 0.9 * g * np.sqrt(np.maximum(100e5 - pl, 0.0)))
    f, base = np.ones(3), supply.constants(p, 200.0)
    outputs = []
    for compiled in (True, False):
        kernels = [(supply, k) for k in ("_valve_flow", "_equilibrium", "_step", "sweep")] + [
            (severity_search, k) for k in ("sweep", "_lowest", "_flat_ends", "_past_flat")]
        saved = [(module, k, getattr(module, k)) for module, k in kernels]
        try:
            if not compiled:
                for module, k, kernel in saved:
                    setattr(module, k, kernel.py_func)
            fit = severity_search.fit_windows if compiled else severity_search.fit_windows.py_func
            s, mse, curv = np.empty(3), np.empty(3), np.empty(3)
            fit(0, -0.05, 3.0, 7, 4, True, g, np.ascontiguousarray(pl), q, f, base, 8, s, mse, curv)
            outputs.append(np.concatenate([s, mse, curv]))
        finally:
            for module, k, kernel in saved:
                setattr(module, k, kernel)
    np.testing.assert_allclose(outputs[0], outputs[1], rtol=1e-12, atol=1e-18)


def test_scorer_service_publishes_pooled_verdicts(parity_dir: Path, fleet: list) -> None:
    from hydrowatch.training.bundle import ModelBundle

    model = ModelBundle.load(parity_dir).condition
    assert model is not None
    machines = fleet[:2]
    code, got, _ = scorer_round_trip(parity_dir, machines, RAW, 3400, 6, ("--smoothing", "3"))
    assert code == 0 and set(got) == {r.state for r in machines}
    for r in machines:
        rows = sorted(got[r.state], key=lambda row: row["window_start"])
        expected = model.judge(windows_from_recording(r.slice(0, 3000), 1000, 1000, temperature=True), 3)
        assert [row["state"] for row in rows] == [v.state for v in expected] == [r.state] * 3
        for row, v in zip(rows, expected):  # the third verdict pools all three windows
            assert row["probabilities"] == pytest.approx(v.probabilities, rel=1e-9)


def test_an_abrupt_fault_reads_unknown_at_once_and_is_named_when_the_pool_has_turned_over(parity_dir: Path) -> None:
    """Pooled verdicts (default 12 windows) on a duty cycle: healthy for 60 s, then a load fault.

    The first window after the change already leaves ``healthy`` (the new state, or ``unknown`` while no
    one state explains the pool); the new state is named at the latest once the pool holds only its
    windows, and the verdict never falls back to healthy (docs/health-pipeline.md)."""
    from hydrowatch.plant.excitation import duty_cycle
    from hydrowatch.recording import Recording
    from hydrowatch.training.bundle import ModelBundle

    command = duty_cycle(120.0, seed=5)
    before, after = (next(simulate_states([s], seconds=120, command=command, seed=7))
                     for s in ("healthy", "load_alert"))
    n = 60 * 200
    recording = Recording(before.t, {k: np.concatenate([before.channels[k][:n], after.channels[k][n:]])
                                     for k in before.channels}, dict(before.meta))
    bundle = ModelBundle.load(parity_dir)
    pooled = [w["state"] for w in score_recording(bundle, recording)["windows"]]
    alone = [w["state"] for w in score_recording(bundle, recording, smoothing=1)["windows"]]
    assert pooled[:12] == ["healthy"] * 12 and alone[:12] == ["healthy"] * 12
    assert alone[12:] == ["load_alert"] * 12
    assert set(pooled[12:23]) <= {"unknown", "load_alert"} and pooled[23] == "load_alert"


def test_the_scorer_service_staggers_windows_by_default() -> None:
    """A restart or a model switch starts every machine at once: phases from the machine names keep the
    window closings spread (docs/health-pipeline.md, scorer speed)."""
    import argparse

    from services.scorer import add_arguments

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert parser.parse_args([]).stagger is True and parser.parse_args(["--no-stagger"]).stagger is False


@pytest.mark.parametrize("recover", [True, False])
def test_a_chunk_lost_on_the_bus_is_fetched_back_by_the_scorer(parity_dir: Path, fleet: list, recover: bool) -> None:
    machines = fleet[:2]
    skip = frozenset({(0, 1500)})  # machine 0's chunk in the middle of its second window
    extra = ("--smoothing", "1") + (() if recover else ("--no-recovery",))
    code, got, _ = scorer_round_trip(parity_dir, machines, RAW, 3400, 6, extra, skip)
    assert code == 0
    rows = sorted(got[machines[0].state], key=lambda row: row["window_start"])
    states = [row["state"] for row in rows]
    if recover:  # every window whole: the same verdicts as a loss-free stream
        assert states == [machines[0].state] * 3
    else:  # the gap breaks the second window, the stream restarts after it
        assert "invalid" in states and machines[0].state in states


def test_a_model_switch_to_a_bundle_reading_temperature_gathers_temperature(bundle_dir: Path, parity_dir: Path,
                                                                          fleet: list) -> None:
    """Issue 11, item 5: the switch happens before the chunks are gathered, so the parity bundle (which reads the
    oil temperature) gets chunks with it, and its verdicts come out; before, it got the entropy bundle's columns."""
    import argparse

    from hydrowatch.training.bundle import ModelBundle
    from services.scorer import _scorer, _step, _Units, add_arguments

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--no-stagger"])

    class Switching:  # the registry alias moves from the entropy bundle to the parity bundle on the first turn
        def __init__(self) -> None:
            self.bundle, self.turns = ModelBundle.load(bundle_dir), 0

        def moved(self) -> bool:
            self.turns += 1
            if self.turns == 1:
                self.bundle = ModelBundle.load(parity_dir)
                return True
            return False

    model = Switching()
    units = _Units(args, model.bundle)
    scorer = _scorer(model, units, args)  # type: ignore[arg-type]
    assert "temperature" not in scorer.columns
    asked: list[list[str]] = []
    r = fleet[0]

    def gather(columns):
        asked.append(list(columns))
        return chunks_from_batches(["t/m"], [sensor_chunk_from_arrays(r.t[:2000], {c: r[c][:2000] for c in RAW})],
                                   columns)

    units, scorer, verdicts = _step(model, units, scorer, args, gather)  # type: ignore[arg-type]
    assert asked == [list(RAW)]
    assert scorer.bundle.method == "parity" and len(verdicts) == 2
    assert all(v.verdict.state != "invalid" for v in verdicts)


def test_commissioning_refuses_an_entropy_bundle_and_says_why(bundle_dir: Path, test_recordings: list) -> None:
    from hydrowatch.condition.commission import CommissioningError
    from hydrowatch.training.bundle import ModelBundle
    from hydrowatch.training.commissioning import commission_bundle

    with pytest.raises(CommissioningError, match="entropy bundle: its base distributions"):
        commission_bundle(ModelBundle.load(bundle_dir), test_recordings[:1], "m7")
