"""Faults survived, measured (issue 18, item 3): kill -9 and restart a recorder shard, then a scorer shard, mid-run.

Two recorder shards and two scorer shards (``--shard i/2``, shards that take over: docs/bus.md) run as processes
on one loopback bus beside the plant in real time (a tiny parity model, trained first, 5 s windows). At
``--kill-at`` s recorder shard 1 is killed with SIGKILL and restarted ``--down`` s later; ``--down`` s after its
return scorer shard 1 gets the same. Printed per machine:

* the longest stretch without verdicts (wall-clock seconds between consecutive verdicts, from the machine's first
  verdict to the end of the plant's run; one window, 5 s, in steady state), and the machine's home shard (1: the
  killed one);
* samples lost to the recordings: samples the plant published that no recorder file holds (every shard's files
  together), and samples recorded twice (two shards at once while their views of who is alive differed);
* windows judged twice (two verdicts of the same machine with the same window start), and invalid verdicts.

Usage::

    python benchmarks/bench_bus_faults.py [--machines 6] [--seconds 60] [--kill-at 12] [--down 10] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from hydrowatch.bus import BusSettings, Subscriber, free_port, machine_hash, open_session, wait_alive
from hydrowatch.io.codec import arrays_from_sensor_chunk
from hydrowatch.io.mcap_io import iter_messages

FLEET = "faults"


def parity_bundle(folder: Path) -> Path:
    """A small parity model (5 s windows); what it judges does not matter here, only that it judges."""
    from hydrowatch.health.plan import DataPlan
    from hydrowatch.plant.fleet import simulate_states
    from hydrowatch.training.options import TrainingSettings
    from hydrowatch.training.trainer import train

    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    states = ["healthy", "load_alert", "pump_leak_alert"]
    recordings = simulate_states(states, seconds=plan.samples_per_state / 200 + 1, seed=0)
    result = train({r.state: [r] for r in recordings}, TrainingSettings(method="parity", plan=plan))
    return result.bundle.save(folder / "model")


def service(module: str, port: int, log: Path, *argv: object) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", module, "-v", *map(str, argv), "--bus-port", str(port)],
                            stderr=log.open("ab"))


def recorded(folder: Path) -> dict[str, np.ndarray]:
    """Every sample time each machine's files hold, over every shard's folder (duplicates kept)."""
    found: dict[str, list[np.ndarray]] = {}
    for path in sorted(folder.rglob("*.mcap")):
        for _, batch, _ in iter_messages(path):
            found.setdefault(path.parent.name, []).append(arrays_from_sensor_chunk(batch)[0])
    return {m: np.concatenate(parts) for m, parts in found.items()}


def run(args: argparse.Namespace, work: Path) -> None:
    port, logs = free_port(), work / "logs"
    logs.mkdir()
    model = parity_bundle(work)
    recorders = {i: service("services.recorder", port, logs / f"record{i}.log", "--out", work / "rec" / f"s{i}",
                            "--fleet", FLEET, "--shard", f"{i}/2", "--flush", 0.2) for i in range(2)}
    scorers = {i: service("services.scorer", port, logs / f"scorer{i}.log", "--model", model, "--fleet", FLEET,
                          "--shard", f"{i}/2", "--smoothing", 1) for i in range(2)}
    everyone = [*recorders.values(), *scorers.values()]
    verdicts: dict[str, list[tuple[float, float, str]]] = {}
    events: list[tuple[str, float]] = []
    load = [os.getloadavg()[0]]
    try:
        with open_session(BusSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",))) as session, \
                Subscriber(session, f"hydro/{FLEET}/*/health") as health:
            for name, count in (("record", 2), ("scorer", 2)):
                assert wait_alive(session, name, FLEET, count, timeout=180), f"{name} did not come up"
            plant = service("services.plant", port, logs / "plant.log", "--fleet", FLEET, "--machines",
                            args.machines, "--seconds", args.seconds, "--speed", 1, "--states",
                            "healthy,load_alert,pump_leak_alert", "--wait-subscribers", 60)
            everyone.append(plant)
            assert wait_alive(session, "plant", FLEET, timeout=120)
            began = time.monotonic()
            plan = [(args.kill_at, "kill", "record"), (args.kill_at + args.down, "start", "record"),
                    (args.kill_at + 2 * args.down, "kill", "scorer"), (args.kill_at + 3 * args.down, "start", "scorer")]
            while plant.poll() is None:
                for message in health.recv_many(timeout=0.2):
                    for row in message.batch.to_pylist():
                        verdicts.setdefault(message.key.machine, []).append(
                            (time.monotonic() - began, float(row["window_start"]), row["state"]))
                while plan and time.monotonic() - began >= plan[0][0]:
                    _, what, name = plan.pop(0)
                    if what == "kill":
                        (recorders if name == "record" else scorers)[1].send_signal(signal.SIGKILL)
                    elif name == "record":
                        recorders[1] = service("services.recorder", port, logs / "record1b.log", "--out",
                                               work / "rec" / "s1b", "--fleet", FLEET, "--shard", "1/2", "--flush", 0.2)
                        everyone.append(recorders[1])
                    else:
                        scorers[1] = service("services.scorer", port, logs / "scorer1b.log", "--model", model,
                                             "--fleet", FLEET, "--shard", "1/2", "--smoothing", 1)
                        everyone.append(scorers[1])
                    events.append((f"{what} {name} 1/2", time.monotonic() - began))
            ended = time.monotonic() - began
            load.append(os.getloadavg()[0])
            for proc in [*recorders.values(), *scorers.values()]:
                proc.send_signal(signal.SIGTERM)
                proc.wait(timeout=120)
    finally:
        for proc in everyone:
            proc.kill()
    report(args, verdicts, recorded(work / "rec"), events, ended, load)


def report(args: argparse.Namespace, verdicts: dict[str, list[tuple[float, float, str]]],
           samples: dict[str, np.ndarray], events: list[tuple[str, float]], ended: float, load: list[float]) -> None:
    print(f"{args.machines} machines, plant {args.seconds} s in real time, 5 s windows; load average "
          f"{load[0]:.1f} at start, {load[1]:.1f} at end; "
          + ", ".join(f"{name} at {t:.1f} s" for name, t in events))
    print(f"{'machine':8} {'shard':>5} {'longest without verdicts':>25} {'samples lost':>13} {'recorded twice':>15} "
          f"{'judged twice':>13} {'invalid':>8}")
    expected = int(args.seconds * 200)
    for machine in sorted(f"m{i:03d}" for i in range(args.machines)):
        got = verdicts.get(machine, [])
        times = [*(t for t, _, _ in got), ended]
        longest = max(np.diff(times)) if got else ended
        t = samples.get(machine, np.empty(0))
        unique = np.unique(np.round(t * 200).astype(np.int64)) if t.size else np.empty(0)
        twice = sum(n - 1 for n in Counter(start for _, start, state in got if state != "invalid").values())
        invalid = sum(state == "invalid" for _, _, state in got)
        print(f"{machine:8} {machine_hash(machine) % 2:>5} {longest:>23.1f} s {expected - unique.size:>13} "
              f"{t.size - unique.size:>15} {twice:>13} {invalid:>8}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=60.0, help="plant run, s (real time)")
    parser.add_argument("--kill-at", type=float, default=12.0, help="when recorder shard 1 is killed, s")
    parser.add_argument("--down", type=float, default=10.0, help="how long each killed shard stays down, s")
    parser.add_argument("--keep", type=Path, default=None, metavar="DIR",
                        help="work in this new folder and keep it (recordings, model, each service's log)")
    args = parser.parse_args()
    if args.kill_at + 3 * args.down >= args.seconds - 5:
        parser.error("--seconds must leave the last restart 5 s before the end")
    if args.keep is not None:
        args.keep.mkdir(parents=True)
        run(args, args.keep)
        return
    with tempfile.TemporaryDirectory(prefix="bench-faults-") as work:
        run(args, Path(work))


if __name__ == "__main__":
    main()
