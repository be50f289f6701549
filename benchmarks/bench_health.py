"""Speed and accuracy figures of hydrowatch.health (prints; no assertions).

Speed reference: the online scorer must keep up with 1000 machines in real time on one core, i.e.
1000 windows (x 3 sensors) per 5 s = 200 windows/s, and 1000 x 200 = 200,000 prediction-error
samples/s per sensor fed in chunks. Ratios above 1 meet the target. Timings on a shared machine
are pessimistic.

Accuracy part: log transform of the features on/off, and Gaussian vs mixture distributions, on a
harder synthetic setting than the tests (short windows, strongly correlated errors) where the
choice shows. Run: ``python benchmarks/bench_health.py [--quick]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hydrowatch.health import HealthClassifier, HealthModel, MachineWindow, RelativeEntropyFeatures
from hydrowatch.health.synthetic import STUDY_STATES, synthetic_errors

TARGET_WINDOWS_PER_S = 1000 / 5.0
"""1000 machines, one 5 s window each per 5 s."""


def _best_of(fn, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def speed() -> None:
    base = {s: synthetic_errors(s, 40_000, seed=i) for i, s in enumerate(STUDY_STATES)}
    windows = {s: synthetic_errors(s, 60_000, seed=100 + i) for i, s in enumerate(STUDY_STATES)}
    errors = synthetic_errors("load_alert", 200_000, seed=5)  # 200 windows
    for distribution in ("gaussian", "mixture"):
        features = RelativeEntropyFeatures(distribution=distribution).fit(base)
        data = errors if distribution == "gaussian" else errors[:20_000]
        n = data.shape[0] // 1000
        rate = n / _best_of(lambda f=features, d=data: f.transform(d), 1 if distribution == "mixture" else 3)
        print(f"features batch  {distribution:8s} {rate:10.0f} windows/s (3 sensors x 7 states) "
              f"= {rate / TARGET_WINDOWS_PER_S:6.2f} x target")

        def stream(f: RelativeEntropyFeatures = features, d: np.ndarray = data) -> None:
            machine = MachineWindow(f)
            for i in range(0, d.shape[0], 20):  # 0.1 s chunks, as bus messages
                machine.update(d[i : i + 20])

        rate = n / _best_of(stream, 1 if distribution == "mixture" else 3)
        print(f"features stream {distribution:8s} {rate:10.0f} windows/s (20-sample chunks)      "
              f"= {rate / TARGET_WINDOWS_PER_S:6.2f} x target")
    model = HealthModel().fit(base, windows)
    X = model.features_.transform(errors)
    clf = model.classifier_
    rate_batch = X.shape[0] / _best_of(lambda: clf.predict_proba(X))
    one = X[:1]
    rate_single = 1000 / _best_of(lambda: [clf.predict_proba(one) for _ in range(1000)])
    print(f"classifier batch  {rate_batch:10.0f} predictions/s = {rate_batch / TARGET_WINDOWS_PER_S:8.1f} x target")
    print(f"classifier 1-row  {rate_single:10.0f} predictions/s = {rate_single / TARGET_WINDOWS_PER_S:8.1f} x target")


def accuracy_study(seeds: int, mixture: bool) -> None:
    """Test accuracy (mean +- sd over seeds): window 250 samples, AR(1) 0.8, 40 windows/state."""
    print("harder synthetic setting: window=250, phi=0.8, 10,000 base samples and 120 windows per state")
    rows: dict[str, list[float]] = {}
    for seed in range(seeds):
        base = {s: synthetic_errors(s, 10_000, seed=1000 * seed + i, phi=0.8) for i, s in enumerate(STUDY_STATES)}
        win = {s: synthetic_errors(s, 30_000, seed=1000 * seed + 100 + i, phi=0.8) for i, s in enumerate(STUDY_STATES)}
        for distribution in ("gaussian", "mixture") if mixture else ("gaussian",):
            features = RelativeEntropyFeatures(distribution=distribution, window=250, hop=250, random_state=seed)
            for log in (True, False):
                model = HealthModel(features=features, classifier=HealthClassifier(log_features=log, random_state=seed))
                model.fit(base, win)
                key = f"{distribution:8s} log_features={log!s:5s}"
                rows.setdefault(key, []).append(model.report_["test_accuracy"])
                rows.setdefault(key + " ECE", []).append(model.report_["ece"])
    for key, values in rows.items():
        print(f"  {key:40s} {np.mean(values):.4f} +- {np.std(values):.4f}  (n={len(values)})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="speed only, no accuracy study")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--no-mixture", action="store_true", help="accuracy study with Gaussian only")
    args = parser.parse_args()
    speed()
    if not args.quick:
        accuracy_study(args.seeds, not args.no_mixture)


if __name__ == "__main__":
    main()
