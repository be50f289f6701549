"""Encode one step of a whole fleet's sensor chunks in one pass (the plant's hot path).

A ``sensor_chunk`` message (:func:`hydrowatch.io.codec.encode_batch`) is an Arrow IPC stream:
schema message, batch metadata, body, end marker. For chunks of the same length whose float
columns hold no nulls, only the body changes between steps, and in the body the float64 columns
come first, each exactly ``8·n`` bytes (a multiple of Arrow's 8-byte alignment, with an empty
validity buffer), then the per-machine label column, which never changes. So each machine's message is a fixed *head*,
the machine's float values in column order, and a fixed *tail*.

:class:`FleetEncoder` takes head and tail from :func:`encode_batch` on the first step and checks
on the second that head + new values + tail gives that step's messages byte for byte, for every
machine; only then does it build later messages the fast way (one ``numpy.stack`` per step, one
``bytes.join`` per machine: ~0.8 µs instead of ~5 µs per message). Otherwise it stays with
``encode_batch``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pyarrow as pa

from hydrowatch.io.codec import LABEL_FIELD, encode_batch, sensor_chunk_from_arrays
from hydrowatch.log import get_logger
from hydrowatch.schemas import SENSOR_CHUNK, wire_schema

log = get_logger("services.plant")


class FleetEncoder:
    """Encodes one ``sensor_chunk`` message per machine from fleet-wide arrays.

    Parameters
    ----------
    channels : sequence of str
        Float channels after ``t``, in ``sensor_chunk`` schema order (e.g. voltage … temperature).
    labels : sequence of str or None
        Each machine's health label (its ``state`` column), or None to leave the column out.
    """

    def __init__(self, channels: Sequence[str], labels: Sequence[str] | None) -> None:
        names = wire_schema(SENSOR_CHUNK).names
        order = [names.index(c) for c in channels]
        if order != sorted(order) or names.index("t") > min(order, default=1):
            raise ValueError(f"channels must follow t in sensor_chunk order {names}. Got {list(channels)}.")
        self.channels = tuple(channels)
        self.labels = None if labels is None else list(labels)
        self.fast = False
        self._heads: list[bytes] = []
        self._tails: list[bytes] = []
        self._n = 0

    def relabel(self, labels: Sequence[str]) -> None:
        """New health labels (a machine wearing along a path changes level); the next step is encoded the slow way
        and learnt again. Nothing happens when the labels are the same."""
        if self.labels is not None and list(labels) != self.labels:
            self.labels, self._heads, self.fast = list(labels), [], False

    def encode(self, t: np.ndarray, values: dict[str, np.ndarray]) -> list[bytes]:
        """One payload per machine.

        Parameters
        ----------
        t : ndarray, shape (M, n)
            Sample times, s.
        values : dict of str to ndarray, shape (M, n)
            Every channel of :attr:`channels`, SI units of the schema.

        Returns
        -------
        list of bytes
            M payloads, each exactly what ``encode_batch`` gives for that machine's chunk.
        """
        block = np.stack([t, *(values[c] for c in self.channels)], axis=1).astype(np.float64, copy=False)
        m, _, n = block.shape
        if self._heads and n == self._n and m == len(self._heads):
            flat = np.ascontiguousarray(block).reshape(-1).view(np.uint8).data
            size = flat.nbytes // m
            fast = [b"".join((head, flat[j * size:(j + 1) * size], tail))
                    for j, (head, tail) in enumerate(zip(self._heads, self._tails))]
            if self.fast:
                return fast
            # the step after learning: trusted only if it equals encode_batch for every machine
            payloads = self._encode_slow(t, values)
            self.fast = fast == payloads
            if not self.fast:
                self._heads = []
                log.info("fleet encoder: head + values + tail differs from encode_batch; encoding every message")
            return payloads
        payloads = self._encode_slow(t, values)
        self._learn(block, payloads)
        return payloads

    def _encode_slow(self, t: np.ndarray, values: dict[str, np.ndarray]) -> list[bytes]:
        m, n = t.shape
        fleet = sensor_chunk_from_arrays(t.reshape(-1), {c: values[c].reshape(-1) for c in self.channels})
        if self.labels is not None:
            labels = pa.array([label for label in self.labels for _ in range(n)], type=pa.string())
            fleet = fleet.append_column(wire_schema(SENSOR_CHUNK).field(LABEL_FIELD), labels)
        return [encode_batch(fleet.slice(j * n, n)) for j in range(m)]

    def _learn(self, block: np.ndarray, payloads: list[bytes]) -> None:
        """Split each payload into head, values, tail (checked on the next step, see :meth:`encode`)."""
        heads, tails = [], []
        for j, payload in enumerate(payloads):
            values = block[j].tobytes()
            at = payload.find(values)
            if at < 0:
                log.info("fleet encoder: values not found as one block; encoding every message")
                self._heads = []
                return
            heads.append(payload[:at])
            tails.append(payload[at + len(values):])
        self._heads, self._tails, self._n, self.fast = heads, tails, block.shape[2], False


__all__ = ["FleetEncoder"]
