"""Which 3 sensors suffice on the UCI hydraulic rig (issue 17's sparse-sensor question).

Greedy forward selection (:func:`hydrowatch.cycles.sparse.greedy_channels`) with the plain baseline
(statistics + LDA). A set is chosen on training cycles only (validation: the honest split inside
them) and judged on the honest split's test cycles:

- per component: chosen on that component's training cycles;
- the accumulator with the transient features (bench_uci.py), chosen among the fast channels;
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

FAST_HZ = 10.0
"""For the transients: channels recorded at this rate or faster (as in bench_uci.py)."""


def honest_accuracy(
    cycles: Cycles, component: str, channels: tuple[int, ...], features: str = "statistics", reference: int = 0
) -> float:
    """Honest-split test accuracy (%) of a classifier whose features are made of ``channels`` only."""
    y = cycles.labels[component]
    nuisance = _others(cycles, component)
    train, test = ordered_split(y)
    model = ComponentClassifier(features=features, reference=reference, channels=channels)
    model.fit(cycles.values[train], y[train], nuisance[train])
    return 100 * float(np.mean(model.predict(cycles.values[test]) == y[test]))


def _others(cycles: Cycles, component: str) -> np.ndarray:
    """The other components' conditions, shape (n_cycles, n_others)."""
    return np.stack([v for name, v in cycles.labels.items() if name not in (component, "stable")], axis=1)


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
    component = "accumulator"
    y = cycles.labels[component]
    train, _ = ordered_split(y)
    fast = [cycles.channels.index(c) for c in rig.recorded_at_least(FAST_HZ)]
    reference = cycles.channels.index("PS1")
    nuisance = {component: _others(cycles, component)[train]}
    steps = greedy_channels(
        lambda chs: validation_score(
            cycles.values[train],
            {component: y[train]},
            [fast[i] for i in chs],
            "transients",
            reference=reference,
            nuisance=nuisance,
        ),
        len(fast),
        args.size,
    )
    picked, score = tuple(fast[i] for i in steps[-1][0]), steps[-1][1]
    print(
        f"{component:12s} {'its training, transients':28s} {_names(cycles, picked):22s} {100 * score:10.1f} "
        f"{honest_accuracy(cycles, component, picked, 'transients', reference):8.1f} "
        f"{honest_accuracy(cycles, component, tuple(fast), 'transients', reference):7.1f} (all {len(fast)} fast)",
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
