"""Speed of the plant kernel: figures and ratios (not a test).

1. One machine: simulated seconds per wall second (and per CPU second of this process), nominal
   plant, sensor noise on, filtered-noise 0–4 V command, default integrator (RK4, 2 kHz).
   Target >= 2000x real time. References: the same kernel at the 10 kHz reference step, and a
   straightforward pure-Python RK4 loop over the same right-hand side (``rates.py_func``).
2. A fleet: machines kept in real time at 200 Hz on one core, streamed in 1 s chunks through one
   batched ``PlantSimulator``. Target >= 1000. Reference: a per-machine loop (one simulator per
   machine, stepped one after the other, same compiled kernel).

Numba compile time is excluded (a warm-up call runs first). Timings on a shared 2-core machine
are pessimistic; the CPU-time figures are less sensitive to the other processes.

Run: ``python benchmarks/bench_plant_kernel.py [--seconds 60] [--machines 1000]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hydrowatch.plant import REFERENCE_SUBSTEPS, PlantParameters, PlantSimulator
from hydrowatch.plant.dynamics import N_COEF, N_LOAD, N_ODE, coefficients, rates
from hydrowatch.plant.effects import effect_row

FS = 200.0


def filtered_noise(n: int, seed: int = 0) -> np.ndarray:
    w = np.random.default_rng(seed).standard_normal(n)
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = 0.9 * y[k - 1] + 0.1 * w[k]
    return 4.0 * (y - y.min()) / (y.max() - y.min())


def timed(fn) -> tuple[float, float]:  # noqa: ANN001
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def python_rk4(u: np.ndarray, substeps: int = 10) -> None:
    """The straightforward reference: RK4 in plain Python over the uncompiled right-hand side."""
    coef = np.empty(N_COEF + N_LOAD)
    coefficients.py_func(PlantParameters().as_array(), coef)
    row, y, sens = effect_row(None), np.zeros(N_ODE), np.empty(3)
    y[2] = 73e5
    h = 1.0 / (FS * substeps)
    k = [np.empty(N_ODE) for _ in range(4)]
    for value in u:
        for _ in range(substeps):
            rates.py_func(coef, row, y, value, 0.0, True, k[0], sens)
            rates.py_func(coef, row, y + 0.5 * h * k[0], value, 0.0, True, k[1], sens)
            rates.py_func(coef, row, y + 0.5 * h * k[1], value, 0.0, True, k[2], sens)
            rates.py_func(coef, row, y + h * k[2], value, 0.0, True, k[3], sens)
            y += h / 6.0 * (k[0] + 2 * k[1] + 2 * k[2] + k[3])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds, single machine")
    parser.add_argument("--machines", type=int, default=1000, help="fleet size")
    args = parser.parse_args()
    u = filtered_noise(int(args.seconds * FS))
    PlantSimulator(PlantParameters(), seed=0).step(u[:10])  # compile (excluded)

    print("== one machine (nominal, noise on, 0-4 V filtered noise) ==")
    results = {}
    for label, substeps in (("default RK4 2 kHz", None), ("reference RK4 10 kHz", REFERENCE_SUBSTEPS)):
        sim = PlantSimulator(PlantParameters(), seed=0, **({"substeps": substeps} if substeps else {}))
        wall, cpu = timed(lambda sim=sim: sim.step(u))
        results[label] = (args.seconds / wall, args.seconds / cpu)
        print(f"{label:24s} {args.seconds / wall:9.0f}x real time (wall)  {args.seconds / cpu:9.0f}x (CPU)")
    short = u[: int(0.5 * FS)]
    wall, cpu = timed(lambda: python_rk4(short))
    python_rate = 0.5 / cpu
    print(f"{'pure-Python RK4 2 kHz':24s} {0.5 / wall:9.2f}x real time (wall)  {python_rate:9.2f}x (CPU)")
    default_cpu = results["default RK4 2 kHz"][1]
    print(f"target 2000x: {'met' if default_cpu >= 2000 else 'NOT met'} (CPU); "
          f"speed-up vs pure Python {default_cpu / python_rate:.0f}x, "
          f"vs 10 kHz reference {default_cpu / results['reference RK4 10 kHz'][1]:.1f}x")

    print(f"\n== fleet of {args.machines} machines, 1 s chunks at 200 Hz, noise on ==")
    chunks = 5
    command = np.stack([filtered_noise(int(chunks * FS), seed=m % 17) for m in range(args.machines)])
    fleet = PlantSimulator([PlantParameters()] * args.machines, seed=1)
    fleet.step(command[:, :2])

    def batched() -> None:
        for c in range(chunks):
            fleet.step(command[:, int(c * FS) : int((c + 1) * FS)])

    wall, cpu = timed(batched)
    batched_rt = args.machines * chunks / cpu
    print(f"{'batched kernel':24s} {args.machines * chunks / wall:9.0f} machines in real time (wall)  "
          f"{batched_rt:9.0f} (CPU)")
    loop_machines = min(args.machines, 200)
    singles = [PlantSimulator(PlantParameters(), seed=m) for m in range(loop_machines)]

    def per_machine() -> None:
        for c in range(chunks):
            for m, sim in enumerate(singles):
                sim.step(command[m, int(c * FS) : int((c + 1) * FS)])

    wall, cpu = timed(per_machine)
    loop_rt = loop_machines * chunks / cpu
    print(f"{'per-machine loop':24s} {loop_machines * chunks / wall:9.0f} machines in real time (wall)  "
          f"{loop_rt:9.0f} (CPU)")
    print(f"target 1000: {'met' if batched_rt >= 1000 else 'NOT met'} (CPU); batched / per-machine loop "
          f"{batched_rt / loop_rt:.2f}x")


if __name__ == "__main__":
    main()
