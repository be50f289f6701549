"""Soak (issue 18, item 4): N machines through the router topology for a long run; memory per service over time,
samples dropped, verdict latency.

The topology of tests/test_bus_topology.py (hydrowatch.testbed: a router process, an MLflow server on PostgreSQL, plant,
two recorder shards, two scorer shards, the trainer and the web service, each its own process and host; network
namespaces where permitted, else loopback), run with compose.yaml's settings where they matter for memory: recorders
close files every 1800 s and chunks every 1 s (their default), the plant keeps 30 s of history, scorers look at their
alias every 60 s. The trainer trains on a simulated set (as benchmarks/bench_bus_router_faults.py) every
``--retrain`` s and moves the alias: the scorers switch models during the run. Scorers keep ``--forecast-history``
equal to the warm-up (in simulated s) so that their bounded forecast rings (46 kB per machine at the default 2 h)
are full once the warm-up ends; everything else is as deployed.

Measured:

* **memory per service**: RSS of each service's process tree (hydrowatch.testbed.usage) every ``--interval`` s;
  printed after the warm-up, at the middle and at the end of the rest, the peak, and the Theil–Sen slope after the
  warm-up in MB/h with its 95 % interval. Verdict per service: ``flat`` when the interval's upper end is below
  ``--flat-mb-h`` (default 5 MB/h: 120 MB a day, under a tenth of what a scorer of 1000 machines holds, so a week
  between restarts costs less than the service itself), ``growing`` when its lower end is above, else
  ``undecided``; and CPU per service (cores, over the run after the warm-up);
* **samples dropped**: what the plant published (every machine, every 1/200 s of its ``--seconds``) against what
  the recorders' files hold (each chunk's start and rows, read without decoding the samples), and samples
  recorded twice;
* **verdict latency**: window end → verdict received by a client of the router in this process. The window's end
  is the publish time (bus attachment) of the sensor chunk that ends it: every machine's chunks of one step go
  out in one burst, so one machine's (m000's) chunks date every window. p50 / p99 / max after the warm-up; and
  windows judged twice, invalid verdicts, the plant's realised speed.

Usage::

    python benchmarks/bench_soak.py [--machines 1000] [--minutes 60] [--speed 1] [--quick] [--loopback] [--sqlite]
        [--warmup-minutes M] [--interval S] [--retrain S] [--keep DIR]

``--minutes 10`` is the 10-minute variant; ``--quick`` runs 3 minutes (1 of warm-up) for a small machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_bus_router_faults import add_topology_arguments, run_topology, training_set  # noqa: E402

from hydrowatch.bus import BusSettings, Subscriber, open_session, wait_alive  # noqa: E402
from hydrowatch.io.codec import check_payload  # noqa: E402
from hydrowatch.io.mcap_io import expected_schema, iter_records  # noqa: E402
from hydrowatch.recording import SAMPLE_RATE_HZ  # noqa: E402
from hydrowatch.testbed.topology import Topology, TopologySettings  # noqa: E402
from hydrowatch.testbed.usage import UsageSampler, memory_trend  # noqa: E402

FLEET = "soak"
SERVICES = ("router", "plant", "record-0", "record-1", "score-0", "score-1", "trainer", "web", "mlflow", "postgres")


class Verdicts:
    """Verdicts of every machine and m000's sensor chunks, heard by a client of the router (a thread)."""

    def __init__(self, settings: BusSettings) -> None:
        self.settings = settings
        self.chunk_published: dict[int, int] = {}
        """m000's chunks: end (sample index, exclusive) → publish time, ns since the epoch."""
        self.heard: list[tuple[int, int, int]] = []
        """(received ns, window end as a sample index, 1 when invalid) per verdict."""
        self.windows: Counter[tuple[str, int]] = Counter()
        """(machine, window start sample index) → verdicts (not invalid)."""
        self._ready, self._done = threading.Event(), threading.Event()
        self._thread = threading.Thread(target=self._listen, name="verdicts", daemon=True)

    def _listen(self) -> None:
        with open_session(self.settings) as session, \
                Subscriber(session, [f"hydro/{FLEET}/*/health", f"hydro/{FLEET}/m000/sensors"]) as sub:
            self._ready.set()
            while not self._done.is_set():
                for message in sub.recv_many(timeout=0.2):
                    if message.key.topic == "sensors":
                        span = message.time_span()
                        if span is not None:
                            end = round(span[1] * SAMPLE_RATE_HZ) + 1
                            self.chunk_published[end] = message.publish_time_ns
                        continue
                    batch = message.batch
                    starts, ends = batch.column("window_start").to_pylist(), batch.column("window_end").to_pylist()
                    for start, end, state in zip(starts, ends, batch.column("state").to_pylist()):
                        self.heard.append((message.receive_time_ns, round(end * SAMPLE_RATE_HZ), state == "invalid"))
                        if state != "invalid":
                            self.windows[(message.key.machine, round(start * SAMPLE_RATE_HZ))] += 1

    def latencies_ms(self, after_ns: int) -> np.ndarray:
        """Window end → verdict received, ms, for verdicts received after ``after_ns`` whose window end is dated."""
        found = [(received - self.chunk_published[end]) / 1e6 for received, end, _ in list(self.heard)
                 if received >= after_ns and end in self.chunk_published]
        return np.asarray(found)

    def plant_speed(self) -> float:
        """Simulated s per wall-clock s between m000's first and last chunk."""
        ends = sorted(self.chunk_published)
        wall = (self.chunk_published[ends[-1]] - self.chunk_published[ends[0]]) / 1e9
        return (ends[-1] - ends[0]) / SAMPLE_RATE_HZ / wall if wall > 0 else float("nan")

    def __enter__(self) -> Verdicts:
        self._thread.start()
        if not self._ready.wait(60):
            raise RuntimeError("the verdict listener did not join the bus in 60 s")
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._thread.join(timeout=30)


