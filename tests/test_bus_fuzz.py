"""Malformed bus traffic against the real recorder and scorer (issue 18, item 3).

Beside a healthy plant stream, thousands of malformed messages: random bytes, truncated Arrow IPC,
bit flips, a valid batch of another schema, a schema version from the future, a huge message,
sensor chunks with NaN and with time going backwards, keys that do not parse; and malformed history
queries, which the plant answers. Every service keeps
running and exits 0 on SIGTERM, the healthy machines' recordings are complete and their verdicts
keep coming, the counters count what was refused, and each bad key is logged once.
"""

from __future__ import annotations

import random
import re
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from hydrowatch.bus import BusSettings, Publisher, Subscriber, free_port, open_session, wait_alive
from hydrowatch.errors import DataError
from hydrowatch.io.codec import arrays_from_sensor_chunk, check_payload, encode_batch, sensor_chunk_from_arrays
from hydrowatch.io.mcap_io import iter_messages
from hydrowatch.schemas import schema_by_name

FLEET = "fz"
HEALTHY = ("m000", "m001")
SECONDS = 80
"""Simulated seconds of the plant (at --speed 4: 20 s of wall time)."""
SENSORS = schema_by_name("sensor_chunk")


def chunk(t0: float, rows: int = 20, *, dt: float = 1 / 200, rng: np.random.Generator | None = None) -> pa.RecordBatch:
    rng = rng or np.random.default_rng(0)
    t = t0 + dt * np.arange(rows)
    return sensor_chunk_from_arrays(t, {c: rng.normal(size=rows) for c in ("voltage", "flow", "speed", "torque")})


def malformed(rng: random.Random, n: int) -> list[tuple[str, bytes]]:
    """``n`` malformed messages as (key, payload), several kinds on keys of their own and garbage on the healthy
    machines' keys (it must not disturb their streams)."""
    good = encode_batch(chunk(0.0))
    status = schema_by_name("status")
    other = encode_batch(pa.RecordBatch.from_pydict(
        {f.name: pa.array([1], f.type) if pa.types.is_integer(f.type) else pa.array(
            [1.0] if pa.types.is_floating(f.type) else ["x"], f.type) for f in status}, schema=status))
    future = chunk(0.0)
    meta = dict(future.schema.metadata)
    meta[b"hydrowatch.schema_version"] = b"99"
    future_payload = encode_batch(future.replace_schema_metadata(meta))
    values = np.random.default_rng(1)
    nan_t, back_t = [0.0], [100.0]

    def nan_chunk() -> bytes:
        batch = chunk(nan_t[0], rng=values)
        nan_t[0] += 0.1
        columns = {name: batch.column(name).to_numpy().copy() for name in batch.schema.names}
        columns[rng.choice(["t", "speed", "voltage"])][rng.randrange(20)] = np.nan
        return encode_batch(sensor_chunk_from_arrays(columns.pop("t"), columns))

    def backwards_chunk() -> bytes:
        back_t[0] -= rng.choice([0.05, 0.1, 7.0])
        return encode_batch(chunk(back_t[0], dt=rng.choice([1 / 200, -1 / 200]), rng=values))

    def flipped() -> bytes:
        data = bytearray(good)
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        return bytes(data)

    kinds = [
        ("random", lambda: rng.randbytes(rng.randint(0, 3000))),
        ("truncated", lambda: good[: rng.randrange(len(good))]),
        ("flipped", flipped),
        ("schema", lambda: other),
        ("version", lambda: future_payload),
        ("nan", nan_chunk),
        ("backwards", backwards_chunk),
    ]
    out = []
    for i in range(n):
        kind, make = kinds[i % len(kinds)]
        out.append((f"hydro/{FLEET}/bad-{kind}/sensors", make()))
        if i % 10 == 0:  # garbage on a healthy machine's own key
            out.append((f"hydro/{FLEET}/{HEALTHY[i % 2]}/sensors", rng.randbytes(rng.randint(1, 200))))
    out.append((f"hydro/{FLEET}/bad-huge/sensors", encode_batch(chunk(0.0, rows=100_000))))  # 4.8 MB, valid
    out.append((f"hydro/{FLEET}/{HEALTHY[0]}/sensors", rng.randbytes(6_000_000)))  # 6 MB of garbage
    for name in ("hydro/fz/m000/sensors/extra", "hydro/fz/m000/bogus", "hydro/fz/junk", "hydro/fz/../sensors",
                 "hydro/fz/./sensors", "hydro/fz/m 0/sensors"):
        out += [(name, good)] * 5  # keys that are not contract keys (only the recorder's hydro/fz/** sees them)
    return out


