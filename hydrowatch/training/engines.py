"""What the online scorer does for each health method, machine by machine and window by window.

:class:`~hydrowatch.training.online.OnlineScorer` cuts chunks into clean segments and handles
breaks; an engine turns the segments into window values and closed windows into verdicts:

* :class:`EntropyEngine` (the study's method): one-step prediction errors of the reference models
  (Eq. 5.1), batched over machines, into a :class:`~hydrowatch.health.streaming.MachineWindow`
  whose closed windows carry relative entropies (Eq. 5.3), judged by the classifier and open-set rule;
* :class:`ParityEngine`: the raw samples into a :class:`RawWindow`; closed windows are judged by the
  :class:`~hydrowatch.condition.ConditionModel` in one batch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrowatch.condition import ConditionModel
from hydrowatch.errors import DataError
from hydrowatch.health.streaming import MachineWindow, WindowResult
from hydrowatch.health.verdict import Verdict, judge
from hydrowatch.recording import INPUT
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.reference import StreamState

REFERENCE_TEMPERATURE_C = 40.0
"""Oil temperature assumed when a parity bundle uses it and a chunk has none, °C (the relations' reference)."""


def condition_verdicts(model: ConditionModel, raw: np.ndarray) -> tuple[list[Verdict], np.ndarray]:
    """Verdicts and relation scores of raw windows, shape (m, window, 4 or 5) → m verdicts, (m, n_features).

    One pass of the parity estimates gives both the verdicts and the band scores (the ``kl`` field).
    """
    return model.judge_with_scores(raw)


@dataclass(frozen=True)
class RawResult:
    """One closed raw window: samples ``[start, stop)`` from the first fed sample, shape (window, width)."""

    index: int
    start: int
    stop: int
    samples: np.ndarray


class RawWindow:
    """The last ``window`` raw samples of one machine; closes a window every ``hop`` samples (river style).

    Parameters
    ----------
    window, hop : int
        Samples per window and between window starts.
    width : int
        Channels per sample.
    """

    def __init__(self, window: int, hop: int, width: int) -> None:
        self.window, self.hop, self.width = window, hop, width
        self._buffer = np.empty((window, width))
        self._fill = 0
        self._skip = 0
        self._closed: list[RawResult] = []
        self.n_windows = 0
        """Windows closed so far."""

    def update(self, x: np.ndarray) -> None:
        """Feed the next samples, shape (n, width); returns nothing."""
        i, n = 0, x.shape[0]
        while i < n:
            if self._skip:
                step = min(self._skip, n - i)
                self._skip -= step
                i += step
                continue
            take = min(n - i, self.window - self._fill)
            self._buffer[self._fill : self._fill + take] = x[i : i + take]
            self._fill += take
            i += take
            if self._fill == self.window:
                start = self.n_windows * self.hop
                self._closed.append(RawResult(self.n_windows, start, start + self.window, self._buffer))
                self.n_windows += 1
                fresh = np.empty_like(self._buffer)
                keep = max(0, self.window - self.hop)
                fresh[:keep] = self._buffer[self.window - keep :]
                self._buffer, self._fill, self._skip = fresh, keep, max(0, self.hop - self.window)

    def drain(self) -> list[RawResult]:
        """The windows closed since the last call, oldest first (they are handed over, not kept)."""
        out, self._closed = self._closed, []
        return out


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
    """The parity method online (module docstring): raw windows judged by the condition model."""

    def __init__(self, bundle: ModelBundle) -> None:
        if bundle.condition is None:
            raise DataError("a parity bundle must hold a condition model. Got none; retrain with `hydrowatch train`.")
        self.model = bundle.condition
        self.columns = [INPUT, "flow", "speed", "torque"]
        self.defaults = {}
        if bundle.manifest.get("temperature"):
            self.columns.append("temperature")
            self.defaults["temperature"] = REFERENCE_TEMPERATURE_C
        self.window, self.hop = bundle.window, bundle.hop
        self._shape = (len(bundle.kl_rows), len(bundle.states))

    def new_states(self) -> list[StreamState]:
        """No reference models: no stream states."""
        return []

    def new_window(self) -> RawWindow:
        """A fresh raw window."""
        return RawWindow(self.window, self.hop, len(self.columns))

    def values(self, x: np.ndarray, states: Sequence[list[StreamState]]) -> np.ndarray:
        """The raw samples themselves, shape (M, n, n_columns)."""
        return x

    def collect(self, window: RawWindow, reported: int) -> list[RawResult]:
        """Windows closed since the last collect."""
        return window.drain()

    def judge(self, results: Sequence[Any]) -> list[tuple[Verdict, np.ndarray]]:
        """Verdicts and relation scores (n_relations, n_states) of closed raw windows, in one batch."""
        verdicts, scores = condition_verdicts(self.model, np.stack([r.samples for r in results]))
        return [(v, s.reshape(self._shape)) for v, s in zip(verdicts, scores)]


Engine = EntropyEngine | ParityEngine


def engine_for(bundle: ModelBundle, *, keep: int = 4) -> Engine:
    """The engine of the bundle's method."""
    return ParityEngine(bundle) if bundle.method == "parity" else EntropyEngine(bundle, keep=keep)
