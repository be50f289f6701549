"""The noise-free simulations of one analysis of one recording, kept by model (issue 12, item 5).

A gap analysis asks for the same model more than once: a fit's start is often the best point of the magnitude
scan just made, the identifiability's central differences step from the calibration's end point as its last
Jacobian did, a screen simulates on the first seconds the model that the last round's settle simulated on the
whole record (dev pair 2035: 89 of 5,414 whole-record simulations asked again). A simulation depends only on
the plant parameters and effects that reach the kernel (its parameter and effect rows), the command and the
start time; the recording and its heads share the command and start time, and the first n samples of a longer
simulation are the simulation of those n samples (the kernel is causal and chunked calls equal one long call bit
for bit). So a model kept here is never simulated again, by this analysis, for as many samples or fewer: the same
numbers, without the simulation.

The keeper belongs to one :class:`~hydrowatch.gap.align.AlignedRecording` (and its heads), made by one analysis,
holds at most LIMIT_BYTES of predictions of each length (the least recently used go first: a screen's heads do not push
out the whole-record simulations a continuation needs) and is emptied when that analysis ends. The analysis's steps that
run side by side (side_by_side.py) share it: every method holds its lock. Which models it still holds then depends on
the threads' timing, never a simulation's numbers.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from hydrowatch.plant.effects import Effects, effect_row
from hydrowatch.plant.parameters import PlantParameters

LIMIT_BYTES = 48 * 2**20
"""Most bytes of predictions kept per prediction length (about 80 simulations of a 120 s record, or 700 of its
14 s screening head; an analysis asks for those two lengths, so at most twice this)."""


Key = tuple[bytes, bytes]
"""A model as the kernel sees it: its parameter row and effect row, bit for bit."""


class Simulations:
    """Predictions (shape (3, n): flow, speed, torque) by model, the longest made of each; see the module docstring.

    Attributes
    ----------
    simulated : int
        Models simulated (by :func:`~hydrowatch.gap.align.simulate_sensors`) and offered to :meth:`keep` since the
        keeper was made.
    reused : int
        Models taken from it instead.
    """

    def __init__(self) -> None:
        self._kept: dict[Key, np.ndarray] = {}
        self._order: dict[int, OrderedDict[Key, None]] = {}  # per length: the keys, least recently used first
        self._bytes: dict[int, int] = {}  # per length: bytes kept
        self._command: tuple[int, int, float] | None = None  # the command's buffer address, stride and t0
        self.simulated = 0
        self.reused = 0
        self._lock = threading.Lock()

    def serves(self, voltage: np.ndarray, t0: float) -> bool:
        """Whether these kept simulations are of this command (the recording's, or a head of it: the same buffer from
        its first sample, the same start time t0 [s]); the first command asked binds them. A recording object copied
        with another command (``dataclasses.replace``) is simulated afresh, never served another's simulations."""
        command = (voltage.__array_interface__["data"][0], voltage.strides[0], float(t0))
        with self._lock:
            if self._command is None:
                self._command = command
            return self._command == command

    @staticmethod
    def key(parameters: PlantParameters, effects: Effects | None) -> Key:
        """The model's key: its kernel rows' bytes (two models with the same key simulate to the same numbers)."""
        return parameters.as_array().tobytes(), effect_row(effects).tobytes()

    def take(self, key: Key, n: int) -> np.ndarray | None:
        """A copy of the first ``n`` samples of the model's kept prediction, or None when none as long is kept."""
        with self._lock:
            kept = self._kept.get(key)
            if kept is None or kept.shape[1] < n:
                return None
            self._order[kept.shape[1]].move_to_end(key)
            self.reused += 1
            return kept[:, :n].copy()

    def keep(self, key: Key, prediction: np.ndarray) -> None:
        """Count a simulated model and keep its ``prediction`` (shape (3, n)) unless one as long of it is kept; drop
        the least recently used of that length beyond LIMIT_BYTES."""
        with self._lock:
            self.simulated += 1
            old = self._kept.get(key)
            if old is not None:
                if old.shape[1] >= prediction.shape[1]:
                    return
                del self._order[old.shape[1]][key]
                self._bytes[old.shape[1]] -= old.nbytes
            n = prediction.shape[1]
            self._kept[key] = prediction.copy()
            order = self._order.setdefault(n, OrderedDict())
            order[key] = None
            self._bytes[n] = self._bytes.get(n, 0) + prediction.nbytes
            while len(order) > 1 and self._bytes[n] > LIMIT_BYTES:
                dropped, _ = order.popitem(last=False)
                self._bytes[n] -= self._kept.pop(dropped).nbytes

    def __len__(self) -> int:
        """How many models are kept."""
        with self._lock:
            return len(self._kept)

    def clear(self) -> None:
        """Forget every kept prediction (the counts stay)."""
        with self._lock:
            self._kept.clear()
            self._order.clear()
            self._bytes.clear()
