"""Per-component condition classification on the real UCI hydraulic test rig (issue 17).

Reads ../shared/data/uci-hydraulic (or $HYDROWATCH_DATA/uci-hydraulic) through the rig
description ``uci-hydraulic`` and prints, per component, accuracy and macro-F1 of

- ``statistics``: the plain baseline (mean, std, min, max, slope and 6 phase means of every
  channel → LDA), and
- ``transients``: the pressures', motor power's and flows' values around each load change relative
  to their settled level, the other components' directions projected out (dimension chosen on the
  training cycles only) → LDA,
- ``transients shares+RR2``: the ``cycles`` method's transients (every channel, each clear step also as shares of the
  cycle's own step, a decision in the 2 leading discriminant directions, and since branch rig17b the covered trees'
  vote: ``TRANSIENTS``), chosen on the UCI accumulator's training cycles only (docs/rigs.md),
- ``entropy``: the study's method without a command (:mod:`hydrowatch.cycles.reference`): per sensor a healthy
  reference model from the second of the cycle and the other channels, the relative entropy of each cycle's errors
  to each condition's base error distribution → LDA,

- ``cycles method``: what ``train --rig`` fits per component (:func:`hydrowatch.methods.cycles.train.fit_component`:
  the feature set chosen on the fold's training cycles, the open set; ``unknown`` counted wrong),

on (a) 5 random folds of cycles and (b) the honest split (within each class of the component,
its first 70 % of cycles in recording order train, the last 30 % test). ``--forest`` adds the
baseline features with a random forest (10-30 s per component on one core; the rest: a few s).

Issue 17's reference figures for the plain baseline: (a) 99.8 / 100 / 99.9 / 97.6-99.1 %,
(b) 100 / 80-100 / 100 / 53-56 % (cooler / valve / pump / accumulator).

    OMP_NUM_THREADS=1 python benchmarks/bench_uci.py [--forest] [--folds 5] [--seed 0] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

import numpy as np
from sklearn.ensemble import RandomForestClassifier
from sklearn.metrics import accuracy_score, f1_score

from hydrowatch.cycles import ComponentClassifier, cycle_statistics, ordered_split, random_folds
from hydrowatch.io.wide import Cycles, shared_cycles
from hydrowatch.methods.cycles.train import TRANSIENTS, CycleData, fit_component, state_name
from hydrowatch.rig import RigDescription, data_root

FAST_HZ = 10.0
"""Channels recorded at this rate or faster have their transients as features: the pressures, motor
power and flows (the temperatures, vibration and virtual cooling sensors, recorded at 1 Hz, have no
load-change dynamics)."""

UNKNOWN_CODE = -1.0
"""The cycles method's ``unknown`` among the numeric labels (no UCI label is negative)."""
Fit = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""(train cycles, train labels, train nuisance, test cycles) → predicted test labels."""


class _Classifier:
    """A :class:`ComponentClassifier` as a :data:`Fit`, keeping the nuisance dimension each fit chose."""

    def __init__(self, features: str, reference: int, channels: list[int] | None = None, **options: object) -> None:
        self.features, self.reference, self.channels, self.options = features, reference, channels, options
        self.directions: list[int] = []
        self.healthy: float | None = None  # the judged component's (entropy)

    def __call__(self, values: np.ndarray, labels: np.ndarray, nuisance: np.ndarray, test: np.ndarray) -> np.ndarray:
        model = ComponentClassifier(features=self.features, reference=self.reference, channels=self.channels,
                                    healthy=self.healthy, **self.options)  # type: ignore[arg-type]
        model.fit(values, labels, nuisance)
        self.directions.append(model.directions_)
        return model.predict(test)


class _CyclesMethod:
    """What ``train --rig`` fits for one component (feature set chosen on the training cycles, open set) as a
    :data:`Fit`; ``unknown`` never equals a label, so it counts wrong. Keeps each fit's chosen feature set."""

    def __init__(self, rig: RigDescription) -> None:
        self.rig, self.healthy, self.chosen = rig, "", []  # type: ignore[var-annotated]

    def __call__(self, values: np.ndarray, labels: np.ndarray, nuisance: np.ndarray, test: np.ndarray) -> np.ndarray:
        states = np.array([state_name(v) for v in labels])
        codes = np.column_stack([np.unique(n, return_inverse=True)[1] for n in nuisance.T]).astype(float)
        model, features, _ = fit_component(self.rig, CycleData(values, states, codes, self.healthy))
        self.chosen.append(features)
        names = {state_name(v): v for v in labels}
        return np.array([names.get(str(s), UNKNOWN_CODE) for s in model.predict(test)])


