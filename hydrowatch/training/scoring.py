"""Offline scoring of recordings window by window: the ``hydrowatch score --json`` objects (contract).

The bundle's method scores the recording (:meth:`HealthMethod.score <hydrowatch.methods.base.HealthMethod.score>`):
entropy bundles cut the prediction errors (after the reference models' warm-up) into windows and give
each its relative entropies per sensor and state (``kl``); parity bundles cut the raw signals into
windows from the first sample and give, in ``kl``, the relation scores per relation and state
(F[r, k] ≥ 1, about 1 for the state whose physics explains the window, docs/command-invariance.md)
and a degradation index. This module turns those into the contract's objects. A labelled recording
also gets its accuracy:
windows whose label is a trained state count as right when the verdict names it; windows of a
state the model was not trained on count as right when the verdict is ``unknown``; ``invalid``
windows are left out of the accuracy (they are counted).
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from hydrowatch.condition.degradation import Degradation
from hydrowatch.condition.forecast import part_forecast
from hydrowatch.errors import ParameterError
from hydrowatch.methods.base import check_channels
from hydrowatch.recording import SAMPLE_RATE_HZ, Recording
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.verdict import INVALID, UNKNOWN


def window_truth(recording: Recording, starts: np.ndarray, window: int, trained: list[str]) -> list[str | None]:
    """The expected verdict of each window: its label, ``unknown`` for an untrained label, None when unlabelled.

    Parameters
    ----------
    starts : ndarray of int, shape (n_windows,)
        First sample of each window, counted from the start of the recording.
    """
    labels = recording.meta.get("labels")
    out: list[str | None] = []
    for start in starts.tolist():
        if labels is not None:
            seen = set(np.asarray(labels[start : start + window]).astype(str).tolist())
            label = seen.pop() if len(seen) == 1 else None
        else:
            label = recording.state
        out.append(None if label is None else (label if label in trained else UNKNOWN))
    return out


def smoothing_for(bundle: ModelBundle, requested: int | None = None) -> int:
    """Windows each verdict pools: ``requested``, else the method's default (parity:
    :data:`~hydrowatch.condition.stream.POOLED_WINDOWS`; 1 for methods whose verdicts are per window)."""
    if requested is not None:
        return requested
    return bundle.health_method.default_smoothing


def score_recording(bundle: ModelBundle, recording: Recording, smoothing: int = 1) -> dict[str, Any]:
    """The contract's object for one recording: ``source``, ``windows``, ``summary``.

    ``smoothing`` (parity bundles): valid windows whose evidence each verdict pools, the window
    itself and the ones before it (:meth:`ConditionModel.judge`; 1: each window alone, as the
    scorer service's ``--smoothing``). Bundles of methods that do not pool (entropy) take only 1.

    ``windows[i]`` has ``start_s`` (time of its first sample, s), ``state``, ``probability``,
    ``probabilities`` (state → p), ``kl`` (sensor → state → relative entropy, nats) and, for
    ``invalid``/``unknown`` windows, ``reason``; ``truth`` when the recording is labelled; parity bundles add
    ``degradation`` (fault → ``{"value", "ci95"}``, the index of :mod:`hydrowatch.condition.degradation`) to every
    window that is not ``invalid``.
    ``summary`` has ``windows``, ``counts`` (state → n), ``accuracy`` (None when unlabelled),
    ``model_version`` and, for parity bundles, ``forecast`` (fault → :meth:`Forecast.to_dict
    <hydrowatch.condition.forecast.Forecast.to_dict>`, :func:`degradation_forecast`).

    Raises
    ------
    DataError
        When the recording lacks a channel the bundle's method reads (naming it).
    """
    check_channels(bundle.health_method, recording)
    if int(smoothing) != smoothing or smoothing < 1 or (smoothing > 1 and not bundle.health_method.pools):
        raise ParameterError(f"smoothing must be an integer >= 1, and 1 for a bundle whose method does not pool "
                             f"(entropy). Got {smoothing!r} ({bundle.method} bundle); pooling windows is the parity "
                             "method's.")
    window = bundle.window
    warmup = bundle.warmup
    t = recording.t
    windows: list[dict[str, Any]] = []
    have = max(0, len(recording) - warmup)
    degradation: Degradation | None = None
    if have < window:
        windows.append({
            "start_s": float(t[0]) if len(t) else 0.0, "state": INVALID, "probability": None, "probabilities": {},
            "kl": {}, "reason": f"too short: {have} samples after the {warmup}-sample warm-up, a window needs {window} "
                                f"({window / SAMPLE_RATE_HZ:g} s)",
        })
        truths: list[str | None] = [None]
    else:
        scored = bundle.health_method.score(recording, smoothing)
        starts, verdicts, kl, degradation = scored.starts, scored.verdicts, scored.scores, scored.degradation
        truths = window_truth(recording, starts + warmup, window, bundle.states)
        for i, (start, verdict) in enumerate(zip(starts.tolist(), verdicts)):
            item: dict[str, Any] = {"start_s": float(t[start + warmup]), **verdict.to_dict()}
            if verdict.state == UNKNOWN and "reason" not in item:
                item["reason"] = "no trained state explains the window (open-set rule)"
            item["kl"] = {} if verdict.state == INVALID else {
                s: {k: float(kl[i, j, m]) for m, k in enumerate(bundle.states)} for j, s in enumerate(bundle.kl_rows)
            }
            if degradation is not None and verdict.state != INVALID:
                item["degradation"] = degradation.window(i)
            if truths[i] is not None:
                item["truth"] = truths[i]
            windows.append(item)
    summary_extra: dict[str, Any] = {}
    if degradation is not None:
        summary_extra["forecast"] = degradation_forecast(windows, degradation)
    counts = Counter(w["state"] for w in windows)
    judged = [(w["state"], truth) for w, truth in zip(windows, truths) if truth is not None and w["state"] != INVALID]
    accuracy = float(np.mean([p == tr for p, tr in judged])) if judged else None
    return {
        "source": str(recording.meta.get("source", "")),
        "windows": windows,
        "summary": {"windows": len(windows), "counts": dict(counts), "accuracy": accuracy,
                    "model_version": bundle.version, **summary_extra},
    }


def degradation_forecast(windows: list[dict[str, Any]], degradation: Degradation) -> dict[str, Any]:
    """``summary["forecast"]``: per fault, :func:`~hydrowatch.condition.forecast.forecast_alert` of its index over
    the recording's windows (``start_s``). Invalid windows have no index; ``unknown`` ones keep theirs (the index
    is a physical estimate whatever the verdict, and an untrained fault wearing is exactly what must be forecast);
    windows where a valve-side look-alike was blamed are left out of that part's history
    (:meth:`~hydrowatch.condition.degradation.Degradation.history`), and a valve-side part the last window rules out
    has none (:func:`~hydrowatch.condition.forecast.part_forecast`); a part sharing its index with a look-alike says
    so (``untold_from``)."""
    t = np.array([w["start_s"] for w in windows])
    return {f: part_forecast(t, degradation, f).to_dict() for f in degradation.parts()}


def pooled_accuracy(results: list[dict[str, Any]]) -> tuple[float | None, list[str], list[str]]:
    """Accuracy over every judged, labelled window of several scored recordings, with the (truth, verdict) lists."""
    truth, verdict = [], []
    for result in results:
        for w in result["windows"]:
            if "truth" in w and w["state"] != INVALID:
                truth.append(w["truth"])
                verdict.append(w["state"])
    accuracy = float(np.mean(np.asarray(truth) == np.asarray(verdict))) if truth else None
    return accuracy, truth, verdict


def scoring_metrics(result: dict[str, Any], prefix: str = "") -> tuple[dict[str, float], list[tuple[str, float, int]]]:
    """What an MLflow run of ``score`` logs for one scored recording (:func:`score_recording`'s object).

    Returns
    -------
    summary : dict of str to float
        ``windows``, ``accuracy`` (when labelled), ``count.<state>``, and per fault ``forecast.<fault>.alert_in_s``
        [s] (when there is a forecast), ``.rate_per_h`` [1/h], ``.level`` [1] (when fitted).
    steps : list of (key, value, step)
        ``degradation.<fault>`` [1], ``degradation.<fault>.low`` and ``.high`` per window that has an index, step =
        the window's position in the recording (MLflow draws each as a curve over the windows).

    Every key is preceded by ``prefix`` (several files in one run).
    """
    s = result["summary"]
    summary: dict[str, float] = {f"{prefix}windows": float(s["windows"])}
    if s.get("accuracy") is not None:
        summary[f"{prefix}accuracy"] = float(s["accuracy"])
    summary.update({f"{prefix}count.{state}": float(n) for state, n in s["counts"].items()})
    for fault, f in (s.get("forecast") or {}).items():
        for name in ("alert_in_s", "rate_per_h", "level"):
            if f.get(name) is not None:
                summary[f"{prefix}forecast.{fault}.{name}"] = float(f[name])
    steps = []
    for i, w in enumerate(result["windows"]):
        for fault, d in (w.get("degradation") or {}).items():
            steps += [(f"{prefix}degradation.{fault}", float(d["value"]), i),
                      (f"{prefix}degradation.{fault}.low", float(d["ci95"][0]), i),
                      (f"{prefix}degradation.{fault}.high", float(d["ci95"][1]), i)]
    return summary, steps
