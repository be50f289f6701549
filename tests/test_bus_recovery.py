"""Chunks a subscriber missed are noticed from the sample times and fetched from the publisher's history."""

from __future__ import annotations

import logging
import time

import numpy as np
import pytest
from test_bus_services import FLEET, assert_contiguous, read_machines, start, stop, wait_for

from hydrowatch.bus import BusSettings, Publisher, Subscriber, free_port, key, open_session
from hydrowatch.bus.history import ChunkHistory, HistoryServer
from hydrowatch.bus.recovery import GapRecovery
from hydrowatch.errors import DataError
from hydrowatch.io.codec import encode_batch
from hydrowatch.io.sensor_chunk import sensor_chunk_from_arrays

MACHINES = ("m0", "m1", "m2")
CHUNKS = 30
SKIPPED = {("m1", 3), ("m1", 4), ("m2", 17)}  # put into the history, never on the bus
UNKNOWN = ("m0", 22)  # not even in the history: a loss recovery cannot mend


def payload(i: int) -> bytes:
    t = (np.arange(20) + 20 * i) / 200.0
    return encode_batch(sensor_chunk_from_arrays(t, {c: np.sin(t) for c in ("voltage", "flow", "speed", "torque")}))


def test_history_keeps_the_last_chunks_and_answers_ranges():
    history = ChunkHistory(depth=3)
    for i in range(5):
        history.add("hydro/f/m0/sensors", i * 0.1, bytes([i]))
    assert [p for p, _ in history.between("hydro/f/m0/sensors", 0.0, 1.0)] == [bytes([2]), bytes([3]), bytes([4])]
    assert history.between("hydro/f/m0/sensors", 0.3, 0.4) == [(bytes([3]), 0)]  # start inclusive, end exclusive
    assert history.between("hydro/f/m9/sensors", 0.0, 1.0) == []
    with pytest.raises(DataError, match="depth"):
        ChunkHistory(depth=0)


