"""Subscriber: samples wait in zenoh channels, the caller takes them in order, sleeps when there are none."""

from __future__ import annotations

import threading
import time

import numpy as np

from hydrowatch.bus import BusSettings, Publisher, Shard, Subscriber, free_port, key, open_session
from hydrowatch.io.codec import sensor_chunk_from_arrays

MACHINES = ("m000", "m001", "m002", "m003")


def chunk(i: int, n: int = 20):
    t = (np.arange(n) + n * i) / 200.0
    return sensor_chunk_from_arrays(t, {c: np.cos(t) for c in ("voltage", "flow", "speed", "torque")})


def first_t(messages) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {}
    for m in messages:
        out.setdefault(m.key.machine, []).append(m.batch.column("t")[0].as_py())
    return out


def test_waits_without_losing_a_message_then_takes_bursts_in_order_and_drains_after_close():
    settings = BusSettings(port=free_port())
    keys = [key("s1", m, "sensors") for m in MACHINES]
    with open_session(settings) as sub_session, open_session(settings) as pub_session:
        sub = Subscriber(sub_session, "hydro/s1/*/sensors")
        publisher = Publisher(pub_session)
        try:
            assert publisher.wait_for_subscribers(keys, 30)
            assert sub.recv(timeout=0.2) is None  # nothing yet: it waits out the timeout
            # a message published while the caller sleeps in recv() wakes it
            later = threading.Timer(0.3, publisher.put, (keys[0], chunk(0)))
            later.start()
            woken = sub.recv(timeout=30)
            later.join()
            assert woken is not None and woken.key.machine == "m000"
            assert woken.receive_time_ns >= woken.publish_time_ns > 0
            # a burst, taken many at a time
            for i in range(1, 51):
                for k in keys:
                    publisher.put(k, chunk(i))
            got, sizes = [], []
            deadline = time.monotonic() + 30
            while len(got) < 200 and time.monotonic() < deadline:
                burst = sub.recv_many(64, timeout=1.0)
                got += burst
                sizes.append(len(burst))
            assert len(got) == 200 and max(sizes) <= 64
            times = first_t(got)
            for machine in MACHINES:  # every chunk once, in publishing order
                np.testing.assert_allclose(times[machine], np.arange(1, 51) * 0.1)
            # what arrived before close() is still there afterwards, in order
            for i in range(51, 61):
                publisher.put(keys[1], chunk(i))
            time.sleep(0.3)
            sub.close()
            rest = list(sub.drain())
            np.testing.assert_allclose(first_t(rest)["m001"], np.arange(51, 61) * 0.1)
            assert sub.received == 211 and sub.undecodable_total == 0
        finally:
            sub.close()
            publisher.close()


def test_a_shard_keeps_only_its_machines():
    settings = BusSettings(port=free_port())
    shard = Shard(0, 2)
    machines = [f"m{i:03d}" for i in range(8)]
    keys = [key("s2", m, "sensors") for m in machines]
    mine = {m for m in machines if shard.includes(m)}
    assert 0 < len(mine) < len(machines)
    with open_session(settings) as sub_session, open_session(settings) as pub_session:
        with Subscriber(sub_session, "hydro/s2/*/sensors", shard=shard) as sub:
            publisher = Publisher(pub_session)
            try:
                assert publisher.wait_for_subscribers(keys, 30)
                for i in range(5):
                    for k in keys:
                        publisher.put(k, chunk(i))
                got = []
                deadline = time.monotonic() + 30
                while len(got) < 5 * len(mine) and time.monotonic() < deadline:
                    got += sub.recv_many(timeout=1.0)
                assert sub.recv(timeout=0.3) is None
            finally:
                publisher.close()
    assert {m.key.machine for m in got} == mine and len(got) == 5 * len(mine)
    assert sub.outside_shard == 5 * (len(machines) - len(mine))
