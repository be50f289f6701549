"""What the online scorer does for each health method, machine by machine and window by window.

:class:`~hydrowatch.training.online.OnlineScorer` cuts chunks into clean segments and handles
breaks; an engine turns the segments into window values and closed windows into verdicts:

* :class:`EntropyEngine` (the study's method): one-step prediction errors of the reference models
  (Eq. 5.1), batched over machines, into a :class:`~hydrowatch.health.streaming.MachineWindow`
  whose closed windows carry relative entropies (Eq. 5.3), judged by the classifier and open-set rule;
* :class:`ParityEngine`: what the parity method reads (condition model, columns, window and hop);
  :class:`~hydrowatch.training.parity_online.ParityStreams` keeps the raw windows of the whole
  fleet in one array and judges them with the :class:`~hydrowatch.condition.ConditionModel`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hydrowatch.condition.estimates import CHANNELS as WINDOW_CHANNELS
from hydrowatch.condition.estimates import TEMPERATURE
from hydrowatch.errors import DataError
from hydrowatch.health.streaming import MachineWindow, WindowResult
from hydrowatch.health.verdict import judge
from hydrowatch.recording import INPUT
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.reference import StreamState
from hydrowatch.verdict import Verdict

UNKNOWN_TEMPERATURE = float("nan")
"""Oil temperature of a chunk without one when a parity bundle uses it: unknown (the window is judged with the
leak boxes widened by the oil's range, :mod:`hydrowatch.condition.oil`)."""


class EntropyEngine:
    """The study's method online (module docstring); ``keep`` closed windows per machine."""

    def __init__(self, bundle: ModelBundle, *, keep: int = 4) -> None:
        if bundle.health is None:
            raise DataError("an entropy bundle must hold a health model. Got none; retrain with `hydrowatch train`.")
        self.health = bundle.health
        self.references = list(bundle.references.values())
        self.keep = keep
        self.columns = [INPUT, *bundle.sensors]
        self.defaults: dict[str, float] = {}
        self.hop = bundle.hop

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


class ParityEngine:
    """What the parity method reads online (module docstring); ``ParityStreams`` does the work."""

    def __init__(self, bundle: ModelBundle) -> None:
        if bundle.condition is None:
            raise DataError("a parity bundle must hold a condition model. Got none; retrain with `hydrowatch train`.")
        self.model = bundle.condition
        self.columns = list(WINDOW_CHANNELS)
        self.defaults = {}
        if bundle.manifest.get("temperature"):
            self.columns.append(TEMPERATURE)
            self.defaults[TEMPERATURE] = UNKNOWN_TEMPERATURE
        self.window, self.hop = bundle.window, bundle.hop
        self._shape = (len(bundle.kl_rows), len(bundle.states))


Engine = EntropyEngine | ParityEngine


def engine_for(bundle: ModelBundle, *, keep: int = 4) -> Engine:
    """The engine of the bundle's method."""
    return ParityEngine(bundle) if bundle.method == "parity" else EntropyEngine(bundle, keep=keep)
