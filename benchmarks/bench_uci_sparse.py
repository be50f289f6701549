"""Which 3 sensors suffice on the UCI hydraulic rig (issue 17's sparse-sensor question).

Greedy forward selection (:func:`hydrowatch.cycles.sparse.greedy_channels`) with the plain baseline
(statistics + LDA). A set is chosen on training cycles only (validation: the honest split inside
them) and judged on the honest split's test cycles:

- per component: chosen on that component's training cycles;
- one set for all four: chosen on the cycles that are training cycles of every component (the
  mean validation accuracy over the components), then each component fitted on its own training
  cycles with that set.

    OMP_NUM_THREADS=1 python benchmarks/bench_uci_sparse.py [--size 3]   (about 1 min on one core)
"""

from __future__ import annotations

import argparse
import sys
from functools import reduce

import numpy as np

from hydrowatch.cycles import ComponentClassifier, ordered_split
from hydrowatch.cycles.sparse import greedy_channels, validation_score
from hydrowatch.io.wide import Cycles, shared_cycles
from hydrowatch.rig import data_root


def honest_accuracy(cycles: Cycles, component: str, channels: tuple[int, ...]) -> float:
    """Honest-split test accuracy (%) of statistics + LDA reading only ``channels``."""
    y = cycles.labels[component]
    train, test = ordered_split(y)
    values = cycles.values[:, list(channels), :]
    model = ComponentClassifier(features="statistics").fit(values[train], y[train])
    return 100 * float(np.mean(model.predict(values[test]) == y[test]))


def _names(cycles: Cycles, channels: tuple[int, ...]) -> str:
    return ",".join(cycles.channels[c] for c in channels)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=3, help="sensors in the set (default 3)")
    args = parser.parse_args(argv)
    loaded = shared_cycles("uci-hydraulic")
    if loaded is None:
        print(f"skipped: the UCI hydraulic data is not at {data_root() / 'uci-hydraulic'} (set HYDROWATCH_DATA)")
        return 0
    rig, cycles = loaded
    n = len(cycles.channels)
    every = tuple(range(n))
    print(f"{'component':12s} {'chosen on':28s} {'sensors':22s} {'validation':>10s} {'(b) acc':>8s} {'all 17':>7s}")
    for component in rig.components:
        y = cycles.labels[component]
        train, _ = ordered_split(y)
        steps = greedy_channels(
            lambda chs, y=y, train=train: validation_score(cycles.values[train], {"c": y[train]}, chs),
            n,
            args.size,
        )
        chosen, score = steps[-1]
        print(
            f"{component:12s} {'its own training cycles':28s} {_names(cycles, chosen):22s} {100 * score:10.1f} "
            f"{honest_accuracy(cycles, component, chosen):8.1f} {honest_accuracy(cycles, component, every):7.1f}",
            flush=True,
        )
    common = reduce(np.intersect1d, [ordered_split(cycles.labels[c])[0] for c in rig.components])
    labels = {c: cycles.labels[c][common] for c in rig.components}
    steps = greedy_channels(lambda chs: validation_score(cycles.values[common], labels, chs), n, args.size)
    chosen, score = steps[-1]
    print(
        f"one set for all four, chosen on the {len(common)} cycles that train every component "
        f"(greedy steps: {'; '.join(f'{_names(cycles, s)} {100 * v:.1f}' for s, v in steps)})"
    )
    for component in rig.components:
        print(
            f"{component:12s} {'the common set':28s} {_names(cycles, chosen):22s} {100 * score:10.1f} "
            f"{honest_accuracy(cycles, component, chosen):8.1f} {honest_accuracy(cycles, component, every):7.1f}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
