"""What a subscriber's backlog leaves in resident memory once it is read, and what trimming gives back (issue 18).

Two zenoh peer sessions on loopback in this process: one publishes ``--messages`` sensor chunks of 20 samples (the
study rig's channels, ~2.2 kB as Arrow IPC) on 200 keys while the other's
:class:`~hydrowatch.bus.pubsub.Subscriber` reads nothing; then the subscriber reads its whole backlog, and
:func:`hydrowatch.bus.heap.trim_heap` runs. Printed per round: the process's RSS before the backlog, with it, once
it is read, and after the trim (with the trim's duration). The services trim once a minute
(:class:`~hydrowatch.bus.heap.HeapTrimmer`). Usage::

    python benchmarks/bench_bus_backlog_memory.py [--messages 60000] [--rounds 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hydrowatch.bus import BusSettings, free_port, open_session
from hydrowatch.bus.heap import resident_mb, trim_heap
from hydrowatch.bus.pubsub import Publisher, Subscriber
from hydrowatch.channels import STUDY_RIG
from hydrowatch.io.codec import encode_batch, sensor_chunk_from_arrays


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=60_000)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    settings = BusSettings(port=free_port())
    rng = np.random.default_rng(0)
    payload = encode_batch(sensor_chunk_from_arrays(np.arange(20) / 200.0, {c: rng.normal(size=20) for c in STUDY_RIG}))
    with open_session(settings) as a, open_session(settings) as b:
        subscriber = Subscriber(b, "hydro/bench/*/sensors")
        publisher = Publisher(a)
        time.sleep(1.0)
        print(f"{args.messages} messages of {len(payload)} B per round, 200 keys; RSS in MB")
        print("round  before  backlog  read  trimmed  trim ms  read back")
        for round_ in range(args.rounds):
            trim_heap()
            before = resident_mb()
            for i in range(args.messages):
                publisher.put_payload(f"hydro/bench/m{i % 200:03d}/sensors", payload)
            time.sleep(1.0)
            backlog = resident_mb()
            got = 0
            while subscriber.recv(timeout=0.5) is not None:
                got += 1
            read = resident_mb()
            t = time.perf_counter()
            trim_heap()
            took = (time.perf_counter() - t) * 1e3
            trimmed = resident_mb()
            print(f"{round_:5d}  {before:6.1f}  {backlog:7.1f}  {read:5.1f}  {trimmed:7.1f}  {took:7.1f}  {got:9d}")


if __name__ == "__main__":
    main()
