"""Cycle-based condition monitoring without plant physics (docs/rigs.md): per-cycle features,
load-change transients with nuisance projection, a per-component classifier, honest splits."""

from hydrowatch.cycles.classify import FEATURES, ComponentClassifier
from hydrowatch.cycles.features import cycle_statistics, statistic_names
from hydrowatch.cycles.splits import ordered_split, random_folds
from hydrowatch.cycles.transients import LoadChangeTransients, NuisanceProjection, load_changes

__all__ = [
    "FEATURES",
    "ComponentClassifier",
    "LoadChangeTransients",
    "NuisanceProjection",
    "cycle_statistics",
    "load_changes",
    "ordered_split",
    "random_folds",
    "statistic_names",
]
