"""NARX reference model: fit time, one-step throughput, accuracy against linear and SysIdentPy baselines.

Targets (issue 4):
- NARX 15/15/35 on 10,000 samples trains in under 120 s on 2 cores;
- batched one-step prediction >= 1,000,000 samples/s (the online scorer's path).

Data: the plant simulator (hydrowatch.plant.simulator.simulate) under the study's identification
input, low-pass filtered noise over 0-4 V (Table 4.1), output gearbox speed, 200 Hz. Training
runs on one thread (hydrowatch.sysid.narx_lm); its CPU time is what it takes on an idle core,
its wall time depends on what else the machine runs.

Usage: python benchmarks/bench_sysid_narx.py [--quick]   (--quick: 3,000 samples, 40 iterations)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hydrowatch.sysid.narx import NARX
from hydrowatch.sysid.narx_lines import linear_one_step

FIT_TARGET_S = 120.0
ONE_STEP_TARGET = 1_000_000.0


def plant_data(n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Valve command [V] and gearbox speed [rad/s] of the healthy plant, n samples at 200 Hz."""
    from hydrowatch.plant.excitation import filtered_noise
    from hydrowatch.plant.simulator import simulate

    command = filtered_noise(n / 200.0, (0.0, 4.0), seed=seed)
    record = simulate(command, seed=seed + 1)
    return record.channels["voltage"], record.channels["speed"]


def nrmse(y: np.ndarray, y_hat: np.ndarray) -> float:
    ok = np.isfinite(y_hat)
    return float(np.sqrt(np.mean((y[ok] - y_hat[ok]) ** 2)) / np.std(y[ok]))


def bench_fit(u: np.ndarray, y: np.ndarray, u_test: np.ndarray, y_test: np.ndarray, max_iter: int) -> NARX:
    wall, cpu = time.perf_counter(), time.process_time()
    model = NARX(input_delays=15, output_delays=15, hidden=35, max_iter=max_iter).fit(u, y)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    s = model.summary()
    print(f"fit 15/15/35 on {u.size} samples: wall {wall:.1f} s, CPU {cpu:.1f} s, {s['iterations']} iterations "
          f"({s['stop_reason']}), {cpu / s['iterations']:.2f} CPU-s/iteration")
    print(f"  target {FIT_TARGET_S:.0f} s on 2 cores: CPU time / target = {cpu / FIT_TARGET_S:.2f} "
          f"(wall / target = {wall / FIT_TARGET_S:.2f} on this machine)")
    print(f"  gamma {s['gamma']:.0f} of {s['n_parameters']} parameters (study, Table 4.6: 934 of 1,120)")
    held_out = nrmse(y_test, model.predict(u_test, y_test))
    arx = nrmse(y_test, linear_one_step(u, y, u_test, y_test, 15, 15))
    print(f"  one-step NRMSE: train {s['nrmse_one_step']:.4f}, held-out {held_out:.4f}; "
          f"linear ARX 15/15 held-out {arx:.4f} (NARX / ARX = {held_out / arx:.2f})")
    try:
        from hydrowatch.sysid.boxjenkins import BoxJenkins

        # The study's Table 3.11 orders; delay 0: the simulator answers after one sample (docs/sysid.md).
        bj = BoxJenkins(nb=4, nf=4, nc=4, nd=5, delay=0).fit(u, y)
        bj_nrmse = nrmse(y_test[20:], bj.predict(u_test, y_test, steps_ahead=1)[20:])
        print(f"  Box-Jenkins 4/4/4/5, delay 0, held-out {bj_nrmse:.4f} (NARX / BJ = {held_out / bj_nrmse:.2f})")
    except ImportError:
        print("  Box-Jenkins: hydrowatch.sysid.boxjenkins not available")
    corr = model.residual_correlations(u_test, y_test, max_lag=20)
    print(f"  held-out residual correlations inside the 95 % bounds: acf {corr['acf_inside']:.2f}, "
          f"ccf {corr['ccf_inside']:.2f}")
    return model


def bench_one_step(model: NARX) -> None:
    rng = np.random.default_rng(0)
    for batch in (1_000, 10_000, 100_000, 1_000_000):
        rows = rng.normal(size=(batch, model.n_regressors)) + 2.0
        model.one_step(rows)  # warm-up
        repeats = max(3, 2_000_000 // batch)
        wall, cpu = time.perf_counter(), time.process_time()
        for _ in range(repeats):
            model.one_step(rows)
        rate = batch * repeats / (time.perf_counter() - wall)
        cpu_rate = batch * repeats / max(time.process_time() - cpu, 1e-9)
        print(f"one_step batch {batch:>9,}: {rate:12,.0f} samples/s wall, {cpu_rate:12,.0f} per CPU-second "
              f"(target {ONE_STEP_TARGET:,.0f}: ratio {rate / ONE_STEP_TARGET:.1f} wall, "
              f"{cpu_rate / ONE_STEP_TARGET:.1f} CPU)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3,000 samples and 40 iterations")
    args = parser.parse_args()
    n_fit, max_iter = (3_000, 40) if args.quick else (10_000, 200)
    u, y = plant_data(n_fit + 4_000)
    u_fit, y_fit, u_test, y_test = u[:n_fit], y[:n_fit], u[n_fit:], y[n_fit:]
    model = bench_fit(u_fit, y_fit, u_test, y_test, max_iter)
    bench_one_step(model)
    print("Peers (SysIdentPy's NARXNN, SIPPY's BJ): benchmarks/peers/.venv/bin/python "
          "benchmarks/bench_sysid_peers.py (docs/sysid.md)")


if __name__ == "__main__":
    main()
