"""Verdicts of windows from their feature vectors: the calibrated classifier and the open-set rule.

:func:`judge` turns feature vectors (relative entropies; the parity method's relation scores)
into :class:`~hydrowatch.verdict.Verdict` objects; the shared verdict type and its smoothing
live in :mod:`hydrowatch.verdict`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hydrowatch.health.classifier import HealthClassifier
from hydrowatch.health.openset import OpenSetRule
from hydrowatch.verdict import INVALID, UNKNOWN, Verdict


def judge(
    features: np.ndarray,
    classifier: HealthClassifier,
    open_set: OpenSetRule | None = None,
    reasons: Sequence[str | None] | None = None,
) -> list[Verdict]:
    """Verdicts of windows from their feature vectors.

    Parameters
    ----------
    features : ndarray, shape (n_windows, n_sensors * n_states)
        Relative entropies (``RelativeEntropyFeatures.transform``); NaN rows are invalid windows.
    classifier : HealthClassifier
    open_set : OpenSetRule, optional
        Without it no window reads ``unknown``.
    reasons : sequence of str or None, optional
        Why each window is invalid (``RelativeEntropyFeatures.window_reasons``).
    """
    f = np.atleast_2d(np.asarray(features, dtype=np.float64))
    proba = classifier.predict_proba(f)
    classes = classifier.classes_.tolist()
    novelty = open_set.score(f) if open_set is not None else np.full(f.shape[0], np.nan)
    unknown = open_set.is_unknown(f, proba) if open_set is not None else np.zeros(f.shape[0], dtype=bool)
    out = []
    for i in range(f.shape[0]):
        why = reasons[i] if reasons is not None else None
        if why is not None or not np.all(np.isfinite(f[i])):
            out.append(Verdict(INVALID, None, {}, why or "relative entropies are not finite"))
            continue
        probs = {c: float(p) for c, p in zip(classes, proba[i])}
        nov = None if np.isnan(novelty[i]) else float(novelty[i])
        if unknown[i]:
            out.append(Verdict(UNKNOWN, None, probs, None, nov))
        else:
            top = int(np.argmax(proba[i]))
            out.append(Verdict(classes[top], float(proba[i, top]), probs, None, nov))
    return out
