"""A publisher's recent sensor chunks, served on request: what a subscriber missed can be fetched again.

Zenoh delivers with ``BLOCK`` congestion control, yet in about one end-to-end run in fifty at
full speed (1000 machines, 100,000 messages) a subscriber never received one transport batch
(~50 consecutive messages) that the publisher had put (docs/bus.md, "Loss and recovery"). The
publisher therefore keeps each machine's last ``depth`` chunks and answers a zenoh *query* on the
sensor key itself, ``hydro/<fleet>/<machine>/sensors?start=<s>;end=<s>``, with the chunks whose
first sample time lies in [start, end), oldest first, unchanged (the same bytes as published),
each with the time it was first sent (the attachment every message carries, ns since the epoch).
Subscribers notice a gap from the sample times (:mod:`hydrowatch.bus.recovery`) and ask.

Cost on the publisher: one copy of each message into its key's ring; memory ``depth`` × machines × slot bytes
(the key's chunk size and a 32nd, rounded up to 64 B: 50 × 1000 × 1.4 kB = 70 MB at the defaults, 5 s of a
1000-machine fleet in 0.1 s chunks).

**One buffer per key, allocated once.** Each key's chunks are copied into fixed slots of one buffer instead of being
kept as objects of their own. Kept as objects (one 3.2 kB ``bytes`` per chunk, 300,000 of them for 30 s of 1000
machines), each freed 30 s after it was allocated among newer ones, the heap fragmented: in the seventh soak
(2026-11-28) the plant's glibc bytes in use stayed at 1028.2 MB while its free space in the arenas and its RSS rose
together (+1.6 and +1.8 MB in 10 minutes, trimmed every 10 s). A slot is reused in place; a chunk larger than its
key's slot grows that key's buffer once (every kept chunk copied over).
"""

from __future__ import annotations

import threading
from array import array

import zenoh

from hydrowatch.bus.keys import parse_key
from hydrowatch.bus.pubsub import STAMP
from hydrowatch.errors import DataError
from hydrowatch.log import event, get_logger

log = get_logger(__name__)
DEPTH = 50
"""Chunks kept per machine (5 s of 0.1 s chunks): longer than any gap a subscriber notices and asks about."""


SLOT_HEADROOM = 1.03125
"""A key's slot holds its first chunk's size and a 32nd, rounded up to 64 B (a later, larger chunk regrows it: a
chunk's size changes only with its label, a wearing machine's state name)."""


def _slot_bytes(size: int) -> int:
    return max(64, -(-int(size * SLOT_HEADROOM) // 64) * 64)


class _Ring:
    """One key's last ``depth`` chunks in fixed slots of one buffer: payload bytes, first sample time, sent ns."""

    __slots__ = ("slot", "data", "size", "start", "sent", "next", "count")

    def __init__(self, depth: int, slot: int) -> None:
        self.slot = slot
        self.data = bytearray(depth * slot)
        self.size = array("q", bytes(8 * depth))
        self.start = array("d", bytes(8 * depth))
        self.sent = array("q", bytes(8 * depth))
        self.next = 0
        """Slot of the next chunk."""
        self.count = 0
        """Chunks held (≤ depth)."""

    def add(self, start: float, payload: bytes, sent_ns: int) -> None:
        depth, n = len(self.size), len(payload)
        if n > self.slot:
            self._regrow(_slot_bytes(n))
        at = self.next * self.slot
        self.data[at:at + n] = payload
        self.size[self.next], self.start[self.next], self.sent[self.next] = n, start, sent_ns
        self.next = (self.next + 1) % depth
        self.count = min(self.count + 1, depth)

    def _regrow(self, slot: int) -> None:
        data = bytearray(len(self.size) * slot)
        for i in range(len(self.size)):
            data[i * slot:i * slot + self.size[i]] = self.data[i * self.slot:i * self.slot + self.size[i]]
        self.data, self.slot = data, slot

    def between(self, start: float, end: float) -> list[tuple[bytes, int]]:
        depth = len(self.size)
        out = []
        for k in range(self.count):
            i = (self.next - self.count + k) % depth
            if start - 1e-9 <= self.start[i] < end - 1e-9:
                out.append((bytes(self.data[i * self.slot:i * self.slot + self.size[i]]), self.sent[i]))
        return out


class ChunkHistory:
    """The last ``depth`` chunks published on each key, as (first sample time s, payload bytes, sent ns), each key's
    in one buffer of fixed slots (module docstring).

    Parameters
    ----------
    depth : int
        Chunks kept per key (older ones are forgotten).
    """

    def __init__(self, depth: int = DEPTH) -> None:
        if depth < 1:
            raise DataError(f"history depth must be >= 1 chunk. Got {depth}.")
        self.depth = depth
        self._rings: dict[str, _Ring] = {}
        self._lock = threading.Lock()  # the publishing thread adds, zenoh's thread reads
        self.served = 0

    @property
    def nbytes(self) -> int:
        """Bytes of the kept chunks' buffers."""
        with self._lock:
            return sum(len(r.data) for r in self._rings.values())

    def add(self, key: str, start: float, payload: bytes, sent_ns: int = 0) -> None:
        """Remember one chunk of ``key`` whose first sample is at ``start`` s, published at ``sent_ns``."""
        with self._lock:
            ring = self._rings.get(key)
            if ring is None:
                ring = self._rings[key] = _Ring(self.depth, _slot_bytes(len(payload)))
            ring.add(start, payload, sent_ns)

    def between(self, key: str, start: float, end: float) -> list[tuple[bytes, int]]:
        """(payload, sent ns) of ``key``'s chunks whose first sample time is in [start, end) s, oldest first."""
        with self._lock:
            ring = self._rings.get(key)
            return [] if ring is None else ring.between(start, end)

    def answer(self, query: zenoh.Query) -> None:
        """Reply to ``<key>?start=<s>;end=<s>`` with the chunks in that range (runs on zenoh's thread)."""
        key = str(query.key_expr)
        try:
            parse_key(key)
            start, end = float(query.parameters.get("start") or "nan"), float(query.parameters.get("end") or "nan")
            if not start <= end:
                raise ValueError(f"start must be <= end. Got start={start}, end={end}")
        except (DataError, ValueError) as exc:
            query.reply_err(f"history query must be '<sensor key>?start=<s>;end=<s>'. {exc}")
            return
        for payload, sent in self.between(key, start, end):
            query.reply(key, payload, attachment=STAMP.pack(sent))
            self.served += 1


class HistoryServer:
    """Answers history queries on ``key_expr`` (e.g. ``hydro/<fleet>/*/sensors``) from a :class:`ChunkHistory`.

    Use as a context manager or call :meth:`close`: a queryable still declared at interpreter exit
    hangs the process (stack-notes).
    """

    def __init__(self, session: zenoh.Session, key_expr: str, history: ChunkHistory) -> None:
        self.history = history
        self._queryable: zenoh.Queryable | None = session.declare_queryable(key_expr, self._answer)

    def _answer(self, query: zenoh.Query) -> None:
        try:
            self.history.answer(query)
        except Exception as exc:  # noqa: BLE001 - never let a query kill zenoh's thread
            event(log, "history query failed", key=str(query.key_expr), reason=exc)

    def close(self) -> None:
        """Undeclare the queryable (safe to call twice)."""
        if self._queryable is not None:
            self._queryable.undeclare()
            self._queryable = None

    def __enter__(self) -> HistoryServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
