"""Box-Jenkins speed: the study's final model (Eq. 3.24: orders 4,4,4,5, delay 4) on 10,000 samples.

Target (issue 4): a fit in under 10 s. Prints the median of a few fits, the ratio to the target,
the parameter error, and how often the order search returns the true orders. SIPPY's BJ on the
same data: ``benchmarks/bench_sysid_peers.py`` (run with the peers' environment).
Run: ``python benchmarks/bench_sysid_bj.py [--search-samples N ...]`` (timings on a shared
machine are pessimistic).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hydrowatch.sysid import BoxJenkins, search_orders
from hydrowatch.sysid.pem import STUDY_MODEL_3_24, filtered_white_noise, simulate_box_jenkins

TARGET_S = 10.0
N = 10_000
M = STUDY_MODEL_3_24


def study_data(seed: int, n: int = N) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = filtered_white_noise(n, rng)
    return u, simulate_box_jenkins(M["b"], M["f"], M["c"], M["d"], 4, u, 0.5 * rng.standard_normal(n))


def bench_fit(repeats: int = 5) -> None:
    truth = np.concatenate([M["b"], M["f"], M["c"], M["d"]])
    times, errors = [], []
    for seed in range(repeats):
        u, y = study_data(seed)
        start = time.perf_counter()
        model = BoxJenkins(nb=4, nf=4, nc=4, nd=5, delay=4).fit(u, y)
        times.append(time.perf_counter() - start)
        errors.append(np.max(np.abs(np.concatenate([model.b_, model.f_, model.c_, model.d_]) - truth)))
    median = float(np.median(times))
    print(f"bj fit (4,4,4,5; K=4), N={N}: median {median:.3f} s over {repeats} fits "
          f"(target {TARGET_S:.0f} s, ratio {median / TARGET_S:.3f}); "
          f"iterations {model.n_iter_}; max |theta - theta_true| median {np.median(errors):.3f}")  # fmt: skip


def bench_search(sizes: list[int], seeds: int) -> None:
    """Share of seeds for which search_orders (from the GPAC) returns Eq. 3.24's (4,4,4,5), K = 4."""
    true = {"nb": 4, "nf": 4, "nc": 4, "nd": 5, "delay": 4}
    for n in sizes:
        found, times, fits = [], [], []
        for seed in range(seeds):
            u, y = study_data(seed, n)
            start = time.perf_counter()
            result = search_orders(u, y)
            times.append(time.perf_counter() - start)
            fits.append(len(result.history))
            found.append(result.orders == true)
            if result.orders != true:
                print(f"  N={n} seed {seed}: {result.orders}")
        print(f"order search on Eq. 3.24 data, N={n}: true orders in {sum(found)}/{seeds} seeds; "
              f"median {np.median(times):.1f} s and {np.median(fits):.0f} fits per search")  # fmt: skip


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--search-samples", type=int, nargs="*", default=[10_000, 30_000, 100_000])
    parser.add_argument("--seeds", type=int, default=5, help="seeds per search sample size")
    args = parser.parse_args()
    bench_fit()
    bench_search(args.search_samples, args.seeds)
