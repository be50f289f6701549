"""The study's method online: one-step prediction errors per machine, windows of them judged in batches.

The fleet driver (:class:`~hydrowatch.training.window_fleet.WindowFleet`) cuts chunks into clean
segments and handles breaks; :meth:`EntropyEngine.values` turns each machine's segments into the
reference models' one-step prediction errors (Eq. 5.1), batched over machines, with each machine's
delay lines or filter states (:class:`~hydrowatch.methods.entropy.reference.StreamState`, NaN while
warming up: the driver starts the windows at the first sample where every sensor has an error);
:meth:`EntropyEngine.judge` gives each closed window of errors its relative entropies (Eq. 5.3,
:func:`~hydrowatch.health.streaming.closed_window`, as the batch path) and the classifier's and
open-set rule's verdict. After :meth:`EntropyEngine.expect` a window holds each sensor's prediction errors and,
beside them, the measured samples, so that :meth:`EntropyEngine.expected` gives what the reference models expected
(measured − error, the one-step predictions) for the machine page's chart.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from hydrowatch.expected import ExpectedWindow, expected_windows
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
        Values per sample: one prediction error per sensor (then, after :meth:`expect`, each sensor's measured
        sample).
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
        """Prediction errors of M machines' segments x (M, n, 1 + n_sensors) → (M, n, width): the errors, then (after
        :meth:`expect`) the sensors as measured; updates ``states``."""
        errors = []
        for j, ref in enumerate(self.references):
            e, new = ref.step(x[:, :, 0], x[:, :, 1 + j], [s[j] for s in states])
            for s, state in zip(states, new):
                s[j] = state
            errors.append(e)
        found = np.stack(errors, axis=2)
        if self.width == len(self.references):
            return found
        return np.concatenate([found, x[:, :, 1:1 + len(self.references)]], axis=2)

    def judge(self, raw: np.ndarray, machines: Sequence[str]) -> list[tuple[Verdict, np.ndarray]]:
        """Verdicts and relative entropies (n_sensors, n_states) of closed windows of errors (m, window, width; the
        measured samples after them, if any, are not read)."""
        features = self.health.features_
        n = len(self.references)
        sensors = list(range(n))
        closed = [closed_window(features, ordered, sensors) for ordered in raw[:, :, :n].transpose(0, 2, 1).copy()]
        verdicts = judge(np.stack([e.ravel() for e, _ in closed]), self.health.classifier_, self.health.open_set_,
                         [why for _, why in closed])
        return [(v, e) for v, (e, _) in zip(verdicts, closed)]

    def expect(self) -> None:
        """Keep each sensor's measured samples beside its prediction errors in the windows (width 2·n_sensors)."""
        self.width = 2 * len(self.references)

    def expected(self, raw: np.ndarray, machines: Sequence[str]) -> list[ExpectedWindow]:
        """What the reference models expected each sensor of the closed windows ``raw`` (m, window, 2·n_sensors) to
        read: their one-step predictions, measured − prediction error (Eq. 5.1), beside the measured samples."""
        n = len(self.references)
        measured = {r.sensor: raw[:, :, n + j] for j, r in enumerate(self.references)}
        expected = {r.sensor: raw[:, :, n + j] - raw[:, :, j] for j, r in enumerate(self.references)}
        return expected_windows(measured, expected, {r.sensor: f"{r.kind} reference model" for r in self.references})
