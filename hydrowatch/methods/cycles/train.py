"""Fitting the per-cycle method: one open-set classifier per component of a rig, and its honest evaluation.

Everything here reuses :mod:`hydrowatch.cycles`: :class:`~hydrowatch.cycles.ComponentClassifier` (features →
LDA), :class:`~hydrowatch.cycles.openset.OpenSetComponent` (``unknown``) and
:func:`~hydrowatch.cycles.ordered_split` (the honest split). Per component the feature set (``statistics``,
``transients`` or ``entropy``, the study's method) is the one with the better accuracy on the honest split
*inside the cycles it is fitted on* (first 70 % of each class fit, last 30 % validate; ties go to the earlier in
that order); a feature set the rig cannot make (no load change on the reference channel, no healthy cycle) is
skipped. The evaluation fits on the first 70 % of each class's cycles in recording
order and tests on the last 30 % (docs/rigs.md: random splits flatter every method).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrowatch.cycles import FEATURES, ComponentClassifier, ordered_split
from hydrowatch.cycles.openset import UNKNOWN, OpenSetComponent
from hydrowatch.errors import ParameterError
from hydrowatch.health.metrics import confusion_matrix, per_class_recall
from hydrowatch.rig import Label, RigDescription
from hydrowatch.rig.description import label_text

TRANSIENTS: dict[str, Any] = {"channels": None, "normalised": True, "discriminants": 2, "trees": 100,
                              "tree_weight": 1.25}
"""How the ``transients`` features are made and decided (:class:`~hydrowatch.cycles.ComponentClassifier`): every
channel (the slow ones' values around the changes carry the condition's drift inside the cycle), each clear step
also as shares of the cycle's own step (cancel the step height and much of the oil temperature), decided in the 2
leading discriminant directions (reduced-rank LDA), with the vote of 100 extremely randomised trees on the plain
statistics weighted 1.25 where the training cycles cover the cycle's operating condition (the other components'
levels) for every state (:class:`~hydrowatch.cycles.trees.CoveredVote`). Chosen on the training cycles of the UCI
accumulator only (docs/rigs.md, issue 17; until 2026-11-26: the channels recorded at >= 10 Hz, plain LDA; the vote
since 2026-11-26, branch rig17b); for a component of 3 conditions or fewer 2 directions are all of them."""
PHASES = 6
"""Phase means per channel of the ``statistics`` features: 6 (the UCI cycle's), or the largest number below that
divides a rig's samples per cycle."""


state_name = label_text
"""A label value as a state name: ``100`` for 100.0, ``2.5``, or the text of a named value."""


def component_states(label: Label) -> list[str]:
    """The component's states, the healthy one first, then the others as declared."""
    healthy = state_name(label.healthy)
    return [healthy, *[state_name(v) for v in label.values if state_name(v) != healthy]]


@dataclass(frozen=True)
class CycleData:
    """What a component's classifier is fitted on.

    Attributes
    ----------
    values : ndarray, shape (n_cycles, n_channels, n_samples)
        The cycles on the grid, recording order.
    states : ndarray of str, shape (n_cycles,)
        The component's state per cycle.
    nuisance : ndarray, shape (n_cycles, n_others)
        The other components' label values (what the ``transients`` projection removes).
    healthy : str
        The component's healthy state (what the ``entropy`` features' reference models are fitted on).
    """

    values: np.ndarray
    states: np.ndarray
    nuisance: np.ndarray
    healthy: str

    def part(self, index: np.ndarray) -> CycleData:
        """The cycles ``index`` (recording order kept)."""
        return CycleData(self.values[index], self.states[index], self.nuisance[index], self.healthy)


def classifier(features: str, rig: RigDescription, healthy: str) -> ComponentClassifier:
    """An unfitted classifier of ``features`` for ``rig``'s channels (``statistics``: :data:`PHASES` phase means;
    ``transients``: the load changes found on the first channel, :data:`TRANSIENTS`; ``entropy``: a reference model
    per channel of role ``sensor``, on the cycles of the component's ``healthy`` state)."""
    names = rig.channels.names
    sensors = [names.index(c.name) for c in rig.channels if c.role == "sensor"]
    phases = next(k for k in range(PHASES, 0, -1) if rig.window.samples % k == 0)
    options = {"transients": TRANSIENTS, "entropy": {"channels": sensors or None}}.get(features, {})
    return ComponentClassifier(features=features, grid_hz=rig.window.grid_hz, phases=phases, healthy=healthy,
                               **options)


def validation_accuracy(features: str, rig: RigDescription, data: CycleData) -> float:
    """Accuracy of ``features`` on the honest split inside ``data``; NaN when the rig cannot make them."""
    fit_part, check = ordered_split(data.states)
    train = data.part(fit_part)
    try:
        model = classifier(features, rig, data.healthy).fit(train.values, train.states, train.nuisance)
    except ParameterError:
        return float("nan")
    return float(np.mean(model.predict(data.values[check]) == data.states[check]))


def fit_component(rig: RigDescription, data: CycleData) -> tuple[OpenSetComponent, str, dict[str, float]]:
    """The open-set classifier of one component fitted on ``data``, its feature set and each set's validation
    accuracy."""
    scores = {f: validation_accuracy(f, rig, data) for f in FEATURES}
    usable = {f: s for f, s in scores.items() if np.isfinite(s)}
    if not usable:
        raise ParameterError(f"no feature set of {list(FEATURES)} could be fitted on these cycles.")
    best = max(usable.values())
    features = next(f for f, s in usable.items() if s >= best - 1e-3)
    model = OpenSetComponent(classifier(features, rig, data.healthy)).fit(data.values, data.states, data.nuisance)
    return model, features, scores


def component_data(rig: RigDescription, values: np.ndarray, labels: dict[str, np.ndarray], component: str) -> CycleData:
    """A component's :class:`CycleData` from a rig's cycles and labels."""
    others = [c for c in rig.components if c != component]
    # each other component's level as a category number (names or numbers: the projection only compares levels)
    nuisance = (np.column_stack([np.unique(labels[c], return_inverse=True)[1].astype(float) for c in others])
                if others else np.zeros((len(values), 1)))
    return CycleData(values, np.array([state_name(v) for v in labels[component]]), nuisance,
                     state_name(rig.label(component).healthy))


def evaluate_component(rig: RigDescription, data: CycleData, states: list[str]) -> dict[str, Any]:
    """The honest split's figures of one component: ``accuracy`` (``unknown`` counted wrong), ``macro_f1``,
    ``unknown`` (share of test cycles read unknown), ``per_class_recall``, ``confusion_matrix`` (rows true
    ``states``, columns ``states`` then ``unknown``), ``features``, ``validation``, ``train_cycles``,
    ``test_cycles``."""
    from sklearn.metrics import f1_score

    train, test = ordered_split(data.states)
    model, features, validation = fit_component(rig, data.part(train))
    truth, predicted = data.states[test], model.predict(data.values[test]).astype(str)
    present = [s for s in states if s in set(truth)]
    return {
        "accuracy": float(np.mean(predicted == truth)),
        "macro_f1": float(f1_score(truth, predicted, labels=present, average="macro", zero_division=0)),
        "unknown": float(np.mean(predicted == UNKNOWN)),
        "per_class_recall": per_class_recall(truth, predicted, states),
        "confusion_matrix": confusion_matrix(truth, predicted, [*states, UNKNOWN])[: len(states)].tolist(),
        "features": features, "validation": validation,
        "train_cycles": int(train.size), "test_cycles": int(test.size),
    }