def _forest(values: np.ndarray, labels: np.ndarray, nuisance: np.ndarray, test: np.ndarray) -> np.ndarray:
    model = RandomForestClassifier(n_estimators=200, random_state=0, n_jobs=1)
    model.fit(cycle_statistics(values, 1.0), labels)
    return np.asarray(model.predict(cycle_statistics(test, 1.0)))


def _scores(truth: np.ndarray, predicted: np.ndarray) -> tuple[float, float]:
    f1 = f1_score(truth, predicted, labels=np.unique(truth), average="macro")  # unknown: wrong, not a class
    return 100 * accuracy_score(truth, predicted), 100 * f1


def evaluate(cycles: Cycles, component: str, others: list[str], fit: Fit, folds: int, seed: int) -> dict[str, float]:
    """Accuracy and macro-F1 (%) of one method on one component, random folds and honest split."""
    y = cycles.labels[component]
    nuisance = np.stack([cycles.labels[o] for o in others], axis=1)
    truth, predicted = [], []
    for train, test in random_folds(len(y), folds, seed):
        truth.append(y[test])
        predicted.append(fit(cycles.values[train], y[train], nuisance[train], cycles.values[test]))
    random_acc, random_f1 = _scores(np.concatenate(truth), np.concatenate(predicted))
    train, test = ordered_split(y)
    honest_acc, honest_f1 = _scores(y[test], fit(cycles.values[train], y[train], nuisance[train], cycles.values[test]))
    return {"random_acc": random_acc, "random_f1": random_f1, "honest_acc": honest_acc, "honest_f1": honest_f1}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--forest", action="store_true", help="add the baseline features with a random forest")
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", nargs="+", help="run only these methods (names as printed)")
    args = parser.parse_args(argv)
    loaded = shared_cycles("uci-hydraulic")
    if loaded is None:
        print(f"skipped: the UCI hydraulic data is not at {data_root() / 'uci-hydraulic'} (set HYDROWATCH_DATA)")
        return 0
    rig, cycles = loaded
    reference = cycles.channels.index("PS1")
    fast = [cycles.channels.index(c) for c in rig.recorded_at_least(FAST_HZ)]
    sensors = [cycles.channels.index(c.name) for c in rig.channels if c.role == "sensor"]
    methods: dict[str, Fit] = {
        "statistics+LDA": _Classifier("statistics", reference),
        "transients+LDA": _Classifier("transients", reference, fast),
        "transients shares+RR2": _Classifier("transients", reference, **TRANSIENTS),
        "entropy+LDA": _Classifier("entropy", reference, sensors),
    }
    methods["cycles method"] = _CyclesMethod(rig)
    if args.forest:
        methods["statistics+forest"] = _forest
    if args.only:
        methods = {k: v for k, v in methods.items() if k in args.only}
    print(
        f"UCI hydraulic rig: {len(cycles)} cycles, {len(cycles.channels)} channels at {cycles.grid_hz:g} Hz; "
        f"(a) {args.folds} random folds (seed {args.seed}), (b) honest split 70/30 per class in recording order"
    )
    print(
        f"{'component':12s} {'method':22s} {'(a) acc':>8s} {'(a) F1':>7s} {'(b) acc':>8s} {'(b) F1':>7s}  "
        "nuisance dims [folds..., honest]"
    )
    for component in rig.components:
        others = [c for c in rig.components if c != component]
        for name, fit in methods.items():
            if isinstance(fit, _Classifier):
                fit.healthy = float(rig.label(component).healthy)
            if isinstance(fit, _CyclesMethod):
                fit.healthy, fit.chosen = state_name(rig.label(component).healthy), []
            start = time.perf_counter()
            s = evaluate(cycles, component, others, fit, args.folds, args.seed)
            dims = fit.directions if isinstance(fit, _Classifier) and fit.features == "transients" else "-"
            if isinstance(fit, _Classifier):
                fit.directions = []
            if isinstance(fit, _CyclesMethod):
                dims = "features " + "/".join(fit.chosen)
            print(
                f"{component:12s} {name:22s} {s['random_acc']:8.1f} {s['random_f1']:7.1f} {s['honest_acc']:8.1f} "
                f"{s['honest_f1']:7.1f}  {dims} ({time.perf_counter() - start:.0f} s)",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
