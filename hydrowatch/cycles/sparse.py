"""Which few sensors suffice: greedy forward selection of channels by validation accuracy.

The score of a set of channels is the mean, over the components, of the accuracy of a
:class:`~hydrowatch.cycles.classify.ComponentClassifier` fitted on the first 70 % of each class's
training cycles and checked on the last 30 % (the honest split inside the training cycles), so
that the cycles a selection is finally judged on never choose it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from hydrowatch.cycles.classify import ComponentClassifier
from hydrowatch.cycles.splits import ordered_split
from hydrowatch.errors import ParameterError


def greedy_channels(
    score: Callable[[tuple[int, ...]], float], n_channels: int, size: int
) -> list[tuple[tuple[int, ...], float]]:
    """Grow a set of channels one at a time, each time adding the one that scores best.

    Parameters
    ----------
    score : callable
        Score of a tuple of channel indices (higher is better); ties go to the lower index.
    n_channels : int
        Channels to choose from (indices ``0 .. n_channels - 1``).
    size : int
        Channels in the final set.

    Returns
    -------
    list of (channels, score)
        The set after each step, ``size`` entries.
    """
    if not 1 <= size <= n_channels:
        raise ParameterError(f"size must be in [1, n_channels={n_channels}]. Got {size}.")
    chosen: tuple[int, ...] = ()
    steps = []
    for _ in range(size):
        candidates = [(score((*chosen, c)), -c) for c in range(n_channels) if c not in chosen]
        best, negative = max(candidates)
        chosen = (*chosen, -negative)
        steps.append((chosen, best))
    return steps


def validation_score(
    values: np.ndarray,
    labels: Mapping[str, np.ndarray],
    channels: Sequence[int],
    features: str = "statistics",
    grid_hz: float = 1.0,
    *,
    reference: int = 0,
    nuisance: Mapping[str, np.ndarray] | None = None,
) -> float:
    """Mean validation accuracy over components of a classifier that reads only ``channels``.

    Parameters
    ----------
    values : ndarray, shape (n_cycles, n_channels, n_samples)
        Training cycles in recording order.
    labels : mapping of str to ndarray, shape (n_cycles,)
        Each component's condition per cycle.
    channels : sequence of int
        The channels the classifier's features are made of.
    features, grid_hz, reference
        As :class:`ComponentClassifier` (``reference`` locates the load changes for ``transients``
        and may lie outside ``channels``).
    nuisance : mapping of str to ndarray, shape (n_cycles, n_others), optional
        Per component, the other components' conditions (``transients``).
    """
    accuracies = []
    for name, y in labels.items():
        fit, check = ordered_split(y)
        others = None if nuisance is None else nuisance[name][fit]
        model = ComponentClassifier(features=features, grid_hz=grid_hz, reference=reference, channels=channels)
        model.fit(values[fit], y[fit], others)
        accuracies.append(float(np.mean(model.predict(values[check]) == y[check])))
    return float(np.mean(accuracies))