def test_corrupted_payloads_raise_only_data_errors_and_what_passes_reads_safely() -> None:
    # bit flips anywhere (schema, field names, metadata, buffer lengths, string offsets, values) of chunks with and
    # without labels: found a UnicodeDecodeError (names and metadata), buffers shorter than the batch says and
    # string offsets outside their data (both read memory outside the message) getting through
    rng, values = random.Random(7), np.random.default_rng(7)
    t = np.arange(20) / 200
    channels = {c: values.normal(size=20) for c in ("voltage", "flow", "speed", "torque")}
    goods = [encode_batch(sensor_chunk_from_arrays(t, channels)),
             encode_batch(sensor_chunk_from_arrays(t, {**channels, "state": ["healthy"] * 20})),
             encode_batch(sensor_chunk_from_arrays(t, {**channels, "state": ["hé"] * 10 + ["x"] * 10}))]
    outcomes: Counter[str] = Counter()
    for i in range(3000):
        data = bytearray(goods[i % 3])
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        try:
            batch = check_payload(bytes(data), SENSORS, "fuzz").read(bytes(data))
        except DataError:
            outcomes["refused"] += 1
            continue
        batch.validate(full=True)
        batch.to_pylist()
        outcomes["accepted"] += 1
    assert outcomes["refused"] > 1000 and outcomes["accepted"] > 500, outcomes


def refused(messages: list[tuple[str, bytes]], subscription: str) -> Counter[str]:
    """What a subscriber of ``subscription`` must refuse, per key (judged with the library's own check)."""
    from hydrowatch.bus.keys import parse_key

    out: Counter[str] = Counter()
    for key, payload in messages:
        if subscription.endswith("*/sensors") and not re.fullmatch(r"hydro/fz/[^/]+/sensors", key):
            continue
        try:
            parse_key(key)
            check_payload(payload, SENSORS, key)
        except DataError:
            out[key] += 1
    return out


def start(module: str, log: Path, *argv: object) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", module, "-v", *map(str, argv)], stderr=log.open("wb"))


def sensor_times(folder: Path) -> np.ndarray:
    parts = [arrays_from_sensor_chunk(batch)[0] for path in sorted(folder.rglob("*.mcap"))
             for topic, batch, _ in iter_messages(path, topics=None) if topic.endswith("/sensors")] \
        if folder.is_dir() else []
    return np.concatenate(parts) if parts else np.empty(0)


