"""Streaming windows of prediction errors, one machine at a time (river style).

``update`` takes the next prediction errors and returns nothing; reading (``last``, ``since``,
``n_windows``) changes nothing and works before any data. The state is a ring buffer of one
window per sensor (8 kB for 1,000 samples) plus the last ``keep`` window results. At each window
close the buffer is laid out oldest-first and handed to the same
:meth:`RelativeEntropyFeatures.sensor_entropies` as the batch path, so streaming and batch
results are identical to the last bit (tested), whatever the chunk sizes.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.health.features import RelativeEntropyFeatures
from hydrowatch.health.windows import invalid_reasons


@dataclass(frozen=True)
class WindowResult:
    """One closed window.

    Attributes
    ----------
    index : int
        Window number, 0 for the first window of the stream.
    start, stop : int
        Sample range ``[start, stop)`` counted from the first sample of the stream.
    entropies : ndarray, shape (n_states,) or (n_sensors, n_states)
        ``D(base || window)`` per state (and sensor), nats; NaN when invalid.
    reason : str or None
        Why the window cannot be judged, or None.
    """

    index: int
    start: int
    stop: int
    entropies: np.ndarray
    reason: str | None

    @property
    def features(self) -> np.ndarray:
        """The flat feature vector (sensor-major), as the classifier takes it."""
        return self.entropies.ravel()


def closed_window(features: RelativeEntropyFeatures, ordered: np.ndarray,
                  sensors: list[int]) -> tuple[np.ndarray, str | None]:
    """Relative entropies (n_sensors, n_states), nats, and the invalid reason (or None) of one closed window.

    ``ordered`` (n_sensors, window), C-contiguous, oldest sample first: prediction errors of the
    ``sensors`` (indices into ``features.sensors_``). The reason names the first invalid sensor.
    """
    rows = [ordered[j][np.newaxis, :] for j in range(ordered.shape[0])]
    entropies = np.stack([features.sensor_entropies(r, i)[0] for r, i in zip(rows, sensors)])
    reasons = [invalid_reasons(r)[0] if np.isnan(e).any() else None for r, e in zip(rows, entropies)]
    names = [features.sensors_[i] for i in sensors]
    return entropies, next((f"{n}: {r}" for n, r in zip(names, reasons) if r), None)


class _Ring:
    """Ring buffer of the last ``window`` samples of ``width`` columns that closes a window every ``hop``."""

    def __init__(self, window: int, hop: int, width: int) -> None:
        self.window, self.hop = window, hop
        self.buffer = np.zeros((window, width))
        self.n_samples = 0
        self.n_windows = 0

    def feed(self, x: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Store ``x`` (n, width); return every window it closed: (index, samples (width, window) oldest first)."""
        closed = []
        i = 0
        while i < x.shape[0]:
            pos = self.n_samples % self.window
            next_close = self.n_windows * self.hop + self.window
            take = min(x.shape[0] - i, self.window - pos, next_close - self.n_samples)
            self.buffer[pos : pos + take] = x[i : i + take]
            self.n_samples += take
            i += take
            if self.n_samples == next_close:
                pos = self.n_samples % self.window
                closed.append((self.n_windows, np.concatenate((self.buffer[pos:], self.buffer[:pos])).T.copy()))
                self.n_windows += 1
        return closed


class _Windows:
    """Shared reading side: the last ``keep`` results."""

    def __init__(self, features: RelativeEntropyFeatures, sensors: list[int], keep: int) -> None:
        if keep < 1:
            raise ParameterError(f"keep must be >= 1 window. Got {keep}.")
        self.features = features
        self._sensors = sensors
        self._ring = _Ring(int(features.window), int(features.hop), len(sensors))
        self._results: deque[WindowResult] = deque(maxlen=keep)

    @property
    def n_samples(self) -> int:
        """Samples seen so far."""
        return self._ring.n_samples

    @property
    def n_windows(self) -> int:
        """Windows closed so far."""
        return self._ring.n_windows

    def _feed(self, x: np.ndarray) -> None:
        for index, ordered in self._ring.feed(x):
            self._close(index, ordered)

    def _close(self, index: int, ordered: np.ndarray) -> None:
        start = index * self._ring.hop
        entropies, reason = closed_window(self.features, ordered, self._sensors)
        self._results.append(WindowResult(index, start, start + self._ring.window, self._shape(entropies), reason))

    def _shape(self, entropies: np.ndarray) -> np.ndarray:
        return entropies

    def last(self) -> WindowResult | None:
        """The latest closed window, or None before the first."""
        return self._results[-1] if self._results else None

    def since(self, index: int) -> list[WindowResult]:
        """Kept windows whose index is >= ``index``, oldest first."""
        return [r for r in self._results if r.index >= index]


class EntropyWindow(_Windows):
    """Streaming relative entropies of one machine and one sensor.

    Parameters
    ----------
    features : RelativeEntropyFeatures
        Fitted base distributions; gives ``window`` and ``hop``.
    sensor : str or int
        The sensor whose prediction errors are fed.
    keep : int, default 8
        Closed windows kept for reading.

    Results carry entropies of shape (n_states,) and a reason prefixed with the sensor name.
    """

    def __init__(self, features: RelativeEntropyFeatures, sensor: str | int, *, keep: int = 8) -> None:
        super().__init__(features, [features.sensor_index(sensor)], keep)

    def _shape(self, entropies: np.ndarray) -> np.ndarray:
        return entropies[0]

    def update(self, errors: np.ndarray) -> None:
        """Feed the next prediction errors of the sensor, shape (n,) (sensor unit); returns nothing."""
        x = np.asarray(errors, dtype=np.float64)
        if x.ndim != 1:
            raise DataError(f"prediction errors of one sensor must be 1-D. Got shape {x.shape}.")
        self._feed(x[:, np.newaxis])


class MachineWindow(_Windows):
    """Streaming feature vectors of one machine, all sensors in one ring buffer.

    Parameters
    ----------
    features : RelativeEntropyFeatures
        Fitted base distributions.
    keep : int, default 8
        Closed windows kept for reading.

    Results carry entropies of shape (n_sensors, n_states); ``features`` flattens them.
    """

    def __init__(self, features: RelativeEntropyFeatures, *, keep: int = 8) -> None:
        super().__init__(features, list(range(len(features.sensors_))), keep)
        self.sensors = features.sensors_

    def update(self, errors: np.ndarray) -> None:
        """Feed prediction errors, shape (n, n_sensors) (columns in ``features.sensors_`` order)."""
        e = np.asarray(errors, dtype=np.float64)
        if e.ndim != 2 or e.shape[1] != len(self.sensors):
            raise DataError(f"prediction errors must have shape (n, {len(self.sensors)}). Got {e.shape}.")
        self._feed(e)
