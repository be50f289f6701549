"""Speed of the plant kernel: figures and ratios (not a test).

1. One machine: simulated seconds per CPU second of this process (and per wall second), nominal
   plant, sensor noise on, filtered-noise 0–4 V command, default integrator (RK4, 2 kHz).
   Target >= 2000x real time. References: the same kernel at the 10 kHz reference step, and a
   straightforward pure-Python RK4 loop over the same right-hand side (``derivatives.py_func``).
   For information: the same machine with all twelve effects switched on.
2. A fleet: machines kept in real time at 200 Hz on one core, streamed in 1 s chunks through one
   batched ``PlantSimulator``. Target >= 1000. Reference: a per-machine loop (one simulator per
   machine, stepped one after the other, same compiled kernel).

Numba compile time is excluded (a warm-up call runs first). Each figure is the median of
``--repeats`` runs. The machine may be shared: the load average is printed with the figures, and
the CPU-time figures are the ones to compare (wall time grows with the other processes' load).

Run: ``python benchmarks/bench_plant_kernel.py [--seconds 60] [--machines 1000] [--repeats 3]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable
from typing import Any
from unittest import mock

import numpy as np

from hydrowatch.plant import EFFECT_IDS, REFERENCE_SUBSTEPS, PlantParameters, PlantSimulator, dynamics
from hydrowatch.plant.effects import effect_row

FS = 200.0


def filtered_noise(n: int, seed: int = 0) -> np.ndarray:
    w = np.random.default_rng(seed).standard_normal(n)
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = 0.9 * y[k - 1] + 0.1 * w[k]
    return 4.0 * (y - y.min()) / (y.max() - y.min())


def timed(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median wall and CPU seconds of ``repeats`` calls of fn."""
    walls, cpus = [], []
    for _ in range(repeats):
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return statistics.median(walls), statistics.median(cpus)


def load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.1f} {five:.1f} {fifteen:.1f} on {os.cpu_count()} cores"


def python_rk4(u: np.ndarray, substeps: int = 10) -> None:
    """The straightforward reference: RK4 in plain Python over the uncompiled right-hand side."""
    coef = np.empty(dynamics.N_COEF + dynamics.N_LOAD)
    dynamics.coefficients.py_func(PlantParameters().as_array(), coef)
    row = effect_row(None)
    y = np.zeros(dynamics.N_ODE)
    y[dynamics.PS] = 73e5
    h = 1.0 / (FS * substeps)
    derive: Any = dynamics.derivatives.py_func  # the uncompiled right-hand side

    def slope(y: np.ndarray, value: float) -> np.ndarray:
        return np.array(derive(coef, row, tuple(y), value, 0.0, True)[0])

    with mock.patch.object(dynamics, "_load_torque", dynamics._load_torque.py_func):
        for value in u:
            for _ in range(substeps):
                k1 = slope(y, value)
                k2 = slope(y + 0.5 * h * k1, value)
                k3 = slope(y + 0.5 * h * k2, value)
                k4 = slope(y + h * k3, value)
                y += h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def one_machine(u: np.ndarray, seconds: float, repeats: int) -> None:
    print(f"== one machine (nominal, noise on, 0-4 V filtered noise, {seconds:g} s); {load()} ==")
    results = {}
    runs: list[tuple[str, dict[str, Any], dict[str, dict] | None]] = [
        ("default RK4 2 kHz", {}, None),
        ("reference RK4 10 kHz", {"substeps": REFERENCE_SUBSTEPS}, None),
        ("all 12 effects, 2 kHz", {}, {effect_id: {} for effect_id in EFFECT_IDS}),
    ]
    for label, kwargs, effects in runs:
        def run(effects: dict | None = effects, kwargs: dict = kwargs, n: int = len(u)) -> None:
            PlantSimulator(PlantParameters(), effects, seed=0, **kwargs).step(u[:n])

        run(n=10)  # compile (excluded)
        wall, cpu = timed(run, repeats)
        results[label] = seconds / cpu
        print(f"{label:24s} {seconds / cpu:9.0f}x real time (CPU)  {seconds / wall:9.0f}x (wall)")
    short = u[: int(0.5 * FS)]
    wall, cpu = timed(lambda: python_rk4(short), 1)
    python_rate = 0.5 / cpu
    print(f"{'pure-Python RK4 2 kHz':24s} {python_rate:9.2f}x real time (CPU)  {0.5 / wall:9.2f}x (wall)")
    default_cpu = results["default RK4 2 kHz"]
    print(f"target 2000x: {'met' if default_cpu >= 2000 else 'NOT met'} (CPU); "
          f"speed-up vs pure Python {default_cpu / python_rate:.0f}x, "
          f"vs 10 kHz reference {default_cpu / results['reference RK4 10 kHz']:.1f}x; {load()}")


def fleet(machines: int, repeats: int) -> None:
    print(f"\n== fleet of {machines} machines, 1 s chunks at 200 Hz, noise on; {load()} ==")
    chunks = 5
    command = np.stack([filtered_noise(int(chunks * FS), seed=m % 17) for m in range(machines)])
    batch = PlantSimulator([PlantParameters()] * machines, seed=1)
    batch.step(command[:, :2])

    def batched() -> None:
        for c in range(chunks):
            batch.step(command[:, int(c * FS) : int((c + 1) * FS)])

    wall, cpu = timed(batched, repeats)
    batched_rt = machines * chunks / cpu
    print(f"{'batched kernel':24s} {batched_rt:9.0f} machines in real time (CPU)  "
          f"{machines * chunks / wall:9.0f} (wall)")
    loop_machines = min(machines, 200)
    singles = [PlantSimulator(PlantParameters(), seed=m) for m in range(loop_machines)]

    def per_machine() -> None:
        for c in range(chunks):
            for m, sim in enumerate(singles):
                sim.step(command[m, int(c * FS) : int((c + 1) * FS)])

    wall, cpu = timed(per_machine, repeats)
    loop_rt = loop_machines * chunks / cpu
    print(f"{'per-machine loop':24s} {loop_rt:9.0f} machines in real time (CPU)  "
          f"{loop_machines * chunks / wall:9.0f} (wall)")
    print(f"target 1000: {'met' if batched_rt >= 1000 else 'NOT met'} (CPU); batched / per-machine loop "
          f"{batched_rt / loop_rt:.2f}x; {load()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds, single machine")
    parser.add_argument("--machines", type=int, default=1000, help="fleet size")
    parser.add_argument("--repeats", type=int, default=3, help="runs per figure (median reported)")
    args = parser.parse_args()
    one_machine(filtered_noise(int(args.seconds * FS)), args.seconds, args.repeats)
    fleet(args.machines, args.repeats)


if __name__ == "__main__":
    main()
