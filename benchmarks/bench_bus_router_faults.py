"""Faults survived, measured (issue 18, item 3): kill -9 and restart the zenoh router, then the MLflow server, mid-run.

The router topology of tests/test_bus_topology.py (hydrowatch.testbed: a router process, an MLflow server process on
PostgreSQL, plant, two recorder shards, two scorer shards and the trainer as the router's clients, each on its own
host in a network namespace where permitted, else loopback). The trainer retrains every ``--retrain`` s on a
simulated training set and moves the alias; the scorers follow it (``--follow-alias 2``, one verdict per 5 s
window, ``--smoothing 1``); the plant runs ``--machines`` in real time. At ``--kill-at`` s the router is killed with
SIGKILL and restarted ``--down`` s later; ``--gap`` s after its return the MLflow server (its whole process group)
gets the same, and is restarted ``--down`` s later (it then needs ~10 s to answer). Printed per machine, as
benchmarks/bench_bus_faults.py:

* the longest stretch without verdicts heard by a client of the router (wall-clock s between consecutive verdicts,
  from the machine's first verdict to the end of the plant's run), and the machine's shard; also the longest of
  those that overlap the router's outage and the 15 s after its return, the MLflow server's outage (kill to
  answering again), and the 20 s after it answers (the scorers switch to the version registered meanwhile);
* samples lost to the recordings (published by the plant, in no recorder file), samples recorded twice;
* windows judged twice, invalid verdicts; the model versions the verdicts named.

And per service: whether it was still running at the end (a service must survive its router or MLflow restarting).

Usage::

    python benchmarks/bench_bus_router_faults.py [--machines 6] [--seconds 100] [--kill-at 20] [--down 10]
        [--gap 20] [--history 30] [--loopback] [--sqlite] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_bus_faults import recorded  # noqa: E402

from hydrowatch.bus import machine_hash, open_session, wait_alive  # noqa: E402
from hydrowatch.testbed import namespaces_unavailable, postgres_unavailable  # noqa: E402
from hydrowatch.testbed.topology import Topology, TopologySettings, VerdictLog  # noqa: E402

FLEET = "rfaults"


def training_set(folder: Path) -> Path:
    """Simulated recordings the trainer trains on (its default data plan: 177.5 s per state)."""
    from hydrowatch.io import write_recording
    from hydrowatch.plant.fleet import simulate_states

    folder.mkdir(parents=True)
    for rec in simulate_states(["healthy", "load_warning", "pump_leak_alert"], seconds=180, seed=0):
        write_recording(rec, folder / f"{rec.state}.mcap")
    return folder


def run(args: argparse.Namespace, work: Path) -> None:
    settings = TopologySettings(
        fleet=FLEET, machines=args.machines, states="healthy,load_warning,pump_leak_alert", speed=1.0,
        plant_seconds=args.seconds, history=args.history, retrain=args.retrain, rotate_s=10.0, follow_s=2.0,
        smoothing=1, namespaces=not args.loopback, postgres=not args.sqlite,
        train_data=str(training_set(work / "train")))  # the trainer trains on a simulated set
    load, events, exits = [os.getloadavg()[0]], [], {}
    with Topology(work, settings) as topology:
        for host in ("record-0", "record-1"):
            topology.start(host)
        topology.tracking.wait_ready(timeout=180)
        topology.start("trainer")
        for host in ("score-0", "score-1"):
            topology.start(host)
        with VerdictLog(topology.client_settings(), FLEET) as heard:
            with open_session(topology.client_settings()) as session:
                for name in ("record", "scorer"):
                    assert wait_alive(session, name, FLEET, 2, timeout=300), f"{name} did not come up"
            plant = topology.start("plant")
            began = time.monotonic()
            heard.began = began  # verdict times from the plant's start
            plan = [(args.kill_at, "kill", "router"), (args.kill_at + args.down, "start", "router"),
                    (args.kill_at + args.down + args.gap, "kill", "mlflow"),
                    (args.kill_at + 2 * args.down + args.gap, "start", "mlflow")]
            while plant.poll() is None:
                time.sleep(0.1)
                while plan and time.monotonic() - began >= plan[0][0]:
                    _, what, host = plan.pop(0)
                    topology.kill(host) if what == "kill" else topology.start(host)
                    events.append((f"{what} {host}", time.monotonic() - began))
                    if what == "start" and host == "mlflow":
                        ready = topology.tracking.wait_ready(timeout=120)
                        events.append(("mlflow answers", time.monotonic() - began))
                        del ready
            ended = time.monotonic() - began
            time.sleep(3)  # the last windows' verdicts
        load.append(os.getloadavg()[0])
        exits = {host: proc.returncode for host, proc in topology.processes.items() if proc.poll() is not None}
        codes = topology.close()
    report(args, heard.by_machine(), recorded(work / "recordings"), events, ended, load, exits, codes)


def _at(events: list[tuple[str, float]], name: str) -> float:
    return next(t for n, t in events if n == name)


def _longest(times: np.ndarray, gaps: np.ndarray, begin: float, end: float) -> float:
    """The longest stretch without verdicts that overlaps [begin, end]."""
    if times.size < 2:
        return float(gaps.max())
    overlapping = (times[1:] >= begin) & (times[:-1] <= end)
    return float(gaps[overlapping].max()) if overlapping.any() else 0.0


def report(args, verdicts, samples, events, ended, load, exits, codes) -> None:  # noqa: ANN001
    print(f"{args.machines} machines, plant {args.seconds:g} s in real time, 5 s windows, "
          f"{'loopback' if args.loopback else 'network namespaces'}, MLflow on "
          f"{'SQLite' if args.sqlite else 'PostgreSQL'}; load average {load[0]:.1f} at start, {load[1]:.1f} at end")
    print("events: " + ", ".join(f"{name} at {t:.1f} s" for name, t in events))
    faults = {"router": (_at(events, "kill router"), _at(events, "start router") + 15.0),
              "mlflow down": (_at(events, "kill mlflow"), _at(events, "mlflow answers")),
              "mlflow after": (_at(events, "mlflow answers"), _at(events, "mlflow answers") + 20.0)}
    print(f"{'machine':8} {'shard':>5} {'longest without verdicts: all':>30} {'router':>7} {'mlflow down':>11} "
          f"{'after':>7} {'samples lost':>13} {'recorded twice':>15} {'judged twice':>13} {'invalid':>8}  versions")
    expected = int(args.seconds * 200)
    for machine in sorted(f"m{i:03d}" for i in range(args.machines)):
        got = verdicts.get(machine, [])
        times = np.array([*(v.t for v in got if v.t <= ended), ended])
        gaps = np.diff(times) if got else np.array([ended])
        longest = {name: _longest(times, gaps, *window) for name, window in faults.items()}
        t = samples.get(machine, np.empty(0))
        unique = np.unique(np.round(t * 200).astype(np.int64)) if t.size else np.empty(0)
        twice = sum(n - 1 for n in Counter(v.window_start for v in got if v.state != "invalid").values())
        invalid = sum(v.state == "invalid" for v in got)
        versions = ",".join(sorted({v.model_version.rsplit("/", 1)[-1] for v in got}))
        print(f"{machine:8} {machine_hash(machine) % 2:>5} {gaps.max():>28.1f} s {longest['router']:>5.1f} s "
              f"{longest['mlflow down']:>9.1f} s {longest['mlflow after']:>5.1f} s {expected - unique.size:>13} "
              f"{t.size - unique.size:>15} {twice:>13} {invalid:>8}  {versions}")
    print("services that exited during the run: " + (", ".join(f"{h} ({c})" for h, c in exits.items()) or "none"))
    print("exit status at the end (SIGTERM): " + ", ".join(f"{h} {c}" for h, c in codes.items()))


def add_topology_arguments(parser: argparse.ArgumentParser, kept: str) -> None:
    """``--loopback``, ``--sqlite`` and ``--keep DIR`` (``kept``: what the folder keeps), for a benchmark of the
    router topology."""
    parser.add_argument("--loopback", action="store_true", help="hosts on loopback even where namespaces work")
    parser.add_argument("--sqlite", action="store_true", help="MLflow on SQLite even where PostgreSQL is installed")
    parser.add_argument("--keep", type=Path, default=None, metavar="DIR",
                        help=f"work in this new folder and keep it ({kept})")


def run_topology(args: argparse.Namespace, run: Callable[[argparse.Namespace, Path], None], prefix: str) -> None:
    """``run(args, work)`` in ``--keep``'s new folder or a temporary one, ``--loopback`` and ``--sqlite`` also set
    where namespaces or PostgreSQL are not available here."""
    args.loopback = args.loopback or namespaces_unavailable() is not None
    args.sqlite = args.sqlite or postgres_unavailable() is not None
    if args.keep is not None:
        args.keep.mkdir(parents=True)
        run(args, args.keep)
        return
    with tempfile.TemporaryDirectory(prefix=prefix) as work:
        run(args, Path(work))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=100.0, help="plant run, s (real time)")
    parser.add_argument("--kill-at", type=float, default=20.0, help="when the router is killed, s")
    parser.add_argument("--down", type=float, default=10.0, help="how long each killed process stays down, s")
    parser.add_argument("--gap", type=float, default=20.0, help="from the router's return to the MLflow kill, s")
    parser.add_argument("--history", type=float, default=30.0, help="plant's history for recovery, s")
    parser.add_argument("--retrain", type=float, default=30.0, help="trainer's --every, s")
    add_topology_arguments(parser, "recordings, each service's log")
    args = parser.parse_args()
    if args.kill_at + 2 * args.down + args.gap >= args.seconds - 15:
        parser.error("--seconds must leave the MLflow server's restart 15 s before the end")
    run_topology(args, run, "bench-router-faults-")


if __name__ == "__main__":
    main()
