"""How many machines one scorer process keeps up with in real time at 200 Hz, on one core, per health method.

The measured path is the scorer service's inner loop without the network: decode each machine's
0.1 s ``sensor_chunk`` (Arrow IPC) and read the columns the method needs
(:func:`~hydrowatch.training.online.chunks_from_batches`, one conversion per column for all),
:meth:`OnlineScorer.update` (entropy: delay lines, batched one-step predictions per sensor,
windows, relative entropies, classifier, open-set rule; parity: raw windows judged by the
condition model) and encoding the ``health`` and ``kl`` messages of closed windows.
Reference: 1000 machines (issue 5 target), i.e. 200,000 samples/s, and a verdict
latency p99 < 100 ms.

Verdict latency is the duration of the ``update`` call in which a window closes (the closing chunk
has arrived; its verdict is published when the call returns), p50/p99 over the steps that close
windows, in two fleets:

* ``synchronised``: every machine starts in the same instant, so all windows close in the same
  0.1 s step (a simulated fleet started together: the worst case);
* ``staggered``: machine i joins at step i mod (window / chunk), so window closings spread evenly
  over the window (machines started at different times, as in a real fleet); measured once every
  machine has joined.

Memory per machine: tracemalloc of the per-machine state after the first chunk. torch runs on one
thread. Usage::

    python benchmarks/bench_scorer.py [--machines 1000] [--seconds 12] [--method parity|entropy|both]
                                      [--reference narx|bj]

Timings on a shared 2-core machine (other jobs running) are pessimistic.
"""

from __future__ import annotations

import argparse
import time
import tracemalloc
from dataclasses import dataclass

import numpy as np
import torch

from hydrowatch.health.plan import DataPlan
from hydrowatch.io.codec import decode_batch, encode_batch, sensor_chunk_from_arrays
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.schemas import SENSOR_CHUNK
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.messages import kl_batch, verdict_batch
from hydrowatch.training.online import OnlineScorer, chunks_from_batches
from hydrowatch.training.options import DEFAULT_NARX, TrainingSettings
from hydrowatch.training.trainer import train

TARGET_MACHINES = 1000
TARGET_P99_S = 0.100
STATES = ["healthy", "load_alert", "pump_leak_alert"]
CHUNK = 20
"""Samples per chunk: 0.1 s, as the plant service sends them."""


@dataclass
class Figures:
    """What one run measured."""

    rate: float
    verdicts: int
    latencies: list[float]
    per_machine: float


def _bundle(method: str, reference: str) -> ModelBundle:
    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    data = {r.state: [r] for r in simulate_states(STATES, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    narx = {**DEFAULT_NARX, "max_iter": 5}  # the demo's network shape; accuracy does not matter here
    return train(data, TrainingSettings(method=method, reference=reference, narx=narx, plan=plan)).bundle


def _payloads(machines: int, seconds: float) -> list[list[tuple[str, bytes]]]:
    """Pre-encoded chunks: step → (machine, bytes) for every machine."""
    source = list(simulate_states(STATES, seconds=seconds, seed=3))
    channels = ("voltage", "flow", "speed", "torque", "temperature")
    steps = len(source[0]) // CHUNK
    out = []
    for k in range(steps):
        part = slice(k * CHUNK, (k + 1) * CHUNK)
        encoded = [encode_batch(sensor_chunk_from_arrays(r.t[part], {c: r[c][part] for c in channels}))
                   for r in source]
        out.append([(f"f/m{i:04d}", encoded[i % len(encoded)]) for i in range(machines)])
    return out


def measure(bundle: ModelBundle, payloads: list[list[tuple[str, bytes]]], stagger: bool) -> Figures:
    """Run the scorer's inner loop over the payloads; only steady-state steps are timed when staggered."""
    machines = len(payloads[0])
    phases = bundle.window // CHUNK
    join = [i % phases if stagger else 0 for i in range(machines)]
    first = phases if stagger else 0
    scorer = OnlineScorer(bundle)
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    latencies, verdicts, elapsed, per_machine, samples = [], 0, 0.0, 0.0, 0
    for k, step in enumerate(payloads):
        t0 = time.perf_counter()
        live = [(machine, decode_batch(payload, SENSOR_CHUNK)) for (machine, payload), j in zip(step, join) if k >= j]
        chunks = chunks_from_batches([m for m, _ in live], [b for _, b in live], scorer.columns)
        out = scorer.update(chunks)
        for v in out:
            verdict_batch(v, bundle.version)
            kl_batch(v, bundle.kl_rows, bundle.states, bundle.version)
        took = time.perf_counter() - t0
        if k == 0:
            per_machine = sum(s.size_diff for s in tracemalloc.take_snapshot().compare_to(before, "lineno")
                              if s.size_diff > 0) / max(1, len(chunks))
            tracemalloc.stop()
        if k >= first:
            elapsed += took
            samples += len(chunks) * CHUNK
            verdicts += len(out)
            if out:
                latencies.append(took)
    return Figures(samples / elapsed, verdicts, latencies, per_machine)


def report(name: str, bundle: ModelBundle, f: Figures, fleet: str) -> None:
    """Print one run's figures and their ratio to the targets."""
    machines = f.rate / 200.0
    print(f"{name} [{fleet}]: {f.rate:,.0f} samples/s on one core = {machines:,.0f} machines in real time "
          f"({machines / TARGET_MACHINES:.2f}x the target of {TARGET_MACHINES}); verdicts={f.verdicts}")
    if f.latencies:
        p50, p99 = np.percentile(f.latencies, 50), np.percentile(f.latencies, 99)
        print(f"  verdict latency (update call that closes windows): p50 {p50 * 1e3:.1f} ms, p99 {p99 * 1e3:.1f} ms "
              f"({p99 / TARGET_P99_S:.2f}x the {TARGET_P99_S * 1e3:.0f} ms target)")
    print(f"  memory per machine (after the first chunk, tracemalloc): {f.per_machine / 1024:.1f} kB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=TARGET_MACHINES)
    parser.add_argument("--seconds", type=float, default=12.0, help="simulated seconds fed to every machine")
    parser.add_argument("--method", choices=("parity", "entropy", "both"), default="both")
    parser.add_argument("--reference", choices=("narx", "bj"), default="narx", help="entropy method's references")
    args = parser.parse_args()
    torch.set_num_threads(1)
    payloads = _payloads(args.machines, args.seconds)
    methods = ["entropy", "parity"] if args.method == "both" else [args.method]
    print(f"machines={args.machines} simulated_s={len(payloads) * CHUNK / 200:g}")
    for method in methods:
        bundle = _bundle(method, args.reference)
        name = method if method == "parity" else f"entropy/{args.reference}"
        for stagger in (False, True):
            report(name, bundle, measure(bundle, payloads, stagger), "staggered" if stagger else "synchronised")


if __name__ == "__main__":
    main()