def recorded_chunks(folder: Path) -> tuple[dict[str, Counter[int]], dict[int, int]]:
    """Per machine, how often each chunk start (sample index) is in the files under ``folder`` (every shard's),
    and rows per chunk start seen; read from each record's head and first time, the samples not decoded."""
    starts: dict[str, Counter[int]] = {}
    rows: dict[int, int] = {}
    for path in sorted(folder.rglob("*.mcap")):
        found = starts.setdefault(path.parent.name, Counter())
        for channel, schema, record in iter_records(path):
            expected = expected_schema(channel, schema)
            if expected is None or not channel.topic.endswith("/sensors"):
                continue
            layout = check_payload(record.data, expected, str(path))
            start = round(layout.start_time(record.data) * SAMPLE_RATE_HZ)  # type: ignore[operator]
            found[start] += 1
            rows[start] = layout.rows
    return starts, rows


def pids(topology: Topology) -> dict[str, int]:
    """Service → process id, for the services running now (PostgreSQL: its postmaster)."""
    found = {host: proc.pid for host, proc in topology.processes.items() if proc.poll() is None}
    if topology.tracking is not None and topology.tracking.process is not None:
        found["mlflow"] = topology.tracking.process.pid
    if topology.postgres is not None and topology.postgres.folder is not None:
        with_pid = topology.postgres.folder / "data" / "postmaster.pid"
        if with_pid.exists():
            found["postgres"] = int(with_pid.read_text().split()[0])
    return found


