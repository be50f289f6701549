"""How many machines one scorer process keeps up with in real time at 200 Hz, on one core.

The measured path is the scorer service's inner loop without the network: decode each machine's
0.1 s ``sensor_chunk`` (Arrow IPC), :meth:`OnlineScorer.update` (delay lines, batched one-step
predictions per sensor, windows, relative entropies, classifier, open-set rule), and encoding the
``health`` and ``kl`` messages of closed windows. Reference: 1000 machines (issue 5 target), i.e.
200,000 samples/s. Also: verdict latency (the ``update`` call in which a window closes, p50/p99)
and memory per machine (tracemalloc of the per-machine state). torch runs on one thread.

Usage: python benchmarks/bench_scorer.py [--machines 1000] [--seconds 12] [--reference narx|bj]
Timings on a shared 2-core machine are pessimistic.
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np
import torch

from hydrowatch.health.plan import DataPlan
from hydrowatch.io.codec import arrays_from_sensor_chunk, decode_batch, encode_batch, sensor_chunk_from_arrays
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.schemas import SENSOR_CHUNK
from hydrowatch.training.messages import kl_batch, verdict_batch
from hydrowatch.training.online import Chunk, OnlineScorer
from hydrowatch.training.options import DEFAULT_NARX, TrainingSettings
from hydrowatch.training.trainer import train

TARGET_MACHINES = 1000
STATES = ["healthy", "load_alert", "pump_leak_alert"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=TARGET_MACHINES)
    parser.add_argument("--seconds", type=float, default=12.0, help="simulated seconds fed to every machine")
    parser.add_argument("--reference", choices=("narx", "bj"), default="narx")
    args = parser.parse_args()
    torch.set_num_threads(1)
    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    data = {r.state: [r] for r in simulate_states(STATES, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    narx = {**DEFAULT_NARX, "max_iter": 5}  # the demo's network shape; accuracy does not matter here
    bundle = train(data, TrainingSettings(reference=args.reference, narx=narx, plan=plan)).bundle
    source = list(simulate_states(STATES, seconds=args.seconds, seed=3))
    n = 20  # 0.1 s chunks, as the plant service sends them
    steps = len(source[0]) // n
    payloads = []  # pre-encoded chunks: step -> list of (machine, bytes)
    for k in range(steps):
        encoded = [encode_batch(sensor_chunk_from_arrays(r.t[k * n:(k + 1) * n],
                                                         {c: r[c][k * n:(k + 1) * n] for c in
                                                          ("voltage", "flow", "speed", "torque")}))
                   for r in source]
        payloads.append([(f"f/m{i:04d}", encoded[i % len(encoded)]) for i in range(args.machines)])
    scorer = OnlineScorer(bundle)
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    latencies, verdicts = [], 0
    start = time.perf_counter()
    for k, step in enumerate(payloads):
        t0 = time.perf_counter()
        chunks = []
        for machine, payload in step:
            t, channels = arrays_from_sensor_chunk(decode_batch(payload, SENSOR_CHUNK))
            chunks.append(Chunk(machine, t, channels))
        out = scorer.update(chunks)
        for v in out:
            verdict_batch(v, bundle.version)
            kl_batch(v, bundle.sensors, bundle.states, bundle.version)
        verdicts += len(out)
        if out:
            latencies.append(time.perf_counter() - t0)
        if k == 0:
            per_machine = sum(s.size_diff for s in tracemalloc.take_snapshot().compare_to(before, "lineno")
                              if s.size_diff > 0) / args.machines
            tracemalloc.stop()
    elapsed = time.perf_counter() - start
    samples = args.machines * steps * n
    rate = samples / elapsed
    machines = rate / 200.0
    print(f"reference={args.reference} machines={args.machines} simulated_s={steps * n / 200:g} "
          f"verdicts={verdicts}")
    print(f"throughput: {rate:,.0f} samples/s on one core = {machines:,.0f} machines in real time at 200 Hz "
          f"({machines / TARGET_MACHINES:.2f}x the target of {TARGET_MACHINES})")
    if latencies:
        print(f"verdict latency after the closing chunk arrives (whole batch of {args.machines} machines): "
              f"p50 {np.percentile(latencies, 50) * 1e3:.1f} ms, p99 {np.percentile(latencies, 99) * 1e3:.1f} ms")
    print(f"memory per machine (state after the first chunk, tracemalloc): {per_machine / 1024:.1f} kB")


if __name__ == "__main__":
    main()
