"""Classification metrics as plain functions (reports and MLflow use them).

Confusion matrices have the **true** state on rows and the **predicted** state on columns
(scikit-learn's convention; the study's Matlab plots, Figures 5.18, 6.10, 6.11, show the transpose).
Predicted labels may include ``"unknown"`` (open-set rejection); such windows count as wrong for
accuracy and recall and get their own column when ``"unknown"`` is listed in ``labels``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from hydrowatch.errors import DataError, ParameterError


def _pair(y_true: Sequence[str] | np.ndarray, y_pred: Sequence[str] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t, p = np.asarray(y_true), np.asarray(y_pred)
    if t.shape != p.shape or t.ndim != 1:
        raise DataError(f"y_true and y_pred must be 1-D of the same length. Got shapes {t.shape} and {p.shape}.")
    return t, p


def accuracy(y_true: Sequence[str] | np.ndarray, y_pred: Sequence[str] | np.ndarray) -> float:
    """Share of windows whose predicted state equals the true one (NaN for no windows)."""
    t, p = _pair(y_true, y_pred)
    return float(np.mean(t == p)) if t.size else float("nan")


def confusion_matrix(
    y_true: Sequence[str] | np.ndarray, y_pred: Sequence[str] | np.ndarray, labels: Sequence[str]
) -> np.ndarray:
    """Counts, shape (len(labels), len(labels)): ``[i, j]`` = windows of state ``labels[i]`` predicted ``labels[j]``.

    Pairs whose true or predicted label is not in ``labels`` are not counted.
    """
    t, p = _pair(y_true, y_pred)
    index = {label: i for i, label in enumerate(labels)}
    m = np.zeros((len(labels), len(labels)), dtype=np.int64)
    for a, b in zip(t.tolist(), p.tolist()):
        if a in index and b in index:
            m[index[a], index[b]] += 1
    return m


def per_class_recall(
    y_true: Sequence[str] | np.ndarray, y_pred: Sequence[str] | np.ndarray, labels: Sequence[str]
) -> dict[str, float]:
    """Per state, the share of its windows predicted as that state (NaN when it has none)."""
    t, p = _pair(y_true, y_pred)
    out = {}
    for label in labels:
        mine = t == label
        out[label] = float(np.mean(p[mine] == label)) if mine.any() else float("nan")
    return out


def weakest_recall(recall: Mapping[str, float]) -> float:
    """The lowest of :func:`per_class_recall`'s values over the states that had windows (NaN when none had)."""
    seen = [r for r in recall.values() if np.isfinite(r)]
    return float(min(seen)) if seen else float("nan")


def expected_calibration_error(probabilities: np.ndarray, y_true_index: np.ndarray, n_bins: int = 15) -> float:
    """Expected calibration error: ``sum_b (n_b / n) |accuracy_b - confidence_b|`` over confidence bins.

    Parameters
    ----------
    probabilities : ndarray, shape (n, n_states)
        Predicted probabilities (rows sum to 1).
    y_true_index : ndarray of int, shape (n,)
        Column of the true state.
    n_bins : int, default 15
        Equal-width bins of the top probability on [0, 1].
    """
    prob = np.asarray(probabilities, dtype=np.float64)
    y = np.asarray(y_true_index)
    if prob.ndim != 2 or y.shape != (prob.shape[0],):
        raise DataError(f"probabilities must be (n, n_states) and y_true_index (n,). Got {prob.shape}, {y.shape}.")
    if n_bins < 1:
        raise ParameterError(f"n_bins must be >= 1. Got {n_bins}.")
    if prob.shape[0] == 0:
        return float("nan")
    confidence = prob.max(axis=1)
    correct = prob.argmax(axis=1) == y
    bins = np.minimum((confidence * n_bins).astype(int), n_bins - 1)
    ece = 0.0
    for b in range(n_bins):
        inside = bins == b
        if inside.any():
            ece += inside.mean() * abs(correct[inside].mean() - confidence[inside].mean())
    return float(ece)