def run(args: argparse.Namespace, work: Path) -> None:
    seconds = args.minutes * 60.0
    warmup_sim = args.warmup_minutes * 60.0 * args.speed
    settings = TopologySettings(
        fleet=FLEET, machines=args.machines, states="healthy,pump_leak_warning,motor_leak_alert", speed=args.speed,
        plant_seconds=seconds * args.speed, history=30.0, retrain=args.retrain, rotate_s=1800.0, flush_s=1.0,
        follow_s=60.0, namespaces=not args.loopback, postgres=not args.sqlite,
        train_data=str(training_set(work / "train")),
        extra={f"score-{i}": ("--forecast-history", f"{max(warmup_sim, 60.0):g}") for i in range(2)})
    load = [os.getloadavg()]
    with Topology(work, settings) as topology:
        for host in ("record-0", "record-1", "web"):
            topology.start(host)
        topology.tracking.wait_ready(timeout=180)  # type: ignore[union-attr]
        topology.start("trainer")
        for host in ("score-0", "score-1"):
            topology.start(host)
        with Verdicts(topology.client_settings()) as verdicts, \
                UsageSampler(lambda: pids(topology), args.interval) as usage:
            with open_session(topology.client_settings()) as session:
                for name in ("record", "scorer"):
                    assert wait_alive(session, name, FLEET, 2, timeout=600), f"{name} did not come up"
            plant = topology.start("plant")
            began = time.monotonic()
            began_ns = time.time_ns()
            while plant.poll() is None:
                ended = {h: p.returncode for h, p in topology.processes.items() if p.poll() is not None}
                if ended:
                    raise RuntimeError(f"{ended} exited during the run; logs in {topology.logs}")
                time.sleep(1.0)
            ended_at = time.monotonic()
            load.append(os.getloadavg())
            time.sleep(5)  # the last windows' verdicts
        codes = topology.close()
        starts, rows = recorded_chunks(topology.recordings)
    report(args, usage, verdicts, starts, rows, began, began_ns, ended_at, load, codes, topology)


def memory_table(args: argparse.Namespace, usage: UsageSampler, began: float, ended: float) -> None:
    after = began + args.warmup_minutes * 60.0
    middle = (after + ended) / 2
    print(f"\nmemory per service (RSS of its process tree, MB; sampled every {args.interval:g} s; warm-up "
          f"{args.warmup_minutes:g} min; slope after the warm-up, Theil-Sen, 95 % interval):")
    print(f"{'service':10} {'at start':>9} {'warm-up end':>12} {'middle':>8} {'end':>8} {'peak':>8} "
          f"{'slope MB/h [95 %]':>26} {'verdict':>10} {'cores':>6}")
    verdicts = {}
    for name in [n for n in SERVICES if n in usage.names()]:
        t, rss, cpu = usage.series(name)
        steady = (t >= after) & (t <= ended)

        def at(moment: float, t: np.ndarray = t, rss: np.ndarray = rss) -> float:
            return float(rss[np.argmin(np.abs(t - moment))]) / 1e6

        if steady.sum() < 3:
            print(f"{name:10} too few samples after the warm-up")
            continue
        trend = memory_trend(t[steady], rss[steady])
        verdicts[name] = trend.verdict(args.flat_mb_h)
        cores = (cpu[steady][-1] - cpu[steady][0]) / (t[steady][-1] - t[steady][0])
        print(f"{name:10} {at(began):>9.1f} {at(after):>12.1f} {at(middle):>8.1f} {at(ended):>8.1f} "
              f"{rss[steady].max() / 1e6:>8.1f} {trend.slope:>+9.1f} [{trend.low:>+7.1f}, {trend.high:>+7.1f}] "
              f"{verdicts[name]:>10} {cores:>6.2f}")
    flat = all(v == "flat" for v in verdicts.values())
    print(f"memory flat after warm-up (every service's slope below {args.flat_mb_h:g} MB/h at 95 %): "
          f"{'yes' if flat else 'NO'}" + ("" if flat else " — " + ", ".join(
              f"{n} {v}" for n, v in verdicts.items() if v != "flat")))


