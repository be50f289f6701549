"""What the scorer's ``…/expected`` costs per window, and how far measured lies from expected per state (issue 16).

For a parity bundle (3 states, the tests' small plan) and recordings of each state of another seed, cut into
5 s windows and judged in batches of 64 as the scorer does (``--smoothing 12``):

* per window, the CPU time (this thread) of the judge's verdict, of what the healthy unit's relations expected
  (:meth:`ParityJudge.expected <hydrowatch.methods.parity.online.ParityJudge.expected>`), and of building and
  encoding the ``expected_window`` message; its size in bytes;
* per state and sensor, the median over windows of RMS(measured − expected) / std(measured) of the 0.1 s points:
  small on healthy windows, large in a fault's own sensor.

Usage::

    python benchmarks/bench_expected.py [--seconds 330] [--states healthy,load_alert,pump_leak_alert,motor_leak_alert]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from hydrowatch.condition.layout import windows_from_recording
from hydrowatch.health.plan import DataPlan
from hydrowatch.io.codec import encode_batch
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.training.chunks import WindowVerdict
from hydrowatch.training.messages import expected_batch
from hydrowatch.training.options import TrainingSettings
from hydrowatch.training.trainer import train

TRAINED = ["healthy", "load_alert", "pump_leak_alert"]
BATCH = 64


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=330.0, help="simulated seconds per state tested")
    parser.add_argument("--states", default="healthy,load_alert,pump_leak_alert,motor_leak_alert")
    args = parser.parse_args()
    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    grouped = {r.state: [r] for r in simulate_states(TRAINED, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    bundle = train(grouped, TrainingSettings(method="parity", plan=plan)).bundle
    judge = bundle.health_method.online(smoothing=12)
    print(f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    timings = np.zeros(3)
    windows, size = 0, 0
    for r in simulate_states(args.states.split(","), seconds=args.seconds, seed=3):
        raw = windows_from_recording(r, 1000, 1000)
        if raw.shape[2] < len(judge.columns):  # the bundle reads the oil temperature: unknown here
            raw = np.concatenate([raw, np.full((*raw.shape[:2], 1), np.nan)], axis=2)
        gaps: dict[str, list[float]] = {}
        for lo in range(0, len(raw), BATCH):
            part = raw[lo:lo + BATCH]
            names = [f"f/m{i}" for i in range(len(part))]
            c = time.thread_time()
            judged = judge.judge(part, names)
            c1 = time.thread_time()
            expected = judge.expected(part, names)
            c2 = time.thread_time()
            for (verdict, scores, index), seen in zip(judged, expected):
                message = expected_batch(WindowVerdict("f/m", 0.0, 5.0, verdict, scores, index, seen), bundle.version)
                size = len(encode_batch(message)) if message is not None else size
            timings += (c1 - c, c2 - c1, time.thread_time() - c2)
            windows += len(part)
            for seen in expected:
                for sensor, e in (seen or {}).items():
                    gaps.setdefault(sensor, []).append(
                        float(np.sqrt(np.mean((e.measured - e.expected) ** 2)) / np.std(e.measured)))
        print(f"{r.state}: " + ", ".join(f"{s} {np.median(v):.3f}" for s, v in sorted(gaps.items())) +
              f" (median RMS(measured - expected) / std(measured) over {len(raw)} windows)")
    judge_ms, expected_ms, message_ms = timings / windows * 1e3
    print(f"per window ({windows} windows, batches of {BATCH}): judge {judge_ms:.2f} ms, expected {expected_ms:.3f} ms "
          f"({expected_ms / judge_ms:.1%} of judging), message built and encoded {message_ms:.3f} ms, {size} bytes; "
          f"at 1000 machines (200 windows/s): {(expected_ms + message_ms) * 0.2:.3f} core, "
          f"{size * 200 / 1e3:.0f} kB/s on the bus")


if __name__ == "__main__":
    main()
