"""Box-Jenkins speed: the study's final model (Eq. 3.24: orders 4,4,4,5, delay 4) on 10,000 samples.

Target (issue 4): a fit in under 10 s. Prints the median of a few fits, the ratio to the target,
the parameter error, and SIPPY's Box-Jenkins on the same data where ``sippy-unipi`` is installed.
Run: ``python benchmarks/bench_sysid_bj.py`` (timings on a shared machine are pessimistic).
"""

from __future__ import annotations

import time

import numpy as np

from hydrowatch.sysid import BoxJenkins, search_orders
from hydrowatch.sysid.pem import STUDY_MODEL_3_24, filtered_white_noise, simulate_box_jenkins

TARGET_S = 10.0
N = 10_000
M = STUDY_MODEL_3_24


def study_data(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = filtered_white_noise(N, rng)
    return u, simulate_box_jenkins(M["b"], M["f"], M["c"], M["d"], 4, u, 0.5 * rng.standard_normal(N))


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


def bench_search() -> None:
    u, y = study_data(0)
    start = time.perf_counter()
    result = search_orders(u, y)
    print(f"order search from the GPAC on Eq. 3.24 data, N={N}: {time.perf_counter() - start:.2f} s, "
          f"{len(result.history)} fits, orders {result.orders}")  # fmt: skip


def bench_sippy() -> None:
    try:
        from sippy_unipi import system_identification  # type: ignore[import-not-found]
    except ImportError:
        try:
            from sippy import system_identification  # type: ignore[import-not-found]
        except ImportError:
            print("sippy-unipi: absent, no comparison. Install it in a separate environment "
                  "(python -m venv /tmp/sippy && /tmp/sippy/bin/pip install sippy-unipi, plus this "
                  "package) and rerun this script there.")  # fmt: skip
            return
    u, y = study_data(0)
    start = time.perf_counter()
    try:
        # SIPPY's BJ_orders = [nb, nc, nd, nf, theta]; theta counts the dead samples before b1
        result = system_identification(y, u, "BJ", BJ_orders=[4, 4, 5, 4, 5], max_iterations=200)
    except Exception as exc:  # noqa: BLE001 - a third-party API that changed between versions
        print(f"sippy-unipi: installed but its BJ call failed ({type(exc).__name__}: {exc}); adapt the call.")
        return
    sippy_s = time.perf_counter() - start
    start = time.perf_counter()
    BoxJenkins(nb=4, nf=4, nc=4, nd=5, delay=4).fit(u, y)
    ours = time.perf_counter() - start
    print(f"sippy-unipi BJ: {sippy_s:.3f} s; hydrowatch {ours:.3f} s (ratio sippy/hydrowatch {sippy_s / ours:.1f}); "
          f"sippy G numerator {getattr(result, 'NUMERATOR', '?')}")  # fmt: skip


if __name__ == "__main__":
    bench_fit()
    bench_search()
    bench_sippy()
