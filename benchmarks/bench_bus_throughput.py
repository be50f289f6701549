"""End to end plant -> bus -> recorder on one machine: sensor samples per second without loss.

Starts a recorder and the plant service (1000 machines at 200 Hz, as fast as possible) as
separate processes on a private loopback bus, then *counts* the samples in the recorder's files
and divides by the span of their receive times. Reference: 200,000 samples/s (1000 machines in
real time). Run again with ``--plants 2`` to spread the simulation over two plant shards.

Usage: python benchmarks/bench_bus_throughput.py [--machines 1000] [--seconds 5] [--plants 1]
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hydrowatch.bus import BusSettings, free_port, open_session, wait_alive
from hydrowatch.io.mcap_io import iter_messages

REFERENCE_SAMPLES_PER_S = 200_000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=1000)
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per machine")
    parser.add_argument("--plants", type=int, default=1, help="plant processes (shards of the fleet)")
    args = parser.parse_args()
    port = free_port()
    with tempfile.TemporaryDirectory() as out:
        recorder = subprocess.Popen([sys.executable, "-m", "services.recorder", "--out", out, "--fleet", "bench",
                                     "--bus-port", str(port)])
        try:
            with open_session(BusSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",))) as session:
                assert wait_alive(session, "record", "bench", timeout=60), "recorder did not come up"
            started = time.monotonic()
            plants = [subprocess.Popen([
                sys.executable, "-m", "services.plant", "--fleet", "bench", "--machines", str(args.machines),
                "--seconds", str(args.seconds), "--speed", "inf", "--wait-subscribers", "60", "--bus-port", str(port),
                "--shard", f"{i}/{args.plants}"]) for i in range(args.plants)]
            codes = [p.wait() for p in plants]
            plant_wall = time.monotonic() - started
            recorder.send_signal(signal.SIGTERM)
            assert recorder.wait(timeout=300) == 0 and codes == [0] * args.plants
        finally:
            recorder.kill()
        messages, samples, first, last = 0, 0, None, None
        per_topic: dict[str, int] = {}
        for path in Path(out).rglob("*.mcap"):
            for topic, batch, log_time in iter_messages(path):
                messages += 1
                samples += batch.num_rows
                per_topic[topic] = per_topic.get(topic, 0) + batch.num_rows
                first = log_time if first is None else min(first, log_time)
                last = log_time if last is None else max(last, log_time)
    published = args.machines * int(round(args.seconds * 200))
    short = sum(n < int(round(args.seconds * 200)) for n in per_topic.values())
    print(f"machines recorded={len(per_topic)} of {args.machines}, with samples missing={short}")
    span = (last - first) / 1e9 if first is not None and last is not None else float("nan")
    rate = samples / span
    print(f"machines={args.machines} simulated_s={args.seconds} plants={args.plants}")
    print(f"published samples={published} recorded samples={samples} messages={messages} lost={published - samples}")
    print(f"receive span={span:.2f} s  plant wall (incl. start-up)={plant_wall:.2f} s")
    print(f"throughput={rate:,.0f} samples/s  ratio to reference {REFERENCE_SAMPLES_PER_S:,.0f}: "
          f"{rate / REFERENCE_SAMPLES_PER_S:.2f}")
    print("note: measured on a shared 2-core machine; figures are pessimistic")


if __name__ == "__main__":
    main()
