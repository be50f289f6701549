"""The parity method trained: labelled recordings in, the fitted condition model and its evaluation out.

Wiring only, the maths lives in :mod:`hydrowatch.condition` (docs/command-invariance.md):

1. each state's recordings are cut into raw windows of voltage, flow, speed, torque (and the oil
   temperature when every recording has it), ``plan.window`` samples every ``plan.hop``; the relations
   read the sensors every recording has (:func:`~hydrowatch.methods.base.shared_sensors`; a sensor they
   lack is NaN in the windows and filled from the nominal relations, docs/command-invariance.md); the first
   85 % of every run fits, the last :data:`TEST_FRACTION` is held out (whole windows, no overlap
   with the fitted part);
2. :class:`~hydrowatch.condition.ConditionModel` fits each state's severity level and box, the
   relations' residual floors, the nearest-physics rule's temperature and the open-set rule;
3. the held-out windows give accuracy, per-class recall, the confusion matrix and the calibration.

The bundle scores non-overlapping windows (hop = window): a verdict every ``plan.window`` samples
at half the cost of the entropy method's overlapping hop.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from hydrowatch.condition import ConditionFeatures, ConditionModel, windows_from_recording
from hydrowatch.condition.layout import WIDTH
from hydrowatch.condition.rule import ParityRule
from hydrowatch.errors import DataError
from hydrowatch.health.metrics import confusion_matrix, expected_calibration_error, per_class_recall
from hydrowatch.log import event, get_logger
from hydrowatch.methods.base import data_summary, ordered_states, shared_sensors
from hydrowatch.recording import Recording
from hydrowatch.verdict import UNKNOWN

if TYPE_CHECKING:
    from hydrowatch.training.options import TrainingSettings

_log = get_logger(__name__)
TEST_FRACTION = 0.15
"""Share of every run's samples held out for the test windows."""


def uses_temperature(grouped: Mapping[str, list[Recording]]) -> bool:
    """Whether every recording carries the oil temperature (then windows get it as 5th channel)."""
    return all("temperature" in r.channels for runs in grouped.values() for r in runs)


def split_windows(runs: list[Recording], window: int, hop: int, temperature: bool) -> tuple[np.ndarray, np.ndarray]:
    """Fit and test windows of one state's runs, shapes (m_fit, window, c) and (m_test, window, c).

    Every run of ``n`` samples gives its first ``n − round(TEST_FRACTION·n)`` samples to the fit
    windows and the rest to the test windows (a run too short for a test window gives none).
    """
    fit: list[np.ndarray] = []
    test: list[np.ndarray] = []
    for run in runs:
        cut = len(run) - int(round(TEST_FRACTION * len(run)))
        for part, into in ((run.slice(0, cut), fit), (run.slice(cut, len(run)), test)):
            if len(part) >= window:
                into.append(windows_from_recording(part, window, hop, temperature=temperature))
    channels = WIDTH + 1 if temperature else WIDTH
    empty = np.empty((0, window, channels))
    return (np.concatenate(fit) if fit else empty), (np.concatenate(test) if test else empty)


def fit_parity(grouped: Mapping[str, list[Recording]],
               settings: TrainingSettings) -> tuple[ConditionModel, bool, dict[str, Any]]:
    """The condition model, whether it reads the temperature, and what was measured on the way (``manifest``,
    ``scores``, ``evaluation``), from recordings grouped by health state (see the module docstring).

    Raises
    ------
    DataError
        When a state has fewer than 2 valid fit windows.
    """
    start = time.perf_counter()
    plan = settings.plan
    states = ordered_states(list(grouped))
    temperature = uses_temperature(grouped)
    fit: dict[str, np.ndarray] = {}
    test: dict[str, np.ndarray] = {}
    for state in states:
        fit[state], test[state] = split_windows(list(grouped[state]), plan.window, plan.hop, temperature)
        if fit[state].shape[0] < 2:
            raise DataError(f"state '{state}' must have at least 2 windows of {plan.window} samples to fit. Got "
                            f"{fit[state].shape[0]}. Record longer.")
    features = ConditionFeatures(window=plan.window, hop=plan.window, sensors=tuple(shared_sensors(grouped)))
    model = ConditionModel(features=features).fit(fit)
    scores = {s: model.features_.transform(test[s]) if test[s].shape[0] else
              np.empty((0, len(model.features_.feature_names_))) for s in states}
    evaluation = evaluate(model, test)
    if isinstance(model.decision_, ParityRule):  # logged: the fitted temperature, floored (docs/command-invariance.md)
        evaluation["rule_temperature"] = model.decision_.temperature_
    n_rel = len(model.features_.relations_)
    window_scores = {s: x.reshape(x.shape[0], n_rel, len(states)) for s, x in scores.items()}
    data = data_summary(grouped, states)
    for s in states:  # the window counts go between the samples and the sources, as they always did
        data[s] = {"runs": data[s]["runs"], "samples": data[s]["samples"], "fit_windows": int(fit[s].shape[0]),
                   "test_windows": int(test[s].shape[0]), "sources": data[s]["sources"]}
    manifest = {
        "method": "parity", "reference": None, "states": states, "sensors": list(model.features_.sensors),
        "relations": list(model.features_.relations_), "window": plan.window, "hop": plan.window, "warmup": 0,
        "temperature": temperature, "settings": settings.to_dict(), "data": data,
        "metrics": {"test_accuracy": evaluation["test_accuracy"], "levels": model.features_.levels_,
                    "floors": model.features_.floors_},
    }
    event(_log, "trained", method="parity", accuracy=evaluation["test_accuracy"],
          seconds=round(time.perf_counter() - start, 1))
    return model, temperature, {"manifest": manifest, "scores": window_scores, "evaluation": evaluation}


def evaluate(model: ConditionModel, test: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Held-out evaluation: the decision alone (``test_accuracy``) and with the open-set rule.

    Keys as the entropy trainer's: ``test_accuracy``, ``test_accuracy_with_open_set``,
    ``known_rejected`` (share read ``unknown``), ``per_class_recall``, ``labels``,
    ``confusion_matrix`` (true rows), ``test_windows``, ``ece``. Invalid windows are left out.
    """
    states = list(model.features_.states_)
    truth, judged, proba = [], [], []
    for s in states:
        for v in (model.judge(test[s]) if test[s].shape[0] else []):
            if v.probabilities:
                truth.append(s)
                judged.append(v.state)
                proba.append([v.probabilities[k] for k in states])
    if not truth:
        raise DataError("the held-out part must give at least one valid test window. Got none. Record longer.")
    p = np.asarray(proba)
    y, verdict = np.asarray(truth), np.asarray(judged)
    predicted = np.asarray(states)[np.argmax(p, axis=1)]
    index = {s: i for i, s in enumerate(states)}
    return {
        "test_accuracy": float(np.mean(predicted == y)),
        "test_accuracy_with_open_set": float(np.mean(verdict == y)),
        "known_rejected": float(np.mean(verdict == UNKNOWN)),
        "per_class_recall": per_class_recall(y, predicted, states), "labels": states,
        "confusion_matrix": confusion_matrix(y, predicted, states).tolist(), "test_windows": int(y.size),
        "ece": expected_calibration_error(p, np.array([index[s] for s in truth])),
    }
