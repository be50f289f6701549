"""Accuracy of a bundle on recordings made apart from its training data (another seed, other commands).

Three kinds of command, as in issue 5: ``"training"`` (the study's filtered noise on 0-4 V, like
the identification data), ``"duty_cycle"`` (holds, ramps and steps on 0-4 V,
:func:`hydrowatch.plant.excitation.duty_cycle`, the same command driving every state) and
``"narrow_range"`` (filtered noise on another range, 1-3 V). Either method's bundle.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.health.metrics import confusion_matrix, per_class_recall, weakest_recall
from hydrowatch.plant.excitation import duty_cycle
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.scoring import pooled_accuracy, score_recording
from hydrowatch.verdict import UNKNOWN

COMMANDS = ("training", "duty_cycle", "narrow_range")
NARROW_VOLTS = (1.0, 3.0)
"""Voltage range of the ``narrow_range`` command, V."""


def measure_accuracy(
    bundle: ModelBundle, *, command: str = "training", seconds: float = 60.0, seed: int = 100,
    states: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Simulate every trained state under ``command`` with ``seed`` and score it window by window.

    Returns
    -------
    dict
        ``command``, ``seconds``, ``seed``, ``accuracy`` (judged windows), ``windows``,
        ``per_class_recall``, ``labels`` and ``confusion_matrix`` (true rows; ``unknown`` column last).
    """
    if command not in COMMANDS:
        raise ParameterError(f"command must be one of {COMMANDS}. Got {command!r}.")
    states = list(states or bundle.states)
    voltage = duty_cycle(seconds, seed=seed) if command == "duty_cycle" else None
    volts = NARROW_VOLTS if command == "narrow_range" else (0.0, 4.0)
    recordings = simulate_states(states, seconds=seconds, volts=volts, command=voltage, seed=seed, fleet="accuracy")
    results = [score_recording(bundle, r) for r in recordings]
    accuracy, truth, verdict = pooled_accuracy(results)
    labels = [*states, UNKNOWN]
    return {
        "command": command, "seconds": seconds, "seed": seed, "accuracy": accuracy, "windows": len(truth),
        "per_class_recall": per_class_recall(np.asarray(truth), np.asarray(verdict), states),
        "labels": labels, "confusion_matrix": confusion_matrix(np.asarray(truth), np.asarray(verdict), labels).tolist(),
    }


def accuracy_metrics(checks: Sequence[dict[str, Any]]) -> dict[str, float]:
    """MLflow metrics of :func:`measure_accuracy` results, per command: ``accuracy.<command>``, ``windows.<command>``
    (windows judged), ``recall_min.<command>`` (the weakest state's recall) and ``recall.<command>.<state>``."""
    out: dict[str, float] = {}
    for a in checks:
        command, recall = a["command"], a["per_class_recall"]
        if a["accuracy"] is not None:
            out[f"accuracy.{command}"] = float(a["accuracy"])
        out[f"windows.{command}"] = float(a["windows"])
        out[f"recall_min.{command}"] = weakest_recall(recall)
        out.update({f"recall.{command}.{s}": float(r) for s, r in recall.items()})
    return out
