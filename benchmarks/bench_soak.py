"""Soak (issue 18, item 4): N machines through the router topology for a long run; memory per service over time,
samples dropped, verdict latency.

The topology of tests/test_bus_topology.py (hydrowatch.testbed: a router process, an MLflow server on PostgreSQL, plant,
two recorder shards, two scorer shards, the trainer and the web service, each its own process and host; network
namespaces where permitted, else loopback), run with compose.yaml's settings where they matter for memory: recorders
close files every 1800 s and chunks every 1 s (their default), the plant keeps 30 s of history, scorers look at their
alias every 60 s. The trainer trains on a simulated set (as benchmarks/bench_bus_router_faults.py) every
``--retrain`` simulated s (1200 by default: every 20 min in real time, 80 min at ``--speed 0.25``) and moves the alias:
the scorers switch models. A new model starts each machine's attribution ring and forecast history again, and they take
300 simulated s to fill: with the trainer's period in wall-clock seconds a quarter-speed run never reached the scorers'
steady state (2026-11-27, 1 hour at 1000 machines: their memory rose in steps within each 20-minute model).
Scorers keep ``--forecast-history`` equal to the warm-up (in simulated s) so that their bounded forecast rings (81 kB
per machine at the default 2 h) are full once the warm-up ends; everything else is as deployed. The web's timelines
(360 windows per machine) fill for 1800 simulated s, by design; a shorter warm-up says so.

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

``--minutes 10`` is the 10-minute variant; ``--quick`` runs 3 minutes; the warm-up is a sixth of the run (at most 10
min), at least 75 simulated s (``SETTLE_SIM_S``), and at least the scorers' 300 s attribution rings where that is
under 60 % of the run (not in --quick: it says what is still filling). On the 2-core build machine: ``--quick
--machines 250``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_bus_router_faults import add_topology_arguments, run_topology, training_set  # noqa: E402
from soak_listen import FLEET, Verdicts, recorded_chunks  # noqa: E402

from hydrowatch.bus import open_session, wait_alive  # noqa: E402
from hydrowatch.bus.heap import holder_changes, memory_events  # noqa: E402
from hydrowatch.recording import SAMPLE_RATE_HZ  # noqa: E402
from hydrowatch.testbed.topology import Topology, TopologySettings  # noqa: E402
from hydrowatch.testbed.usage import UsageSampler, memory_trend  # noqa: E402

ROTATE_S = 1800.0
"""Recorders close a file every this many wall-clock s (compose.yaml's setting); their memory is judged per file."""
SETTLE_SIM_S = 75.0
"""Simulated s after which every fixed-size per-machine buffer but the web's timelines is full: the plant's 30 s
history, the scorers' 12-window pools and the web's 12 windows of evidence (60 s), plus 15 s. The warm-up is at least
this long (the quick run at first measured the plant's history filling: +1.2 GB at 1000 machines)."""
FILLING_SIM_S = {
    "scorers' attribution rings (60 windows per machine: hydrowatch.condition.degradation.ATTRIBUTION_WINDOWS)": 300.0,
    "web's timelines (360 windows per machine, ~80 B each: hydrowatch.web.live)": 1800.0,
}
"""Bounded buffers that fill for longer than :data:`SETTLE_SIM_S`: what → simulated s. The default warm-up of a run
longer than --quick covers the scorers' rings; the web's take 30 min. In-process the scorer's core grew 2 B per window
once its ring was full (tracemalloc, 50 machines, 3,800 windows)."""
SERVICES = ("router", "plant", "record-0", "record-1", "score-0", "score-1", "trainer", "web", "mlflow", "postgres")


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


def registry_load(topology: Topology, looks: int = 20) -> str:
    """What the MLflow server answers: the time of one alias look-up (what each scorer does every --follow-alias s),
    over ``looks`` of them, and the artifacts stored per registered version (what each scorer downloads when the
    alias moves)."""
    from mlflow import MlflowClient

    s = topology.settings
    client = MlflowClient(tracking_uri=topology.tracking_uri, registry_uri=topology.tracking_uri)
    took = []
    for _ in range(looks):
        began = time.perf_counter()
        version = client.get_model_version_by_alias(s.model_name, s.alias).version
        took.append(time.perf_counter() - began)
    stored = sum(p.stat().st_size for p in (topology.work / "mlartifacts").rglob("*") if p.is_file())
    return (f"MLflow ({topology.backend}): alias look-up p50 {np.median(took) * 1e3:.0f} ms, max "
            f"{max(took) * 1e3:.0f} ms over {looks}; {version} versions registered, {stored / 1e6:.2f} MB of "
            f"artifacts ({stored / 1e6 / int(version):.2f} MB per version)")


def run(args: argparse.Namespace, work: Path) -> None:
    seconds = args.minutes * 60.0
    warmup_sim = args.warmup_minutes * 60.0 * args.speed
    settings = TopologySettings(
        fleet=FLEET, machines=args.machines, states="healthy,pump_leak_warning,motor_leak_alert", speed=args.speed,
        plant_seconds=seconds * args.speed, history=30.0, retrain=args.retrain / args.speed, rotate_s=ROTATE_S,
        flush_s=1.0,
        follow_s=60.0, namespaces=not args.loopback, postgres=not args.sqlite,
        train_data=str(training_set(work / "train")),
        extra={f"score-{i}": ("--forecast-history", f"{warmup_sim:g}") for i in range(2)})
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
        registry = registry_load(topology)
        codes = topology.close()
        starts, rows, totals = recorded_chunks(topology.recordings)
    report(args, usage, verdicts, starts, rows, began, began_ns, ended_at, load, codes, topology)
    print(recordings_line(args, totals))
    print(registry)


def rotation_peaks(t: np.ndarray, rss: np.ndarray, began: float, ended: float) -> list[float]:
    """Peak RSS, MB, in each whole :data:`ROTATE_S` period from the plant's start: a recorder's memory grows with the
    open file's chunk index and falls when it closes the file, so its bound is the peak per file, not a slope."""
    period = np.floor((t - began) / ROTATE_S)
    whole = (t >= began) & (period < int((ended - began) // ROTATE_S))
    return [float(rss[whole & (period == k)].max()) / 1e6 for k in np.unique(period[whole])]


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
    for name in [n for n in verdicts if n.startswith("record-")]:
        t, rss, _ = usage.series(name)
        peaks = rotation_peaks(t, rss, began, ended)
        if len(peaks) >= 2:
            rise = (peaks[-1] - peaks[0]) / ((len(peaks) - 1) * ROTATE_S / 3600.0)
            if rise < args.flat_mb_h:
                verdicts[name] = "bounded"
            print(f"{name}: peak per {ROTATE_S / 60:g}-min file " + ", ".join(f"{x:.1f}" for x in peaks)
                  + f" MB ({rise:+.1f} MB/h from file to file): {verdicts[name]} by its file rotation")
    for what, fill_s in FILLING_SIM_S.items():
        if args.warmup_minutes * 60.0 * args.speed < fill_s:
            print(f"(still filling after the warm-up, by design: the {what}, until {fill_s:g} simulated s, "
                  f"{fill_s / args.speed / 60:g} min here)")
    flat = all(v in ("flat", "bounded") for v in verdicts.values())
    print(f"memory flat after warm-up (every service's slope below {args.flat_mb_h:g} MB/h at 95 %, a recorder's peak "
          f"per file): {'yes' if flat else 'NO'}" + ("" if flat else " — " + ", ".join(
              f"{n} {v}" for n, v in verdicts.items() if v not in ("flat", "bounded"))))


def holders_table(logs: Path, after_s: float, ended_s: float) -> None:
    """What each service holds, from its own ``memory`` events after the warm-up (first → last, and per hour): which
    allocator, if any, holds what its resident set gained (hydrowatch.bus.heap.holder_changes)."""
    print("\nwhat each service holds (its own 'memory' events after the warm-up, first -> last [per hour]; MB, "
          "python_blocks in thousands):")
    for name in SERVICES:
        log = logs / f"{name}.log"
        logged = memory_events(log.read_text(errors="replace")) if log.exists() else []
        events = [(t, e) for t, e in logged if after_s <= t <= ended_s + 60.0]
        if not logged:  # not a hydrowatch service (router, MLflow, PostgreSQL)
            continue
        if len(events) < 2:
            print(f"{name:10} fewer than two memory events after the warm-up ({len(logged)} in all)")
            continue
        cells = []
        for k, (a, b, per_hour) in holder_changes(events).items():
            scale = 1e-3 if k == "python_blocks" else 1.0
            cells.append(f"{k.removesuffix('_mb')} {a * scale:.1f} -> {b * scale:.1f} [{per_hour * scale:+.1f}]")
        minutes = (events[-1][0] - events[0][0]) / 60.0
        print(f"{name:10} {len(events)} events over {minutes:.0f} min: " + ", ".join(cells))


def recordings_line(args: argparse.Namespace, totals: Counter[str]) -> str:
    """Bytes on disk and on the wire per machine, from the recordings."""
    machine_s = args.machines * args.minutes * 60.0 * args.speed
    return (f"recordings: {totals['file_bytes'] / 1e6:.1f} MB in {totals['files']} files, "
            f"{totals['file_bytes'] / machine_s / 1e3:.2f} kB per machine-second of data; payloads (as published) "
            f"{totals['payload_bytes'] / max(totals['messages'], 1):.0f} B per message, "
            f"{totals['payload_bytes'] / machine_s / 1e3:.2f} kB per machine-second")


def report(args, usage, verdicts, starts, rows, began, began_ns, ended, load, codes, topology) -> None:  # noqa: ANN001
    seconds = args.minutes * 60.0
    print(f"soak: {args.machines} machines at speed {args.speed:g} ({args.machines * args.speed:g} machine-s per s), "
          f"{args.minutes:g} min, {'network namespaces' if not args.loopback else 'loopback'}, MLflow on "
          f"{topology.backend}; plant realised speed {verdicts.plant_speed():.3f}; load average (1/5/15 min) "
          f"{'/'.join(f'{x:.1f}' for x in load[0])} before, {'/'.join(f'{x:.1f}' for x in load[1])} at the end; "
          f"{os.cpu_count()} cores")
    memory_table(args, usage, began, ended)
    holders_table(topology.logs, began_ns / 1e9 + args.warmup_minutes * 60.0, began_ns / 1e9 + (ended - began))
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
    print("payload per message: " + ", ".join(
        f"{topic} {verdicts.bytes[topic] / verdicts.bytes[f'{topic} messages']:.0f} B"
        for topic in ("sensors", "health", "kl") if verdicts.bytes[f"{topic} messages"]))
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
    parser.add_argument("--quick", action="store_true",
                        help="3 minutes, samples every 2 s (with --machines 250 for 2 cores)")
    parser.add_argument("--interval", type=float, default=5.0, help="seconds between memory samples")
    parser.add_argument("--retrain", type=float, default=1200.0,
                        help="simulated s between trainings (the trainer's --every is this / --speed)")
    parser.add_argument("--flat-mb-h", type=float, default=5.0, help="memory slope below which a service is flat")
    add_topology_arguments(parser, "recordings, each service's log, memory.csv")
    args = parser.parse_args()
    if args.quick:
        args.minutes, args.interval = 3.0, 2.0
    settle = SETTLE_SIM_S / args.speed / 60.0
    if args.warmup_minutes is None:
        rings = (min(FILLING_SIM_S.values()) + 15.0) / args.speed / 60.0  # the scorers' rings, where the run allows
        args.warmup_minutes = max(settle, min(args.minutes / 6, 10.0), rings if rings < 0.6 * args.minutes else 0.0)
    if not settle <= args.warmup_minutes < args.minutes:
        parser.error(f"--warmup-minutes must be at least {settle:.2f} ({SETTLE_SIM_S:g} simulated s: fixed-size "
                     f"buffers fill) and shorter than --minutes ({args.minutes:g}); fewer machines at a higher "
                     "--speed shorten it")
    run_topology(args, run, "bench-soak-")


if __name__ == "__main__":
    main()
