"""The study's method online: one-step prediction errors per machine, windows of them judged in batches.

The fleet driver (:class:`~hydrowatch.training.window_fleet.WindowFleet`) cuts chunks into clean
segments and handles breaks; :meth:`EntropyEngine.values` turns each machine's segments into the
reference models' one-step prediction errors (Eq. 5.1), batched over machines, with each machine's
delay lines or filter states (:class:`~hydrowatch.methods.entropy.reference.StreamState`, NaN while
warming up: the driver starts the windows at the first sample where every sensor has an error);
:meth:`EntropyEngine.judge` gives each closed window of errors its relative entropies (Eq. 5.3,
:func:`~hydrowatch.health.streaming.closed_window`, as the batch path) and the classifier's and
open-set rule's verdict.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from hydrowatch.health.model import HealthModel
from hydrowatch.health.streaming import closed_window
from hydrowatch.health.verdict import judge
from hydrowatch.methods.entropy.reference import SensorReference, StreamState
from hydrowatch.recording import INPUT
from hydrowatch.verdict import Verdict


class EntropyEngine:
    """The study's method online (module docstring): a :class:`~hydrowatch.methods.base.StreamEngine`.

    Attributes
    ----------
    columns : list of str
        The command, then the sensors (chunk columns read).
    width : int
        Values per sample: one prediction error per sensor.
    window, hop : int
        Samples per window and between window starts (after the warm-up).
    staggers : bool
        False: windows start at the first sample after the warm-up (never staggered).
    """

    staggers: ClassVar[bool] = False

    def __init__(self, references: Sequence[SensorReference], health: HealthModel, sensors: Sequence[str]) -> None:
        self.health = health
        self.references = list(references)
        self.columns = [INPUT, *sensors]
        self.defaults: dict[str, float] = {}
        self.width = len(self.references)
        self.window, self.hop = int(health.features_.window), int(health.features_.hop)

    def new_states(self) -> list[StreamState]:
        """Fresh stream states of the reference models (warm-up again)."""
        return [r.initial_state() for r in self.references]

    def values(self, x: np.ndarray, states: Sequence[list[StreamState]]) -> np.ndarray:
        """Prediction errors of M machines' segments x (M, n, 1 + n_sensors) → (M, n, n_sensors); updates ``states``."""
        errors = []
        for j, ref in enumerate(self.references):
            e, new = ref.step(x[:, :, 0], x[:, :, 1 + j], [s[j] for s in states])
            for s, state in zip(states, new):
                s[j] = state
            errors.append(e)
        return np.stack(errors, axis=2)

    def judge(self, raw: np.ndarray, machines: Sequence[str]) -> list[tuple[Verdict, np.ndarray]]:
        """Verdicts and relative entropies (n_sensors, n_states) of closed windows of errors (m, window, n_sensors)."""
        features = self.health.features_
        sensors = list(range(self.width))
        closed = [closed_window(features, ordered, sensors) for ordered in raw.transpose(0, 2, 1).copy()]
        verdicts = judge(np.stack([e.ravel() for e, _ in closed]), self.health.classifier_, self.health.open_set_,
                         [why for _, why in closed])
        return [(v, e) for v, (e, _) in zip(verdicts, closed)]
