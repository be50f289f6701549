"""A publisher's recent sensor chunks, served on request: what a subscriber missed can be fetched again.

Zenoh delivers with ``BLOCK`` congestion control, yet in about one end-to-end run in fifty at
full speed (1000 machines, 100,000 messages) a subscriber never received one transport batch
(~50 consecutive messages) that the publisher had put (docs/bus.md, "Loss and recovery"). The
publisher therefore keeps each machine's last ``depth`` chunks and answers a zenoh *query* on the
sensor key itself, ``hydro/<fleet>/<machine>/sensors?start=<s>;end=<s>``, with the chunks whose
first sample time lies in [start, end), oldest first, unchanged (the same bytes as published),
each with the time it was first sent (the attachment every message carries, ns since the epoch).
Subscribers notice a gap from the sample times (:mod:`hydrowatch.bus.recovery`) and ask.

Cost on the publisher: one deque append per message; memory ``depth`` × machines × chunk bytes
(50 × 1000 × 1.3 kB = 65 MB at the defaults: 5 s of a 1000-machine fleet in 0.1 s chunks).
"""

from __future__ import annotations

import threading
from collections import deque

import zenoh

from hydrowatch.bus.keys import parse_key
from hydrowatch.bus.pubsub import STAMP
from hydrowatch.errors import DataError
from hydrowatch.log import event, get_logger

log = get_logger(__name__)
DEPTH = 50
"""Chunks kept per machine (5 s of 0.1 s chunks): longer than any gap a subscriber notices and asks about."""


class ChunkHistory:
    """The last ``depth`` chunks published on each key, as (first sample time s, payload bytes, sent ns).

    Parameters
    ----------
    depth : int
        Chunks kept per key (older ones are forgotten).
    """

    def __init__(self, depth: int = DEPTH) -> None:
        if depth < 1:
            raise DataError(f"history depth must be >= 1 chunk. Got {depth}.")
        self.depth = depth
        self._chunks: dict[str, deque[tuple[float, bytes, int]]] = {}
        self._lock = threading.Lock()  # the publishing thread adds, zenoh's thread reads
        self.served = 0

    def add(self, key: str, start: float, payload: bytes, sent_ns: int = 0) -> None:
        """Remember one chunk of ``key`` whose first sample is at ``start`` s, published at ``sent_ns``."""
        chunks = self._chunks.get(key)
        if chunks is None:
            chunks = self._chunks[key] = deque(maxlen=self.depth)
        with self._lock:
            chunks.append((start, payload, sent_ns))

    def between(self, key: str, start: float, end: float) -> list[tuple[bytes, int]]:
        """(payload, sent ns) of ``key``'s chunks whose first sample time is in [start, end) s, oldest first."""
        chunks = self._chunks.get(key)
        if chunks is None:
            return []
        with self._lock:
            kept = list(chunks)
        return [(p, sent) for t, p, sent in kept if start - 1e-9 <= t < end - 1e-9]

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