def test_history_reuses_its_slots_and_grows_a_key_once_for_a_larger_chunk():
    history, key = ChunkHistory(depth=4), "hydro/f/m0/sensors"
    sent = [payload(i) for i in range(10)]
    for i, p in enumerate(sent):
        history.add(key, i * 0.1, p, sent_ns=1000 + i)
    kept = history.nbytes
    assert kept == 4 * (-(-int(len(sent[0]) * 1.03125) // 64) * 64)  # 4 slots of the chunk size and a 32nd
    for i, p in enumerate(sent):  # the same again, later: nothing allocated
        history.add(key, 1.0 + i * 0.1, p, sent_ns=2000 + i)
    assert history.nbytes == kept
    assert history.between(key, 1.6, 2.0) == [(sent[i], 2000 + i) for i in range(6, 10)]
    bigger = sent[9] + b"\x00" * 2000  # a chunk larger than the slot: the key's kept chunks move to larger slots
    history.add(key, 2.0, bigger, sent_ns=3000)
    assert history.nbytes > kept
    assert history.between(key, 0.0, 3.0) == [(sent[7], 2007), (sent[8], 2008), (sent[9], 2009), (bigger, 3000)]


def test_missed_chunks_are_recovered_once_and_an_unanswered_gap_is_counted(caplog):
    port = free_port()
    keys = {m: key("f", m, "sensors") for m in MACHINES}
    with open_session(BusSettings(port=port)) as pub_session, open_session(BusSettings(port=port)) as sub_session:
        history = ChunkHistory()
        with HistoryServer(pub_session, "hydro/f/*/sensors", history), \
                Subscriber(sub_session, "hydro/f/*/sensors") as subscriber, Publisher(pub_session) as publisher:
            recovery = GapRecovery(sub_session, timeout=2.0)
            assert publisher.wait_for_subscribers(list(keys.values()), 20)
            for i in range(CHUNKS):
                for m in MACHINES:
                    if (m, i) != UNKNOWN:
                        history.add(keys[m], i * 0.1, payload(i))
                    if (m, i) not in SKIPPED and (m, i) != UNKNOWN:
                        publisher.put_payload(keys[m], payload(i))
            got: list = []
            deadline = time.monotonic() + 10
            with caplog.at_level(logging.INFO):
                while time.monotonic() < deadline and (len(got) < CHUNKS * 3 - 1 or recovery.pending):
                    got += recovery.observe(subscriber.recv_many(timeout=0.1))
                    got += recovery.collect()
                got += recovery.wait()
    starts: dict[str, list[int]] = {m: [] for m in MACHINES}
    for message in got:
        starts[message.key.machine].append(int(round(message.start_time() * 10)))
    assert sorted(starts["m1"]) == list(range(CHUNKS)) and sorted(starts["m2"]) == list(range(CHUNKS))
    assert sorted(starts["m0"]) == [i for i in range(CHUNKS) if i != 22]  # every chunk exactly once, but the unknown
    assert recovery.gaps == 3 and recovery.samples_missing == 80  # m1: chunks 3-4 in one gap; m2: 17; m0: 22
    assert recovery.chunks_recovered == 3 and recovery.samples_recovered == 60
    assert recovery.samples_lost == 20 and recovery.chunks_lost == 1 and history.served == 3
    lost = [r for r in caplog.records if r.getMessage() == "samples lost: the gap was not recovered"]
    assert [(r.levelno, r.fields["key"], r.fields["samples"]) for r in lost] == [  # type: ignore[attr-defined]
        (logging.WARNING, "hydro/f/m0/sensors", 20)]


def test_a_late_chunk_and_its_recovered_copy_are_kept_once():
    port = free_port()
    k = key("f", "m0", "sensors")
    with open_session(BusSettings(port=port)) as pub_session, open_session(BusSettings(port=port)) as sub_session:
        history = ChunkHistory()
        for i in range(4):
            history.add(k, i * 0.1, payload(i))
        with HistoryServer(pub_session, "hydro/f/*/sensors", history), \
                Subscriber(sub_session, k) as subscriber, Publisher(pub_session) as publisher:
            recovery = GapRecovery(sub_session)
            assert publisher.wait_for_subscribers([k], 20)
            for i in (0, 2, 3, 1):  # chunk 1 overtaken: a gap, asked for, then the chunk itself arrives
                publisher.put_payload(k, payload(i))
            got: list = []
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and len(got) < 4:
                got += recovery.observe(subscriber.recv_many(timeout=0.1))
                got += recovery.collect()
            got += recovery.wait()
    assert sorted(int(round(m.start_time() * 10)) for m in got) == [0, 1, 2, 3]
    assert recovery.gaps == 1 and recovery.samples_lost == 0


def test_a_lossy_plant_is_recorded_in_full(tmp_path):
    """plant -> recorder in separate processes; the plant leaves every 7th message off the bus (fault
    injection): the recorder notices each gap from the sample times and fetches the chunk from the
    plant's history, so the files hold every sample exactly once."""
    port = free_port()
    recorder = start("services.recorder", "--out", tmp_path, "--fleet", FLEET, "--bus-port", port)
    try:
        wait_for(port, "record")
        plant = start("services.plant", "--fleet", FLEET, "--machines", 4, "--seconds", 3, "--speed", "inf",
                      "--drop-every", 7, "--wait-subscribers", 30, "--bus-port", port)
        assert plant.wait(timeout=120) == 0
        assert stop(recorder) == 0
    finally:
        recorder.kill()
    machines = read_machines(tmp_path / FLEET)
    assert sorted(machines) == ["m000", "m001", "m002", "m003"]
    # 120 messages, every 7th left out (17: every machine lost some, m002 its last chunk, found by asking for
    # the tails); each file holds all 600 samples in order (held back until the gap was filled)
    for t, _ in machines.values():
        assert_contiguous(t, 600)


def test_a_machine_that_stops_while_the_fleet_goes_on_has_its_tail_fetched():
    port = free_port()
    keys = {m: key("f", m, "sensors") for m in ("m0", "m1")}
    with open_session(BusSettings(port=port)) as pub_session, open_session(BusSettings(port=port)) as sub_session:
        history = ChunkHistory()
        with HistoryServer(pub_session, "hydro/f/*/sensors", history), \
                Subscriber(sub_session, "hydro/f/*/sensors") as subscriber, Publisher(pub_session) as publisher:
            recovery = GapRecovery(sub_session)
            assert publisher.wait_for_subscribers(list(keys.values()), 20)
            got: list = []

            def publish(chunks: range, machines: tuple[str, ...], on_bus: bool = True) -> None:
                for i in chunks:
                    for m in machines:
                        history.add(keys[m], i * 0.1, payload(i))
                        if on_bus:
                            publisher.put_payload(keys[m], payload(i))

            for chunks, machines, on_bus in [(range(0, 5), ("m0", "m1"), True),
                                             (range(5, 6), ("m0",), False),  # m0's last chunk: lost on the bus
                                             (range(5, 10), ("m1",), True)]:
                publish(chunks, machines, on_bus)
                time.sleep(0.3)
                got += recovery.observe(subscriber.recv_many(timeout=0.2))
                recovery.ask_stalled()  # after the third phase m0 has not moved while m1 has: its tail is asked for
            got += recovery.wait()
    m0 = sorted(int(round(m.start_time() * 10)) for m in got if m.key.machine == "m0")
    assert m0 == [0, 1, 2, 3, 4, 5] and recovery.chunks_recovered == 1


def test_a_tail_answer_leaves_out_the_chunks_that_arrived_meanwhile():
    # a tail is asked for (a machine quiet for a second, e.g. a loaded host or a router that has just come back) and
    # its next chunks arrive on the bus before the answer: they were written twice (2 chunks in 2 of 4 runs of
    # benchmarks/bench_bus_router_faults.py), now once
    port = free_port()
    k = key("f", "m0", "sensors")
    with open_session(BusSettings(port=port)) as pub_session, open_session(BusSettings(port=port)) as sub_session:
        history = ChunkHistory()
        for i in range(7):
            history.add(k, i * 0.1, payload(i))
        with HistoryServer(pub_session, "hydro/f/*/sensors", history), \
                Subscriber(sub_session, k) as subscriber, Publisher(pub_session) as publisher:
            recovery = GapRecovery(sub_session)
            assert publisher.wait_for_subscribers([k], 20)

            def receive(n: int) -> list:
                out: list = []
                deadline = time.monotonic() + 10
                while len(out) < n and time.monotonic() < deadline:
                    out += subscriber.recv_many(timeout=0.1)
                return out

            for i in range(5):
                publisher.put_payload(k, payload(i))
            got = recovery.observe(receive(5))
            got += recovery.wait()  # the head question, answered with nothing new
            recovery.ask_tails()  # the tail after chunk 4: the history holds 5 and 6 ...
            for i in (5, 6):  # ... which arrive on the bus before the answer is read
                publisher.put_payload(k, payload(i))
            got += recovery.observe(receive(2))
            got += recovery.wait()
    assert sorted(int(round(m.start_time() * 10)) for m in got) == list(range(7))
