"""The study's method trained: labelled recordings in, the fitted method and its evaluation out (Figure 6.4).

Wiring only, the maths lives in :mod:`hydrowatch.sysid` and :mod:`hydrowatch.health`:

1. the reference models (Box-Jenkins or NARX, one per sensor every recording has,
   :func:`~hydrowatch.methods.base.shared_sensors`) are fitted on the healthy state's
   reference part of the data plan (:mod:`hydrowatch.health.plan`, section 6.3);
2. their one-step prediction errors (Eq. 5.1) are computed on every state's data;
3. each state's base part gives its base distributions, its classifier part the windows whose
   relative entropies (Eq. 5.2/5.3) train the classifier (70/15/15, Table 6.3) and calibrate the
   open-set rule (:class:`hydrowatch.health.HealthModel`);
4. the held-out test windows give accuracy, per-class recall and the confusion matrix.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from hydrowatch.errors import DataError
from hydrowatch.health.classifier import HealthClassifier
from hydrowatch.health.features import RelativeEntropyFeatures
from hydrowatch.health.model import HealthModel
from hydrowatch.health.plan import split_state
from hydrowatch.log import event, get_logger
from hydrowatch.methods.base import HEALTHY, data_summary, ordered_states, shared_sensors
from hydrowatch.methods.entropy.reference import SensorReference
from hydrowatch.recording import INPUT, SENSORS, Recording
from hydrowatch.sysid.correlation import autocorrelation, confidence_bound, cross_correlation

if TYPE_CHECKING:
    from hydrowatch.training.options import TrainingSettings

_log = get_logger(__name__)

def _longest(runs: list[Recording]) -> Recording:
    return max(runs, key=len)


def fit_references(healthy: Recording, settings: TrainingSettings,
                   sensors: Sequence[str] = SENSORS) -> dict[str, SensorReference]:
    """Reference model of every sensor of ``sensors`` on the healthy reference part (first
    ``plan.reference_samples``)."""
    n = settings.plan.reference_samples
    if len(healthy) < n:
        raise DataError(
            f"the healthy recording must have at least {n} samples for the reference models. Got {len(healthy)}. "
            "Record longer or use a smaller plan (--reference-samples).",
            healthy.meta.get("source"),
        )
    u = healthy[INPUT][:n]
    refs = {}
    for sensor in sensors:
        t0 = time.perf_counter()
        refs[sensor] = SensorReference(kind=settings.reference, sensor=sensor,
                                       params=settings.reference_params()).fit(u, healthy[sensor][:n])
        event(_log, "reference model fitted", sensor=sensor, kind=settings.reference,
              nrmse=round(refs[sensor].nrmse_one_step_, 4), seconds=round(time.perf_counter() - t0, 1))
    return refs


def state_errors(bundle_refs: Mapping[str, SensorReference], runs: list[Recording]) -> np.ndarray:
    """Prediction errors of one state's runs, concatenated, shape (n, n_sensors); NaN rows during warm-up."""
    blocks = []
    for run in runs:
        u = run[INPUT]
        blocks.append(np.column_stack([ref.errors(u, run[s]) for s, ref in bundle_refs.items()]))
    return np.concatenate(blocks)


def fit_entropy(grouped: Mapping[str, list[Recording]],
                settings: TrainingSettings) -> tuple[dict[str, SensorReference], HealthModel, dict[str, Any]]:
    """Reference models, health model and what was measured on the way (``states``, ``base``, ``entropies``,
    ``evaluation``, ``reference``), from recordings grouped by state (``healthy`` among them).

    Raises
    ------
    DataError
        When a state has fewer samples than the data plan needs.
    """
    start = time.perf_counter()
    states = ordered_states(list(grouped))
    sensors = shared_sensors(grouped)
    refs = fit_references(_longest(list(grouped[HEALTHY])), settings, sensors)
    plan = settings.plan
    base: dict[str, np.ndarray] = {}
    windows: dict[str, np.ndarray] = {}
    correlations: dict[str, dict[str, Any]] = {}
    for state in states:
        runs = sorted(grouped[state], key=len, reverse=True) if state == HEALTHY else list(grouped[state])
        errors = state_errors(refs, runs)
        try:
            split = split_state(errors.shape[0], plan)
        except DataError as exc:
            raise DataError(f"state '{state}': {exc}") from None
        part = errors[split.base]
        base[state] = part[np.all(np.isfinite(part), axis=1)]
        windows[state] = errors[split.classifier]
        if state == HEALTHY:
            correlations = _correlations(runs[0][INPUT][split.base], part, sensors)
    features = RelativeEntropyFeatures(distribution=settings.distribution, window=plan.window, hop=plan.hop)
    classifier = HealthClassifier(hidden=settings.hidden, random_state=settings.seed)
    health = HealthModel(features=features, classifier=classifier).fit(base, windows, sensors)
    entropies = {s: health.features_.window_entropies(windows[s]) for s in states}
    evaluation = _evaluate(health)
    reference = {s: {"nrmse_one_step": r.nrmse_one_step_, "summary": r.summary(), "correlations": correlations[s]}
                 for s, r in refs.items()}
    event(_log, "trained", reference=settings.reference, accuracy=evaluation["test_accuracy"],
          seconds=round(time.perf_counter() - start, 1))
    manifest = {
        "method": "entropy", "reference": settings.reference, "states": states, "sensors": list(sensors),
        "window": plan.window, "hop": plan.hop, "warmup": max(r.warmup_ for r in refs.values()),
        "settings": settings.to_dict(), "data": data_summary(grouped, states),
        "metrics": {"test_accuracy": evaluation["test_accuracy"],
                    "nrmse_one_step": {s: r["nrmse_one_step"] for s, r in reference.items()}},
    }
    return refs, health, {"manifest": manifest, "base": base, "entropies": entropies, "evaluation": evaluation,
                          "reference": reference}


def _correlations(u: np.ndarray, errors: np.ndarray, sensors: Sequence[str],
                  max_lag: int = 20) -> dict[str, dict[str, Any]]:
    """Residual autocorrelation (Eq. 4.22) and input cross-correlation (Eq. 4.23) of each sensor's errors
    (columns in ``sensors`` order)."""
    ok = np.all(np.isfinite(errors), axis=1)
    out = {}
    for i, sensor in enumerate(sensors):
        e = errors[ok, i]
        acf, ccf = autocorrelation(e, max_lag), cross_correlation(u[ok], e, max_lag)
        bound = confidence_bound(e.size)
        out[sensor] = {"acf": acf.tolist(), "ccf": ccf.tolist(), "bound": float(bound),
                       "acf_inside": float(np.mean(np.abs(acf[1:]) <= bound)),
                       "ccf_inside": float(np.mean(np.abs(ccf) <= bound))}
    return out


def _evaluate(health: HealthModel) -> dict[str, Any]:
    report = health.report_
    labels = list(report["states"])
    matrix = np.asarray(report["confusion_matrix"])
    rows = matrix.sum(axis=1)
    recall = {s: (float(matrix[i, i] / rows[i]) if rows[i] else float("nan")) for i, s in enumerate(labels)}
    return {
        "test_accuracy": float(report["test_accuracy"]),
        "test_accuracy_with_open_set": float(report["test_accuracy_with_open_set"]),
        "known_rejected": float(report["known_rejected"]),
        "per_class_recall": recall, "labels": labels, "confusion_matrix": matrix.tolist(),
        "test_windows": int(rows.sum()), "ece": float(report["ece"]), "temperature": float(report["temperature"]),
    }
