"""Full training on the study's data plan, timed (issue 5: "under 10 minutes on 2 cores").

The study's data set (7 health states × 1250 s at 200 Hz, filtered noise 0–4 V, one recording per
state, section 6.3) is simulated and written as MCAP, then trained exactly as ``hydrowatch train
--full-plan`` does (:func:`hydrowatch.training.pipeline.train_each`, MLflow in a temporary SQLite
store, bundles registered): by default the three pipelines of ``--method all`` (Box-Jenkins
reference models, NARX reference models, the parity model), each a separate run. ``--narx 15,15,35``
times the study's NARX size instead of hydrowatch's default (4,4,8).

Printed per stage: wall and CPU seconds, and the total against the reference of 600 s. Wall time is
what the target names; on a shared machine it is pessimistic (the load average is printed).

    python benchmarks/bench_training.py [--seconds 1250] [--narx 4,4,8] [--methods all]
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

from hydrowatch.io import write_recording
from hydrowatch.plant.faults import STUDY_STATES
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.training.options import GROUPS, add_training_arguments, settings_list_from_args
from hydrowatch.training.pipeline import train_each

REFERENCE_S = 600.0
"""Issue 5: full training on the study's data plan in under 10 minutes on 2 cores."""


def cpu_seconds() -> float:
    """CPU time of this process and its finished children (all threads), s."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=1250.0, help="recorded seconds per state (study: 1250)")
    add_training_arguments(parser)
    args = parser.parse_args()
    args.full_plan = True  # the study's plan is what is timed
    settings = settings_list_from_args(args)
    print(f"plan: {settings[0].plan}; pipelines: {[s.name for s in settings]} (--method {args.method}, "
          f"groups {GROUPS}); load average {os.getloadavg()[0]:.2f}")
    stages: list[tuple[str, float, float]] = []
    with tempfile.TemporaryDirectory(prefix="hydrowatch-bench-train-") as tmp:
        root = Path(tmp)
        data = root / "data"
        data.mkdir()
        wall, cpu = time.perf_counter(), cpu_seconds()
        for r in simulate_states(STUDY_STATES, seconds=args.seconds, seed=0):
            write_recording(r, data / f"{r.state}.mcap")
        stages.append(("simulate + write MCAP", time.perf_counter() - wall, cpu_seconds() - cpu))
        uri = f"sqlite:///{root / 'mlflow.db'}"
        wall, cpu = time.perf_counter(), cpu_seconds()
        for summary in train_each(data, root / "model", settings, tracking=uri, experiment="bench"):
            now, now_cpu = time.perf_counter(), cpu_seconds()
            name = summary.get("reference") or summary["method"]
            stages.append((f"train {name} (test accuracy {summary['test_accuracy']:.3f})", now - wall, now_cpu - cpu))
            wall, cpu = now, now_cpu
    print(f"{'stage':<52} {'wall s':>8} {'CPU s':>8}")
    for name, w, c in stages:
        print(f"{name:<52} {w:8.1f} {c:8.1f}")
    total_wall = sum(w for _, w, _ in stages)
    total_train = sum(w for n, w, _ in stages if n.startswith("train"))
    print(f"{'total':<52} {total_wall:8.1f} {sum(c for _, _, c in stages):8.1f}")
    print(f"training only: {total_train:.1f} s wall = {total_train / REFERENCE_S:.2f} of the "
          f"{REFERENCE_S:.0f} s target;"
          f" with the data set: {total_wall / REFERENCE_S:.2f}; load average now {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
