"""Arrow publish/subscribe across processes over loopback: order, decode errors, status."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import textwrap
import time

import numpy as np

from hydrowatch.bus import BusSettings, StatusReporter, Subscriber, alive, free_port, key_expr, open_session
from hydrowatch.bus.quarantine import Quarantine
from hydrowatch.io.codec import arrays_from_sensor_chunk

PUBLISHER = textwrap.dedent("""
    import sys
    import numpy as np
    from hydrowatch.bus import BusSettings, Publisher, key, open_session, status_batch
    from hydrowatch.io.codec import sensor_chunk_from_arrays

    def chunk(i):
        t = (np.arange(20) + 20 * i) / 200.0
        return sensor_chunk_from_arrays(t, {c: np.sin(t) for c in ("voltage", "flow", "speed", "torque")})

    good, garbage, version, other = (key("t1", m, "sensors") for m in ("good", "garbage", "v2", "other"))
    with open_session(BusSettings(port=int(sys.argv[1]))) as session:
        pub = Publisher(session)
        try:
            assert pub.wait_for_subscribers([good, garbage, version, other], 30)
            for i in range(30):
                pub.put(good, chunk(i))
                if i in (10, 11):
                    pub.put_payload(garbage, b"not arrow at all" * i)
                if i in (20, 21):
                    b = chunk(i)
                    v2 = {**b.schema.metadata, b"hydrowatch.schema_version": b"3"}
                    pub.put(version, b.replace_schema_metadata(v2))
                if i == 25:
                    pub.put(other, status_batch("plant", None, "running", {}))
        finally:
            pub.close()
