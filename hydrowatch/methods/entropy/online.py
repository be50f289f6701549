"""The study's method online: one-step prediction errors per machine, windows of them judged in batches.

The fleet driver (:class:`~hydrowatch.training.online.OnlineScorer`) cuts chunks into clean segments
and handles breaks; :class:`EntropyEngine` turns the segments into the reference models' one-step
prediction errors (Eq. 5.1), batched over machines, fed to a
:class:`~hydrowatch.health.streaming.MachineWindow` whose closed windows carry relative entropies
(Eq. 5.3), judged by the classifier and the open-set rule.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hydrowatch.health.model import HealthModel
from hydrowatch.health.streaming import MachineWindow, WindowResult
from hydrowatch.health.verdict import judge
from hydrowatch.methods.entropy.reference import SensorReference, StreamState
from hydrowatch.recording import INPUT
from hydrowatch.verdict import Verdict


class EntropyEngine:
    """The study's method online (module docstring); ``keep`` closed windows per machine."""

    def __init__(self, references: Sequence[SensorReference], health: HealthModel, sensors: Sequence[str], *,
                 keep: int = 4) -> None:
        self.health = health
        self.references = list(references)
        self.keep = keep
        self.columns = [INPUT, *sensors]
        self.defaults: dict[str, float] = {}
        self.hop = int(health.features_.hop)

    def new_states(self) -> list[StreamState]:
        """Fresh stream states of the reference models (warm-up again)."""
        return [r.initial_state() for r in self.references]

    def new_window(self) -> MachineWindow:
        """A fresh window of prediction errors."""
        return MachineWindow(self.health.features_, keep=self.keep)

    def values(self, x: np.ndarray, states: Sequence[list[StreamState]]) -> np.ndarray:
        """Prediction errors of M machines' segments x (M, n, 1 + n_sensors) → (M, n, n_sensors); updates ``states``."""
        errors = []
        for j, ref in enumerate(self.references):
            e, new = ref.step(x[:, :, 0], x[:, :, 1 + j], [s[j] for s in states])
            for s, state in zip(states, new):
                s[j] = state
            errors.append(e)
        return np.stack(errors, axis=2)

    def collect(self, window: MachineWindow, reported: int) -> list[WindowResult]:
        """Windows closed since ``reported``."""
        return window.since(reported)

    def judge(self, results: Sequence[Any]) -> list[tuple[Verdict, np.ndarray]]:
        """Verdicts and relative entropies (n_sensors, n_states) of closed windows, batched."""
        features = np.stack([r.features for r in results])
        verdicts = judge(features, self.health.classifier_, self.health.open_set_, [r.reason for r in results])
        return [(v, r.entropies) for v, r in zip(verdicts, results)]