def report(args, usage, verdicts, starts, rows, began, began_ns, ended, load, codes, topology) -> None:  # noqa: ANN001
    seconds = args.minutes * 60.0
    print(f"soak: {args.machines} machines at speed {args.speed:g} ({args.machines * args.speed:g} machine-s per s), "
          f"{args.minutes:g} min, {'network namespaces' if not args.loopback else 'loopback'}, MLflow on "
          f"{topology.backend}; plant realised speed {verdicts.plant_speed():.3f}; load average (1/5/15 min) "
          f"{'/'.join(f'{x:.1f}' for x in load[0])} before, {'/'.join(f'{x:.1f}' for x in load[1])} at the end; "
          f"{os.cpu_count()} cores")
    memory_table(args, usage, began, ended)
    per_machine = round(seconds * args.speed * SAMPLE_RATE_HZ)
    published = args.machines * per_machine
    machines = [f"m{i:03d}" for i in range(args.machines)]
    held = sum(rows.get(s, 0) for m in machines for s in starts.get(m, {}) if s < per_machine)
    twice = sum(rows.get(s, 0) * (n - 1) for m in machines for s, n in starts.get(m, {}).items())
    short = sorted(m for m in machines if sum(rows.get(s, 0) for s in starts.get(m, {})) < per_machine)
    print(f"\nsamples: published {published:,}, recorded {held:,}, dropped {published - held:,} "
          f"({(published - held) / published:.2e}); recorded twice {twice:,}; machines missing samples: "
          f"{len(short)}{' (' + ', '.join(short[:5]) + ('…' if len(short) > 5 else '') + ')' if short else ''}")
    after_ns = began_ns + int(args.warmup_minutes * 60e9)
    ms = verdicts.latencies_ms(after_ns)
    heard = list(verdicts.heard)
    judged_twice = sum(n - 1 for n in verdicts.windows.values())
    print(f"verdicts: {len(heard):,} heard, {sum(i for _, _, i in heard):,} invalid, {judged_twice:,} windows judged "
          f"twice; machines with verdicts {len({m for m, _ in verdicts.windows})} of {args.machines}")
    if ms.size:
        p50, p99, worst = np.percentile(ms, [50, 99, 100])
        print(f"verdict latency after the warm-up (window end → verdict received, {ms.size:,} verdicts): "
              f"p50 {p50:.0f} ms, p99 {p99:.0f} ms, max {worst:.0f} ms")
    print("exit status at the end (SIGTERM): " + ", ".join(f"{h} {c}" for h, c in codes.items()))
    if args.keep is not None:
        with (args.keep / "memory.csv").open("w") as out:
            out.write("t_s,service,rss_bytes,cpu_s\n")
            for t, found in usage.samples:
                for name, u in found.items():
                    out.write(f"{t - began:.1f},{name},{u.rss},{u.cpu_s:.2f}\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=1000)
    parser.add_argument("--speed", type=float, default=1.0, help="plant speed, simulated s per s (below 1 where the "
                        "machine cannot keep up with --machines in real time)")
    parser.add_argument("--minutes", type=float, default=60.0, help="wall-clock minutes the plant runs")
    parser.add_argument("--warmup-minutes", type=float, default=None,
                        help="left out of the memory slope and latency (default: a sixth of the run, at most 10)")
    parser.add_argument("--quick", action="store_true", help="3 minutes, 1 of warm-up, samples every 2 s")
    parser.add_argument("--interval", type=float, default=5.0, help="seconds between memory samples")
    parser.add_argument("--retrain", type=float, default=1200.0, help="trainer's --every, s")
    parser.add_argument("--flat-mb-h", type=float, default=5.0, help="memory slope below which a service is flat")
    add_topology_arguments(parser, "recordings, each service's log, memory.csv")
    args = parser.parse_args()
    if args.quick:
        args.minutes, args.interval = 3.0, 2.0
        args.warmup_minutes = 1.0 if args.warmup_minutes is None else args.warmup_minutes
    if args.warmup_minutes is None:
        args.warmup_minutes = min(args.minutes / 6, 10.0)
    if not 0 <= args.warmup_minutes < args.minutes:
        parser.error("--warmup-minutes must be >= 0 and shorter than --minutes")
    run_topology(args, run, "bench-soak-")


if __name__ == "__main__":
    main()