""")


class _Count(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def test_undecodable_messages_are_counted_logged_once_skipped_and_the_first_kept(tmp_path) -> None:
    port = free_port()
    counter = _Count()
    logger = logging.getLogger("hydrowatch.bus.pubsub")
    logger.addHandler(counter)
    try:
        with open_session(BusSettings(port=port)) as session, \
                Subscriber(session, key_expr("t1"), quarantine=Quarantine(tmp_path / "q", limit=4)) as sub:
            proc = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(port)])
            try:
                messages = []
                deadline = time.monotonic() + 60
                while len(messages) < 30 and time.monotonic() < deadline:
                    message = sub.recv(timeout=1.0)
                    if message is not None:
                        messages.append(message)
                assert proc.wait(timeout=60) == 0
                while (extra := sub.recv(timeout=0.3)) is not None:
                    messages.append(extra)
            finally:
                proc.kill()
                proc.wait()
    finally:
        logger.removeHandler(counter)
    assert len(messages) == 30
    assert {m.key.machine for m in messages} == {"good"}
    t = np.concatenate([arrays_from_sensor_chunk(m.batch)[0] for m in messages])
    np.testing.assert_allclose(np.diff(t), 1 / 200.0)  # in order, none lost, none twice
    assert t[0] == 0.0 and t.size == 600
    assert sub.undecodable == {"hydro/t1/garbage/sensors": 2, "hydro/t1/v2/sensors": 2, "hydro/t1/other/sensors": 1}
    assert sub.received == 35
    logged = sorted(r.fields["key"] for r in counter.records)  # type: ignore[attr-defined]
    assert logged == ["hydro/t1/garbage/sensors", "hydro/t1/other/sensors", "hydro/t1/v2/sensors"]
    assert all(m.receive_time_ns >= m.publish_time_ns > 0 for m in messages)
    kept = [json.loads(line) for line in (tmp_path / "q" / "rejected.jsonl").read_text().splitlines()]
    assert len(kept) == 4 and sub.quarantine.kept == 4  # the limit, of 5 rejected
    garbage = [k for k in kept if k["key"] == "hydro/t1/garbage/sensors"]
    assert [(tmp_path / "q" / k["file"]).read_bytes() for k in garbage] == [b"not arrow at all" * i for i in (10, 11)]
    assert all(k["reason"] and k["published_ns"] > 0 and k["bytes"] > 0 for k in kept)


def test_status_reporter_liveliness_and_heartbeat() -> None:
    settings = BusSettings(port=free_port())
    with open_session(settings) as watcher, open_session(settings) as service:
        with Subscriber(watcher, "hydro/f1/*/status") as beats:
            time.sleep(0.3)
            reporter = StatusReporter(service, "f1", "plant", lambda: {"messages_out": 7}, machines=["m1", "m2"],
                                      interval=0.1)
            with reporter:
                time.sleep(0.5)
                tokens = alive(watcher, "hydro/f1/*/status")
            time.sleep(0.5)  # the undeclarations travel to the watcher
            after = alive(watcher, "hydro/f1/*/status")
            rows = [m.batch.to_pylist()[0] for m in beats.drain()]
    assert tokens == sorted(["hydro/f1/m1/status", "hydro/f1/m2/status", f"hydro/f1/{reporter.id}/status"])
    assert after == []
    assert len(rows) >= 3 and rows[-1]["status"] == "stopped" and rows[0]["status"] == "starting"
    assert {r["messages_out"] for r in rows} == {7} and {r["service"] for r in rows} == {"plant"}


def test_free_ports_lie_below_the_ephemeral_range_and_can_be_bound() -> None:
    """free_port never hands out a port that an outgoing connection's source port could take before the service
    binds it (hydrowatch.bus.session.free_port)."""
    from hydrowatch.bus.session import BELOW_EPHEMERAL, _ephemeral_low

    low = _ephemeral_low()
    ports = {free_port() for _ in range(20)}
    assert all(max(1024, low - BELOW_EPHEMERAL) <= p < low for p in ports), (low, ports)
    assert len(ports) > 10  # chosen at random, not the same port each time
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", ports.pop()))


def test_free_port_avoids_the_ports_already_chosen(monkeypatch) -> None:
    """Two services started together get two ports: ``avoid`` skips the one already chosen even when the random pick
    lands on it (forced here by a range of two ports), and the kernel's fallback skips it too."""
    import hydrowatch.bus.session as S

    monkeypatch.setattr(S, "BELOW_EPHEMERAL", 2)
    low = S._ephemeral_low()
    first = free_port()
    assert low - 2 <= first < low
    assert {free_port(avoid={first}) for _ in range(20)} == {low - 2, low - 1} - {first}
    monkeypatch.setattr(S, "BELOW_EPHEMERAL", 1)
    only = free_port()
    fallback = free_port(avoid={only})  # the range holds only the avoided port: the kernel chooses
    assert fallback != only and fallback > 0


def test_waiting_for_subscribers_ends_when_told_to_stop() -> None:
    """wait_for_subscribers returns False as soon as its stop event is set, not after its timeout."""
    import threading

    from hydrowatch.bus import Publisher

    with open_session(BusSettings(port=free_port())) as session:
        publisher = Publisher(session)
        stop = threading.Event()
        threading.Timer(0.3, stop.set).start()
        began = time.monotonic()
        assert publisher.wait_for_subscribers(["hydro/none/m1/sensors"], timeout=30.0, stop=stop) is False
        assert 0.25 < time.monotonic() - began < 5.0
        stop.clear()
        assert publisher.wait_for_subscribers(["hydro/none/m1/sensors"], timeout=0.2, stop=stop) is False  # timeout


def test_waiting_for_subscribers_waits_until_one_matches() -> None:
    """Without a subscriber the wait runs to its timeout; with one on the key it returns True (the check once tested
    zenoh's MatchingStatus object, always true, and never waited)."""
    from hydrowatch.bus import Publisher

    port = free_port()
    with open_session(BusSettings(port=port)) as session:
        publisher = Publisher(session)
        began = time.monotonic()
        assert publisher.wait_for_subscribers(["hydro/none/m1/sensors"], timeout=1.0, settle=0.0) is False
        assert time.monotonic() - began >= 1.0
        subscriber = Subscriber(session, "hydro/none/*/sensors")
        try:
            assert publisher.wait_for_subscribers(["hydro/none/m1/sensors"], timeout=10.0, settle=0.0) is True
        finally:
            subscriber.close()
