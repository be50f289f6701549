"""Open set on the UCI hydraulic rig: train without one level of a component; do its cycles read unknown?

For each component and each of its levels L: the component's honest split (first 70 % of each
class's cycles train, last 30 % test) with every cycle of L removed from training; an
:class:`hydrowatch.cycles.openset.OpenSetComponent` (thresholds calibrated inside the training
cycles) is fitted and reports

- ``L unknown``: the share of all of L's cycles that read ``unknown`` (want 100 %);
- ``known unknown``: the share of the known levels' test cycles that read ``unknown`` (want 0 %);
- ``known acc``: accuracy on those test cycles, an ``unknown`` counted wrong.

The accumulator is judged with the plain statistics, the plain transients of the fast channels and the ``cycles``
method's transients (``cycles-tr``); the statistics use every channel, as the method's do.

    OMP_NUM_THREADS=1 python benchmarks/bench_uci_openset.py   (about 1 min on one core)
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from hydrowatch.cycles import ComponentClassifier, ordered_split
from hydrowatch.cycles.openset import UNKNOWN, OpenSetComponent
from hydrowatch.io.wide import Cycles, shared_cycles
from hydrowatch.methods.cycles.train import TRANSIENTS
from hydrowatch.rig import data_root

METHOD_TRANSIENTS = "cycles-tr"
"""The ``cycles`` method's transients (``TRANSIENTS``: every channel, step shares, 2 discriminants, the covered trees'
vote), beside the plain transients of the fast channels."""
FAST_HZ = 10.0
"""Channels recorded at this rate or faster have their transients as features (as in bench_uci.py)."""


def held_out(
    cycles: Cycles, fast: list[int], component: str, others: list[str], level: float, features: str
) -> tuple[float, ...]:
    """(L unknown, known unknown, known acc), % for one held-out level."""
    y = cycles.labels[component]
    nuisance = np.stack([cycles.labels[o] for o in others], axis=1)
    train, test = ordered_split(y)
    train, test = train[y[train] != level], test[y[test] != level]
    reference = cycles.channels.index("PS1")
    classifier = (ComponentClassifier(features="transients", reference=reference, **TRANSIENTS)
                  if features == METHOD_TRANSIENTS else
                  ComponentClassifier(features=features, reference=reference,
                                      channels=fast if features == "transients" else None))  # statistics: every channel
    model = OpenSetComponent(classifier).fit(cycles.values[train], y[train], nuisance[train])
    unseen = model.predict(cycles.values[y == level])
    known = model.predict(cycles.values[test])
    return (
        100 * float(np.mean(unseen == UNKNOWN)),
        100 * float(np.mean(known == UNKNOWN)),
        100 * float(np.mean(known == y[test])),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.parse_args(argv)
    loaded = shared_cycles("uci-hydraulic")
    if loaded is None:
        print(f"skipped: the UCI hydraulic data is not at {data_root() / 'uci-hydraulic'} (set HYDROWATCH_DATA)")
        return 0
    rig, cycles = loaded
    fast = [cycles.channels.index(c) for c in rig.recorded_at_least(FAST_HZ)]
    header = ["component", "held out", "features", "L unknown", "known unknown", "known acc"]
    print("{:12s} {:>8s} {:11s} {:>9s} {:>13s} {:>9s}".format(*header))
    for component in rig.components:
        others = [c for c in rig.components if c != component]
        methods = ("statistics", "transients", METHOD_TRANSIENTS) if component == "accumulator" else ("statistics",)
        for level in rig.label(component).values:
            for features in methods:
                unseen, false_unknown, accuracy = held_out(cycles, fast, component, others, float(level), features)
                print(
                    f"{component:12s} {float(level):8g} {features:11s} {unseen:9.1f} {false_unknown:13.1f} "
                    f"{accuracy:9.1f}",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
