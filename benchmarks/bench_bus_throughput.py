"""End to end plant -> bus -> recorder on one host: sensor samples per second without loss.

Starts the recorder(s) and the plant(s) (1000 machines at 200 Hz, as fast as possible) as separate
processes on a private loopback bus, then *counts* the samples in the recorders' files and checks
that every machine has every sample exactly once. Figures:

* throughput: recorded samples / (time the recorders had written the last message − receive time
  of the first); the end comes from the recorders' status heartbeats (every 0.1 s here), so this
  is what the recorder sustained, not how fast the queue in front of it filled.
* CPU cost: samples per CPU-second of each kind of process from the first receive to the last
  write (from /proc, sampled every 0.05 s; start-up and shutdown excluded): the throughput each would reach
  alone on an idle core; and from both, a CPU-bound estimate for the two alone on two idle
  cores (samples / the largest of either process's CPU and half their sum). On a machine that
  other jobs load, the measured figure is what they left over; the estimate is not a measurement.

``--source synthetic`` replaces the plant by a publisher of ready-made chunks (same messages, no
simulation) to measure the bus + recorder on their own. Reference: 200,000 samples/s (1000
machines in real time).

Usage: python benchmarks/bench_bus_throughput.py [--machines 1000] [--seconds 10] [--plants 1]
       [--recorders 1] [--chunk 0.1] [--source plant|synthetic] [--scratch DIR]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from hydrowatch.bus import BusSettings, Publisher, Subscriber, free_port, key, open_session, parse_shard, wait_alive
from hydrowatch.bus.fleet_publisher import FleetEncoder
from hydrowatch.io.mcap_io import iter_messages
from services.plant import CHANNELS

REFERENCE_SAMPLES_PER_S = 200_000.0
FLEET = "bench"
RATE_HZ = 200.0
HEARTBEAT_S = 0.1
_TICK_S = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of a running process (None once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / _TICK_S


class Child:
    """A child process whose CPU time is sampled while it runs and read from rusage when it ends."""

    def __init__(self, argv: list[str]) -> None:
        self.proc = subprocess.Popen(argv)
        self.samples: list[tuple[float, float]] = []  # (wall clock, s since epoch; CPU s)
        self.status: int | None = None

    def sample(self) -> None:
        if self.status is None and (cpu := cpu_seconds(self.proc.pid)) is not None:
            self.samples.append((time.time(), cpu))

    def wait(self, timeout: float) -> int:
        """Reap it and add the exact final CPU time (from rusage)."""
        deadline = time.monotonic() + timeout
        while self.status is None:
            pid, status, usage = os.wait4(self.proc.pid, os.WNOHANG)
            if pid:
                self.status = os.waitstatus_to_exitcode(status)
                self.proc.returncode = self.status
                self.samples.append((time.time(), usage.ru_utime + usage.ru_stime))
            elif time.monotonic() > deadline:
                self.proc.kill()
            else:
                time.sleep(0.02)
        return self.status

    def cpu_between(self, start: float, end: float) -> float:
        """CPU seconds used from ``start`` to ``end`` (s since epoch; sampled every 0.05 s, interpolated)."""
        times, cpu = np.array(self.samples).T
        return float(np.interp(end, times, cpu) - np.interp(start, times, cpu))


def publish_synthetic(machines: int, seconds: float, chunk: float, port: int, shard: str) -> None:
    """The plant's messages without the simulation, encoded the plant's way (one pass per step)."""
    n = int(round(chunk * RATE_HZ))
    mine = [m for m in (f"m{i:03d}" for i in range(machines)) if parse_shard(shard).includes(m)]
    keys = [key(FLEET, m, "sensors") for m in mine]
    rng = np.random.default_rng(0)
    channels = {c: rng.normal(size=(len(mine), n)) for c in CHANNELS}
    encoder = FleetEncoder(CHANNELS, ["healthy"] * len(mine))
    with open_session(BusSettings(port=port)) as session:
        publisher = Publisher(session)
        try:
            assert publisher.wait_for_subscribers(keys, 60), "no recorder subscribed"
            for step in range(int(round(seconds / chunk))):
                t = np.tile((step * n + np.arange(n)) / RATE_HZ, (len(mine), 1))
                for k, payload in zip(keys, encoder.encode(t, channels)):
                    publisher.put_payload(k, payload)
            time.sleep(2.0)  # let the recorder read its sockets before the session closes
        finally:
            publisher.close()


def count_samples(out: Path) -> tuple[dict[str, np.ndarray], int, int | None]:
    """Sample times per machine (every file, every message), message count, first log time, ns."""
    times: dict[str, list[np.ndarray]] = defaultdict(list)
    messages, first = 0, None
    for path in out.rglob("*.mcap"):
        for topic, batch, log_time in iter_messages(path):
            messages += 1
            times[topic].append(batch.column("t").to_numpy())
            first = log_time if first is None else min(first, log_time)
    return {k: np.sort(np.concatenate(v)) for k, v in times.items()}, messages, first


def watch(port: int, children: list[Child], rows: list[tuple[str, dict]], stop: threading.Event) -> None:
    """Sample the children's CPU time and collect (service id, heartbeat row) of every status
    message, every 0.05 s until ``stop``."""
    settings = BusSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",))
    with open_session(settings) as session, Subscriber(session, f"hydro/{FLEET}/*/status") as beats:
        while not stop.is_set():
            for child in list(children):
                child.sample()
            rows.extend((m.key.machine, row) for m in beats.recv_many(timeout=0.05) for row in m.batch.to_pylist())


def missing_chunks(per_machine: dict[str, np.ndarray], n_expected: int, args: argparse.Namespace) -> list:
    """The most common runs of missing samples, as ((first chunk, last chunk, samples missing), machines,
    first and last machine): machines consecutive in publishing order point at one lost transport batch."""
    per_chunk = max(1, int(round(args.chunk * RATE_HZ)))
    runs: Counter = Counter()
    machines: dict[tuple, list[str]] = defaultdict(list)
    for topic, t in per_machine.items():
        lost = np.setdiff1d(np.arange(n_expected), np.round(t * RATE_HZ).astype(int))
        if lost.size:
            run = (int(lost[0]) // per_chunk, int(lost[-1]) // per_chunk, int(lost.size))
            runs[run] += 1
            machines[run].append(topic.split("/")[2])
    return [(run, n, min(machines[run]), max(machines[run])) for run, n in runs.most_common(6)]


def last_counters(rows: list[tuple[str, dict]]) -> dict[str, dict]:
    """Each plant's and recorder's last heartbeat counters (messages in, out, undecodable): a plant that
    counted every message out and a recorder that counted fewer in lost them on the bus."""
    last: dict[str, dict] = {}
    for service_id, row in rows:
        if row["service"] in ("record", "plant"):
            last[service_id] = {k: row.get(k) for k in ("messages_in", "messages_out", "messages_undecodable",
                                                        "messages_dropped")}
    return last


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=1000)
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per machine (default 10)")
    parser.add_argument("--plants", type=int, default=1, help="publisher processes (shards of the fleet)")
    parser.add_argument("--recorders", type=int, default=1, help="recorder processes (shards of the fleet)")
    parser.add_argument("--chunk", type=float, default=0.1, help="seconds of samples per message (default 0.1)")
    parser.add_argument("--source", choices=("plant", "synthetic"), default="plant")
    parser.add_argument("--drop-every", type=int, default=0, metavar="N",
                        help="the plant leaves every N-th message off the bus (fault injection): the recorders "
                             "must fetch them from its history")
    parser.add_argument("--history", type=float, default=5.0, metavar="SECONDS",
                        help="simulated seconds of chunks each plant keeps for recovery (plant --history, default 5)")
    parser.add_argument("--scratch", type=Path, default=None,
                        help="folder for the temporary recordings (default: the system's temporary folder)")
    parser.add_argument("--publish-shard", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--bus-port", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.publish_shard is not None:  # the synthetic publisher's own process
        publish_synthetic(args.machines, args.seconds, args.chunk, args.bus_port, args.publish_shard)
        return
    load_before = os.getloadavg()
    port = free_port()
    rows: list[tuple[str, dict]] = []
    stop_watching = threading.Event()
    with tempfile.TemporaryDirectory(dir=args.scratch, prefix="bench-bus-") as tmp:
        out = Path(tmp)
        recorders = [Child([sys.executable, "-m", "services.recorder", "--out", str(out / f"s{i}"), "--fleet", FLEET,
                            "--shard", f"{i}/{args.recorders}", "--heartbeat", str(HEARTBEAT_S),
                            "--bus-port", str(port)]) for i in range(args.recorders)]
        plants: list[Child] = []
        children = list(recorders)
        watcher = threading.Thread(target=watch, args=(port, children, rows, stop_watching))
        try:
            with open_session(BusSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",))) as session:
                assert wait_alive(session, "record", FLEET, args.recorders, timeout=60), "recorders did not come up"
            watcher.start()
            common = ["--machines", str(args.machines), "--seconds", str(args.seconds), "--chunk", str(args.chunk),
                      "--bus-port", str(port)]
            if args.source == "plant":
                argv = [sys.executable, "-m", "services.plant", "--fleet", FLEET, "--speed", "inf",
                        "--wait-subscribers", "60", "--drop-every", str(args.drop_every),
                        "--history", str(args.history), *common]
                plants = [Child([*argv, "--shard", f"{i}/{args.plants}"]) for i in range(args.plants)]
            else:
                argv = [sys.executable, __file__, *common]
                plants = [Child([*argv, "--publish-shard", f"{i}/{args.plants}"]) for i in range(args.plants)]
            children += plants
            codes = [p.wait(timeout=600) for p in plants]
            for r in recorders:
                r.proc.send_signal(signal.SIGTERM)
            assert [r.wait(timeout=300) for r in recorders] == [0] * args.recorders and codes == [0] * args.plants
        finally:
            stop_watching.set()
            if watcher.is_alive():
                watcher.join()
            for child in (*recorders, *plants):
                child.proc.kill()
        per_machine, messages, first_ns = count_samples(out)
    load_after = os.getloadavg()
    n_expected = int(round(args.seconds * RATE_HZ))
    expected_t = np.arange(n_expected) / RATE_HZ
    complete = sum(t.size == n_expected and np.allclose(t, expected_t) for t in per_machine.values())
    samples = sum(t.size for t in per_machine.values())
    published = args.machines * n_expected
    # when each recorder had written its last message: its first heartbeat showing its final count
    beats: dict[str, list[tuple[float, int]]] = defaultdict(list)
    for service_id, row in rows:
        if row["service"] == "record":
            beats[service_id].append((row["time"], row["messages_out"]))
    done = max(min(t for t, n in b if n == max(n for _, n in b)) for b in beats.values())
    first = first_ns / 1e9 if first_ns is not None else float("nan")
    rate = samples / (done - first)
    plant_cpu = sum(p.cpu_between(first, done) for p in plants)
    recorder_cpu = sum(r.cpu_between(first, done) for r in recorders)
    print(f"source={args.source} machines={args.machines} simulated_s={args.seconds} chunk={args.chunk} s "
          f"publishers={args.plants} recorders={args.recorders}")
    print(f"published samples={published:,} recorded={samples:,} lost={published - samples} messages={messages:,} "
          f"machines with every sample exactly once={complete} of {args.machines}")
    counters = last_counters(rows)
    recovered = sum((c["messages_out"] or 0) - (c["messages_in"] or 0)
                    for k, c in counters.items() if k.startswith("record"))
    if recovered:  # the bus lost these (or --drop-every left them off): fetched from the plants' history
        print(f"  chunks the recorders fetched from the plants' history: {recovered}")
    if args.drop_every:
        print(f"  left off the bus on purpose: every {args.drop_every}th message; recorders' last heartbeats "
              f"(messages_dropped = chunks not recovered): {counters}")
    if published != samples:  # where the loss happened: before the recorder, at validation, or in the files
        print("  missing chunks ((first, last, samples), machines, first machine, last machine): "
              f"{missing_chunks(per_machine, n_expected, args)}")
        for service_id, b in sorted(last_counters(rows).items()):
            print(f"  {service_id}: last heartbeat {b}")
    print(f"throughput={rate:,.0f} samples/s over {done - first:.2f} s (first receive -> last write)  "
          f"ratio to reference {REFERENCE_SAMPLES_PER_S:,.0f}: {rate / REFERENCE_SAMPLES_PER_S:.2f}")
    for name, cpu in ((args.source, plant_cpu), ("recorder", recorder_cpu)):
        per_core = samples / cpu if cpu > 0 else float("inf")
        print(f"{name:>9}: {cpu:.2f} CPU s from first receive to last write, {per_core:,.0f} samples per CPU-second "
              f"({per_core / REFERENCE_SAMPLES_PER_S:.2f} x reference on one idle core)")
    bound = max(plant_cpu, recorder_cpu, (plant_cpu + recorder_cpu) / 2)
    print(f"CPU-bound estimate for these processes alone on 2 idle cores (not a measurement): "
          f"{samples / bound:,.0f} samples/s ({samples / bound / REFERENCE_SAMPLES_PER_S:.2f} x reference)")
    print(f"load average before {load_before[0]:.1f}, after {load_after[0]:.1f} (2 cores shared with other jobs)")


if __name__ == "__main__":
    main()
