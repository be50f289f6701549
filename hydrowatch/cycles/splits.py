"""Train/test splits of cycles: random folds, and the honest split in recording order.

Neighbouring cycles of a rig are near-identical, so random splits put near-copies of the test
cycles in the training set and flatter every method; the honest split trains on the earlier cycles
of each class and tests on the later ones.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from hydrowatch.errors import ParameterError


def ordered_split(labels: np.ndarray, train_fraction: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """Within each class, its first ``train_fraction`` of cycles (recording order) train, the rest test.

    Parameters
    ----------
    labels : ndarray, shape (n_cycles,)
        Class of each cycle, in recording order.
    train_fraction : float, default 0.7
        Share of each class's cycles used for training (rounded down, at least one each side).

    Returns
    -------
    train, test : ndarray of int
        Cycle indices, each sorted.
    """
    if not 0.0 < train_fraction < 1.0:
        raise ParameterError(f"train_fraction must be in (0, 1). Got {train_fraction}.")
    train, test = [], []
    for value in np.unique(labels):
        members = np.flatnonzero(labels == value)
        if members.size < 2:
            raise ParameterError(f"every class must have at least 2 cycles to split. Got {members.size} of {value!r}.")
        cut = min(max(int(members.size * train_fraction), 1), members.size - 1)
        train.append(members[:cut])
        test.append(members[cut:])
    return np.sort(np.concatenate(train)), np.sort(np.concatenate(test))


def random_folds(n_cycles: int, folds: int = 5, seed: int = 0) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """``folds`` random train/test splits of ``n_cycles`` cycles (each cycle tested once)."""
    if folds < 2 or n_cycles < folds:
        raise ParameterError(f"folds must be in [2, n_cycles={n_cycles}]. Got {folds}.")
    order = np.random.default_rng(seed).permutation(n_cycles)
    for part in np.array_split(order, folds):
        yield np.setdiff1d(order, part), np.sort(part)
