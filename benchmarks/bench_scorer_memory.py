"""What the scorer keeps per machine once every bounded buffer is full, and how much of it the attribution ring is.

A parity scorer keeps, per machine: its window in progress, the evidence of its last ``--smoothing`` windows, its
degradation stream (:class:`hydrowatch.condition.degradation_stream.DegradationStream`: a ring of the fits of its last
:data:`~hydrowatch.condition.degradation.ATTRIBUTION_WINDOWS` valid windows, 60 = 300 s, which the valve-side
attribution reads) and, in the service, its forecast history (:class:`hydrowatch.training.forecasts.FleetForecasts`,
``--forecast-history`` s of windows). This feeds ``--machines`` machines 0.1 s chunks of simulated recordings (three
states) through :class:`~hydrowatch.training.online.OnlineScorer` (parity, smoothing 12) and ``FleetForecasts`` as
the scorer service does, past the point where the attribution rings are full, and prints, per machine, what
tracemalloc finds held: everything, the part allocated in ``condition/degradation.py`` (the ring), and the growth
after the rings were full. Usage::

    python benchmarks/bench_scorer_memory.py [--machines 30] [--seconds 330] [--forecast-history 7200]
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time
import tracemalloc

from hydrowatch.channels import STUDY_RIG
from hydrowatch.condition.degradation import ATTRIBUTION_WINDOWS
from hydrowatch.condition.degradation_stream import DegradationStream
from hydrowatch.health.plan import DataPlan
from hydrowatch.io.codec import sensor_chunk_from_arrays
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.recording import SAMPLE_RATE_HZ
from hydrowatch.training.forecasts import FleetForecasts
from hydrowatch.training.online import OnlineScorer, chunks_from_batches
from hydrowatch.training.options import TrainingSettings
from hydrowatch.training.trainer import train

STATES = ["healthy", "load_alert", "pump_leak_alert"]
CHUNK = 20
"""Samples per chunk: 0.1 s, as the plant service sends them."""


def held(snapshot: tracemalloc.Snapshot, part: str | None = None) -> int:
    """Bytes traced in ``snapshot`` (only those allocated in files whose path contains ``part``, when given)."""
    stats = snapshot.statistics("filename")
    return sum(s.size for s in stats if part is None or part in s.traceback[0].filename)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=30)
    parser.add_argument("--seconds", type=float, default=330.0,
                        help="simulated seconds per machine (the rings fill after 300 s of valid windows)")
    parser.add_argument("--forecast-history", type=float, default=7200.0, help="as the scorer's flag, s")
    args = parser.parse_args()
    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    data = {r.state: [r] for r in simulate_states(STATES, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    bundle = train(data, TrainingSettings(method="parity", plan=plan)).bundle
    source = list(simulate_states(STATES, seconds=args.seconds, seed=3))
    machines = [f"f/m{i:04d}" for i in range(args.machines)]
    steps = len(source[0]) // CHUNK
    hop_s = bundle.hop / SAMPLE_RATE_HZ
    print(f"machines={args.machines} simulated_s={steps * CHUNK / SAMPLE_RATE_HZ:g} window hop {hop_s:g} s, "
          f"attribution ring {ATTRIBUTION_WINDOWS} windows; load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    tracemalloc.start()
    scorer = OnlineScorer(bundle, smoothing=12, stagger=True)
    forecasts = FleetForecasts(capacity=max(1, round(args.forecast_history / hop_s)))
    base = tracemalloc.take_snapshot()
    full_at, full, windows, started = None, None, 0, time.perf_counter()
    for k in range(steps):
        part = slice(k * CHUNK, (k + 1) * CHUNK)
        batches = [sensor_chunk_from_arrays(r.t[part], {c: r[c][part] for c in STUDY_RIG}) for r in source]
        chunks = chunks_from_batches(machines, [batches[i % len(batches)] for i in range(len(machines))],
                                     scorer.columns)
        verdicts = scorer.update(chunks)
        forecasts.update(verdicts)
        windows += len(verdicts)
        if full is None and windows >= (ATTRIBUTION_WINDOWS + 1) * len(machines):
            full_at, full = k, tracemalloc.take_snapshot()
    end = tracemalloc.take_snapshot()
    tracemalloc.stop()
    rings = _streams()
    filled = [len(s._fits) for s in rings]
    if full is None or full_at is None:
        sys.exit(f"the rings did not fill: {windows} windows in {args.seconds} s; give --seconds > "
                 f"{(ATTRIBUTION_WINDOWS + 2) * hop_s:g}")
    per = 1.0 / len(machines)
    total = (held(end) - held(base)) * per
    ring = (held(end, "degradation.py") - held(base, "degradation.py")) * per
    forecast = (held(end, "forecast") - held(base, "forecast")) * per
    later = (held(end) - held(full)) * per
    later_windows = (windows - (ATTRIBUTION_WINDOWS + 1) * len(machines)) * per
    print(f"{windows} windows judged in {time.perf_counter() - started:.0f} s; degradation streams "
          f"{len(rings)}, ring lengths {min(filled)}-{max(filled)} of {ATTRIBUTION_WINDOWS}")
    print(f"per machine, held at the end (tracemalloc): {total / 1024:.1f} kB in all; allocated in "
          f"condition/degradation.py (the attribution ring): {ring / 1024:.1f} kB; in the forecast code "
          f"(history of {forecasts.capacity} windows, filled {steps * CHUNK / SAMPLE_RATE_HZ / hop_s:.0f}): "
          f"{forecast / 1024:.1f} kB")
    print(f"per machine after the rings were full (step {full_at}): {later:+.0f} B over {later_windows:.1f} windows")
    one, entries = rings[0]._fits[0], ATTRIBUTION_WINDOWS * sys.getsizeof(rings[0]._fits[0])
    print(f"one ring entry: a {one.shape} {one.dtype} array, sys.getsizeof {sys.getsizeof(one)} B (data "
          f"{one.nbytes} B); {ATTRIBUTION_WINDOWS} entries: {entries / 1024:.1f} kB + the deque "
          f"{sys.getsizeof(rings[0]._fits)} B")


def _streams() -> list[DegradationStream]:
    """Every degradation stream alive (the scorer's judge holds one per machine; found by the garbage collector)."""
    return [o for o in gc.get_objects() if isinstance(o, DegradationStream)]


if __name__ == "__main__":
    main()
