"""What the scorer's forecasts cost per machine: CPU per forecast and per machine-hour, memory per machine.

A fleet of synthetic machines feeds :class:`hydrowatch.training.forecasts.FleetForecasts` with the degradation
index of every 5 s window, as the scorer does after judging them: healthy machines (all six parts at noise level,
sd 0.02, 1 % outlier windows) and wearing machines (one part wearing linearly from 0 to 0.9 over the run, the others
healthy). No plant and no judging: only the forecasts' own cost (:func:`~hydrowatch.condition.forecast.
forecast_alert` per part on the machine's history), measured by process CPU time on one core, once each machine's
history is full (``--hours`` ≥ the history's two hours).

Reference: a forecast per machine per minute (``--every 12``) at 1000 machines; target: the scorer's default
schedule costs under 0.1 core per 1000 machines (the scorer judges 1000 machines' windows with ~0.5 core).

Usage: python benchmarks/bench_forecast_online.py [--machines 20] [--hours 2.5] [--every 60 12]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hydrowatch.condition.forecast_stream import HISTORY_WINDOWS
from hydrowatch.plant.faults import FAULTS
from hydrowatch.training.chunks import WindowVerdict
from hydrowatch.training.forecasts import FleetForecasts
from hydrowatch.verdict import Verdict

HOP_S = 5.0
TARGET_CORES_PER_1000 = 0.1


def _indices(machines: int, windows: int, seed: int) -> np.ndarray:
    """Index per machine, window and part, shape (machines, windows, len(FAULTS)); odd machines wear one part."""
    rng = np.random.default_rng(seed)
    x = 0.02 * rng.standard_normal((machines, windows, len(FAULTS)))
    outliers = rng.random(x.shape) < 0.01
    x[outliers] += rng.uniform(0.3, 1.2, outliers.sum())
    for m in range(1, machines, 2):
        x[m, :, m % len(FAULTS)] += np.linspace(0.0, 0.9, windows)
    return x


def run(machines: int, hours: float, every: int, seed: int) -> dict[str, float]:
    """CPU of the forecasts that fall due once the histories are full, per forecast (healthy / wearing machines),
    per machine-hour and per 1000 machines, and the history's bytes per machine."""
    windows = int(hours * 3600 / HOP_S)
    index = _indices(machines, windows, seed)
    fleet = FleetForecasts(every=every)
    names = [f"f/m{m:04d}" for m in range(machines)]
    verdict = Verdict("healthy", 1.0, {"healthy": 1.0})
    cpu = {"healthy": 0.0, "wearing": 0.0}
    count = {"healthy": 0, "wearing": 0}
    for w in range(windows):
        batch = [WindowVerdict(name, w * HOP_S, (w + 1) * HOP_S, verdict, None,
                               {f: {"value": float(index[m, w, j]), "ci95": [0.0, 0.0]} for j, f in enumerate(FAULTS)})
                 for m, name in enumerate(names)]
        if w < HISTORY_WINDOWS:
            fleet.update(batch)
            continue
        for m, item in enumerate(batch):  # one machine at a time, to charge each forecast to its kind
            kind = "wearing" if m % 2 else "healthy"
            start = time.process_time()
            due = fleet.update([item])
            if due:
                cpu[kind] += time.process_time() - start
                count[kind] += 1
    measured_hours = (windows - HISTORY_WINDOWS) * HOP_S / 3600.0
    stream = fleet.stream(names[0])
    per_forecast = {k: cpu[k] / max(count[k], 1) for k in cpu}
    per_machine_hour = sum(cpu.values()) / machines / measured_hours
    return {"healthy_ms": 1e3 * per_forecast["healthy"], "wearing_ms": 1e3 * per_forecast["wearing"],
            "forecasts": sum(count.values()), "cpu_s_per_machine_hour": per_machine_hour,
            "cores_per_1000": 1000 * per_machine_hour / 3600.0, "bytes_per_machine": stream.nbytes if stream else 0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--machines", type=int, default=20)
    parser.add_argument("--hours", type=float, default=2.5, help="simulated hours (the first two fill the history)")
    parser.add_argument("--every", type=int, nargs="+", default=[60, 12], help="windows between forecasts")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"{args.machines} machines, {args.hours} h of 5 s windows, history {HISTORY_WINDOWS} windows; "
          "half healthy, half with one part wearing")
    for every in args.every:
        r = run(args.machines, args.hours, every, args.seed)
        verdict = "met" if every != 60 or r["cores_per_1000"] < TARGET_CORES_PER_1000 else "NOT met"
        print(f"every {every:>3} windows: {r['forecasts']:>4} forecasts, healthy {r['healthy_ms']:.1f} ms, wearing "
              f"{r['wearing_ms']:.1f} ms per forecast; {r['cpu_s_per_machine_hour']:.2f} CPU-s per machine-hour = "
              f"{r['cores_per_1000']:.3f} cores per 1000 machines"
              f"{f' (target < {TARGET_CORES_PER_1000} at the default 60: {verdict})' if every == 60 else ''}; "
              f"history {r['bytes_per_machine'] / 1e3:.1f} kB per machine")


if __name__ == "__main__":
    main()