@pytest.fixture(scope="module")
def parity_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from hydrowatch.health.plan import DataPlan
    from hydrowatch.plant.fleet import simulate_states
    from hydrowatch.training.options import TrainingSettings
    from hydrowatch.training.trainer import train

    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    states = ["healthy", "load_alert", "pump_leak_alert"]
    grouped = {r.state: [r] for r in simulate_states(states, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    return train(grouped, TrainingSettings(method="parity", plan=plan)).bundle.save(
        tmp_path_factory.mktemp("parity") / "model")


@pytest.mark.slow
def test_malformed_traffic_is_counted_logged_once_and_stops_nothing(tmp_path: Path, parity_model: Path) -> None:
    port = free_port()
    logs = {name: tmp_path / f"{name}.log" for name in ("record", "scorer")}
    recorder = start("services.recorder", logs["record"], "--out", tmp_path / "rec", "--keys", f"hydro/{FLEET}/**",
                     "--fleet", FLEET, "--bus-port", port, "--flush", 0.2)
    scorer = start("services.scorer", logs["scorer"], "--model", parity_model, "--fleet", FLEET, "--bus-port", port,
                   "--smoothing", 1)
    plant = None
    verdicts: dict[str, list[float]] = {}
    states: dict[str, Counter[str]] = {}
    heartbeats: dict[str, dict] = {}
    messages = malformed(random.Random(18), 3500)
    try:
        with open_session(BusSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",))) as session, \
                Publisher(session) as publisher, Subscriber(session, f"hydro/{FLEET}/*/health") as health, \
                Subscriber(session, f"hydro/{FLEET}/*/status") as status:

            def listen(seconds: float) -> None:
                end = time.monotonic() + seconds
                while (left := end - time.monotonic()) > 0:
                    for message in health.recv_many(timeout=min(left, 0.2)):
                        verdicts.setdefault(message.key.machine, []).append(time.monotonic())
                        states.setdefault(message.key.machine, Counter()).update(
                            message.batch.column("state").to_pylist())
                    for message in status.recv_many(timeout=0.0):
                        row = message.batch.to_pylist()[0]
                        heartbeats[row["service"]] = row

            for service in ("record", "scorer"):
                assert wait_alive(session, service, FLEET, timeout=120), f"{service} did not come up"
            plant = start("services.plant", tmp_path / "plant.log", "--fleet", FLEET, "--machines", 2, "--speed", 4,
                          "--seconds", SECONDS, "--states", "healthy,load_alert", "--wait-subscribers", 60,
                          "--bus-port", port)
            deadline = time.monotonic() + 120
            while not all(verdicts.get(m) for m in HEALTHY) and time.monotonic() < deadline:
                listen(0.5)
            assert all(verdicts.get(m) for m in HEALTHY), "no verdicts before the fuzz"
            began = time.monotonic()
            queries = [f"hydro/{FLEET}/m000/sensors?{p}" for p in ("start=abc", "start=5;end=1", "start=nan;end=nan",
                                                                    "", "start=-inf;end=inf;x=y", "end=1e400")]
            queries += [f"hydro/{FLEET}/*/sensors?start=-inf;end=inf", f"hydro/{FLEET}/../sensors?start=0;end=1"]
            for i, (key, payload) in enumerate(messages):  # spread over ~6 s, verdicts due meanwhile
                publisher.put_payload(key, payload)
                if i % 25 == 0:  # malformed history queries: the plant answers those (and must go on)
                    session.get(queries[i // 25 % len(queries)], lambda reply: None, timeout=2.0)
                if i % 200 == 0:
                    listen(0.3)
                    assert plant.poll() is None, "the plant ended before the fuzz did"
            ended = time.monotonic()
            listen(2.0)
            assert recorder.poll() is None and scorer.poll() is None, "a service stopped"
            for service in ("record", "scorer"):  # still on the bus
                assert wait_alive(session, service, FLEET, timeout=30), f"{service} is gone"
            assert plant.wait(timeout=180) == 0
            listen(3.0)
            assert [stop(recorder), stop(scorer)] == [0, 0]
            listen(2.0)
    finally:
        for proc in (recorder, scorer, plant):
            if proc is not None:
                proc.kill()
    text = {name: path.read_text(encoding="utf-8", errors="replace") for name, path in logs.items()}
    for machine in HEALTHY:
        after = [t for t in verdicts[machine] if t > ended]
        during = [t for t in verdicts[machine] if began <= t <= ended + 1.0]
        assert after, f"{machine}: no verdict after the fuzz"
        assert during, f"{machine}: no verdict during {ended - began:.1f} s of fuzz"
        t = sensor_times(tmp_path / "rec" / FLEET / machine)
        assert t.size == SECONDS * 200, (machine, t.size)  # every sample once: no complete chunk lost
        np.testing.assert_allclose(np.diff(t), 1 / 200, atol=1e-9)
    for service, subscription in (("record", f"hydro/{FLEET}/**"), ("scorer", f"hydro/{FLEET}/*/sensors")):
        expected = refused(messages, subscription)
        keys = re.findall(r'undecodable message skipped key=("[^"]*"|\S+)', text[service])
        logged = Counter(k.strip('"') for k in keys)
        assert logged == Counter(dict.fromkeys(expected, 1)), (service, logged, expected)  # once per key
        beat = heartbeats[service]
        assert beat["status"] == "stopped" and beat["messages_undecodable"] == sum(expected.values()), (service, beat)
    assert f"undecodable={sum(refused(messages, f'hydro/{FLEET}/**').values())}" in text["record"]
    assert "Traceback" not in text["record"] + text["scorer"]
    # NaN or time going backwards in every chunk: no window of those machines is ever complete, so they get no
    # verdict but 'invalid' ones (the parity scorer starts each window at the machine's phase after a break)
    for machine in ("bad-nan", "bad-backwards"):
        assert set(states.get(machine, {})) <= {"invalid"}, (machine, states[machine])
    # every file in a machine's own folder: no key wrote outside it (a machine id '..' or '.' would)
    assert {p.parent.parent for p in (tmp_path / "rec").rglob("*.mcap")} == {tmp_path / "rec" / FLEET}
    during = [sum(began <= t <= ended for t in verdicts[m]) for m in HEALTHY]
    print(f"fuzz: {len(messages)} messages in {ended - began:.1f} s; refused by the recorder "
          f"{sum(refused(messages, f'hydro/{FLEET}/**').values())}; verdicts per healthy machine during the fuzz "
          f"{during}, in all {[len(verdicts[m]) for m in HEALTHY]}; verdict states per machine {states}")


def stop(proc: subprocess.Popen) -> int:
    proc.send_signal(signal.SIGTERM)
    return proc.wait(timeout=120)
