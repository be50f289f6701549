"""Gaps in each machine's sensor chunks, noticed from the sample times and filled from the publisher's history.

A subscriber that must not lose samples (the recorder) passes every received burst through
:meth:`GapRecovery.observe` and writes what it returns, then what :meth:`GapRecovery.collect`
returns. Per sensor key it expects the next chunk to start one sample period after the last one
ended; a chunk that starts later leaves a gap [expected, start), which is asked for at once with
a zenoh query on the key itself (``<key>?start=<s>;end=<s>``, :mod:`hydrowatch.bus.history`).
While a key has a question open, its newer chunks are held back; when every answer is in (or
``timeout`` has passed) the recovered and the held chunks are released together in sample-time
order, so what is written stays in order (files, replays and readers never see a chunk out of
place). A chunk that turns up both ways is kept once. Recovered chunks carry the time their
publisher first sent them (the history's stamp) as receive time.

The ends of a stream have no neighbour to show a gap. Its *head*: on a machine's first chunk
the history is asked for whatever came before (chunks lost at the start, or, for a recorder that
joins a running fleet, up to the history's depth of past chunks, which the recording then starts
with). Its *tail*: when the bus has been quiet for a moment (the end of a run; publishers linger a
while before they leave), :meth:`ask_tails` asks every machine's history for whatever follows its
last received chunk; and :meth:`ask_stalled`, called every second or so, asks for the tails of the
machines that sent nothing while others did (a publisher that ended before the rest of the fleet).
A gap nobody answers (a publisher without history, or one that has forgotten
the chunks or is gone) is counted and logged with its machine and time range: the loss is then
known, not silent. What this cannot see: a machine none of whose chunks arrived, and a tail whose
publisher has already left.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

import pyarrow as pa
import zenoh

from hydrowatch.bus.keys import parse_key
from hydrowatch.bus.pubsub import Message, publish_time
from hydrowatch.bus.shard import Shard
from hydrowatch.bus.takeover import ShardTakeover
from hydrowatch.errors import DataError
from hydrowatch.io.codec import check_payload
from hydrowatch.log import event, get_logger
from hydrowatch.schemas import schema_by_name

log = get_logger(__name__)
TIMEOUT_S = 2.0
"""Seconds a history query may take before its missing samples count as lost."""
SAMPLE_PERIOD_S = 1.0 / 200.0
"""Sample period assumed for one-row chunks, s (the contract's 200 Hz)."""
FORGET_AFTER_S = 60.0
"""Chunk starts taken out of order are remembered this long behind a key's stream (to keep each once), s."""
LOGGED_GAPS = 20
"""Gaps logged one by one (then only counted), and losses logged per key (a publisher of chunks whose times are
broken, NaN or going backwards, must not flood the log)."""


def _stamp(t: float) -> int:
    """A sample time as whole microseconds (chunk starts compare exactly)."""
    return int(round(t * 1e6))


@dataclass
class _Request:
    key: str
    start: float
    end: float
    samples: int
    """Samples missing (0 for a head or tail: nothing is known to be missing)."""
    kind: str
    """``gap``, ``head`` or ``tail``."""
    deadline: float
    replies: zenoh.handlers.Handler
    received: int = 0
    done: bool = False


@dataclass
class GapRecovery:
    """Notices gaps per sensor key, fetches the missing chunks and keeps each key's output in order.

    Parameters
    ----------
    session : zenoh.Session
    timeout : float
        Seconds to wait for a history query's replies.
    shard : Shard or ShardTakeover or None
        The machines asked about unprompted (tails of quiet or stalled machines): only those the shard handles
        now. A machine given back to its returning shard stops sending here, and must not be fetched from the
        publisher's history as if stalled.

    Attributes
    ----------
    gaps, samples_missing : int
        Gaps noticed and the samples they lacked.
    chunks_recovered, samples_recovered : int
        What the history queries brought back (heads and tails included).
    samples_lost, chunks_lost : int
        Samples of gaps that stayed unanswered (or were answered only in part), and about how many
        chunks they were (at the key's chunk length).
    """

    session: zenoh.Session
    timeout: float = TIMEOUT_S
    shard: Shard | ShardTakeover | None = None
    gaps: int = 0
    samples_missing: int = 0
    chunks_recovered: int = 0
    samples_recovered: int = 0
    samples_lost: int = 0
    chunks_lost: int = 0
    losses: Counter[str] = field(default_factory=Counter)
    """Per key, gaps that stayed (in part) unanswered; a key's first :data:`LOGGED_GAPS` are logged one by one."""
    _next: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Per key: when its next chunk should start, s, and its sample period, s."""
    _rows: dict[str, int] = field(default_factory=dict)
    _pending: list[_Request] = field(default_factory=list)
    _held: dict[str, list[Message]] = field(default_factory=dict)
    """Per key with a gap or head question open: the chunks received or recovered meanwhile."""
    _filled: dict[str, set[int]] = field(default_factory=dict)
    """Per key, the starts (µs) of chunks taken out of their order (late or recovered): each is kept once."""
    _tail_asked: dict[str, float] = field(default_factory=dict)
    _seen: dict[str, float] = field(default_factory=dict)
    _schema: pa.Schema = field(default_factory=lambda: schema_by_name("sensor_chunk"))

    def observe(self, messages: Iterable[Message]) -> list[Message]:
        """Check received messages (in arrival order), ask for what is missing; returns those to write now."""
        out: list[Message] = []
        for message in messages:
            span = message.time_span() if message.key.topic == "sensors" else None
            if span is None or not (math.isfinite(span[0]) and math.isfinite(span[1]) and span[1] >= span[0]):
                out.append(message)  # no times, or not a stretch of time (NaN, time going backwards): not a place
                continue             # in the stream to expect the next chunk from; the scorer rejects it
            start, end, rows = span
            key = str(message.key)
            previous = self._next.get(key)
            if previous is None:
                self._query(key, float("-inf"), start, 0, "head")
            else:
                expected, period = previous
                if start > expected + 0.5 * period:
                    self._ask(key, expected, start, period)
                elif start < expected - 0.5 * period:  # late: it may fill a gap, or have been recovered already
                    self._take_late(key, message, start, rows, out)
                    continue
            period = (end - start) / (rows - 1) if rows > 1 else (previous[1] if previous else SAMPLE_PERIOD_S)
            self._next[key] = (end + period, period)
            self._rows[key] = rows
            (self._held[key] if key in self._held else out).append(message)
        return out

    def _take_late(self, key: str, message: Message, start: float, rows: int, out: list[Message]) -> None:
        filled = self._filled.setdefault(key, set())
        if _stamp(start) in filled:
            return
        filled.add(_stamp(start))
        for request in self._pending:  # a gap it fills is that much less lost
            if request.key == key and request.start - 1e-9 <= start < request.end - 1e-9:
                request.received += rows
        (self._held[key] if key in self._held else out).append(message)

    def _ask(self, key: str, start: float, end: float, period: float) -> None:
        samples = max(1, int(round((end - start) / period)))
        self.gaps += 1
        self.samples_missing += samples
        self._query(key, start, end, samples, "gap")
        if self.gaps <= LOGGED_GAPS:
            event(log, "gap in sensor chunks; asking the publisher's history", key=key, start_s=round(start, 6),
                  end_s=round(end, 6), samples=samples)

    def _query(self, key: str, start: float, end: float, samples: int, kind: str) -> None:
        """Ask the history of ``key`` for chunks starting in [start, end) s; a gap or head holds the key's output."""
        replies = self.session.get(f"{key}?start={start!r};end={end!r}", zenoh.handlers.FifoChannel(1024),
                                   consolidation=zenoh.ConsolidationMode.NONE, target=zenoh.QueryTarget.ALL,
                                   timeout=self.timeout)
        self._pending.append(_Request(key, start, end, samples, kind, time.monotonic() + self.timeout, replies))
        if kind != "tail":
            self._held.setdefault(key, [])

    def ask_tails(self, keys: Iterable[str] | None = None) -> None:
        """Ask the history of ``keys`` (default: every machine) for chunks after the last one received (call
        when the bus is quiet); a key is asked once per place in its stream."""
        asking = {r.key for r in self._pending if r.kind == "tail"}
        for key in self._next if keys is None else keys:
            if self.shard is not None and not self.shard.includes(key.split("/")[2]):
                continue
            expected = self._next[key][0]
            if key not in asking and self._tail_asked.get(key) != expected:
                self._tail_asked[key] = expected
                self._query(key, expected, float("inf"), 0, "tail")

    def ask_stalled(self) -> None:
        """Ask for the tails of the machines that sent nothing since the last call while others did (call every
        second or so): a machine's last chunks lost while the rest of the fleet goes on (its publisher ended
        first, or a shard) are fetched before that publisher leaves."""
        moved = {key for key, (expected, _) in self._next.items() if self._seen.get(key) != expected}
        if moved:
            self.ask_tails([key for key in self._next if key not in moved and key in self._seen])
        self._seen = {key: expected for key, (expected, _) in self._next.items()}

    @property
    def pending(self) -> int:
        """History queries still waiting for replies."""
        return len(self._pending)

    def collect(self) -> list[Message]:
        """Recovered chunks, and chunks held back behind a question now answered, in sample-time order per key."""
        out: list[Message] = []
        now = time.monotonic()
        settled: set[str] = set()
        for request in list(self._pending):
            self._drain(request, out)
            if request.done or now > request.deadline:
                self._pending.remove(request)
                self._settle(request)
                settled.add(request.key)
        if settled:
            still_open = {r.key for r in self._pending if r.kind != "tail"}
            for key in settled - still_open:
                held = self._held.pop(key, None)
                if held:
                    out += sorted(held, key=lambda m: m.start_time() or 0.0)
        return out

    def _drain(self, request: _Request, out: list[Message]) -> None:
        filled = self._filled.setdefault(request.key, set())
        while True:
            try:
                reply = request.replies.try_recv()
            except zenoh.ZError:  # every replier has answered
                request.done = True
                return
            if reply is None:
                return
            message = self._message(request, reply)
            span = None if message is None else message.time_span()
            if message is None or span is None or not request.start - 1e-9 <= span[0] < request.end - 1e-9 \
                    or _stamp(span[0]) in filled:
                continue  # refused, undecodable, outside the range, or already taken
            if request.kind == "tail" and span[0] < self._next[request.key][0] - 0.5 * self._next[request.key][1]:
                continue  # arrived on the bus, in order, since the tail was asked for: already written
            filled.add(_stamp(span[0]))
            request.received += span[2]
            self.chunks_recovered += 1
            self.samples_recovered += span[2]
            if request.kind == "tail":  # in order after everything written: out at once, the stream goes on after it
                expected, period = self._next[request.key]
                self._next[request.key] = (max(expected, span[1] + period), period)
                (self._held[request.key] if request.key in self._held else out).append(message)
            else:
                self._held.setdefault(request.key, []).append(message)

    def _message(self, request: _Request, reply: zenoh.Reply) -> Message | None:
        sample = reply.ok
        if sample is None:
            error = reply.err
            event(log, "history query refused", logging.WARNING, key=request.key,
                  reason=error.payload.to_string() if error is not None else "no reply")
            return None
        payload = sample.payload.to_bytes()
        sent = publish_time(sample)
        try:
            layout = check_payload(payload, self._schema, f"history of {request.key}")
        except DataError as exc:
            event(log, "undecodable history reply skipped", logging.WARNING, key=request.key, reason=exc)
            return None
        return Message(parse_key(request.key), None, payload, sent or time.time_ns(), sent, layout)

    def _settle(self, request: _Request) -> None:
        filled = self._filled.get(request.key)
        if filled and request.key in self._next:  # a long-running recorder keeps only the last minute's
            oldest = _stamp(self._next[request.key][0] - FORGET_AFTER_S)
            self._filled[request.key] = {t for t in filled if t >= oldest}
        lost = request.samples - request.received
        if lost > 0:
            self.samples_lost += lost
            self.chunks_lost += -(-lost // max(1, self._rows.get(request.key, lost)))
            self.losses[request.key] += 1
            if self.losses[request.key] <= LOGGED_GAPS:
                event(log, "samples lost: the gap was not recovered", logging.WARNING, key=request.key,
                      start_s=round(request.start, 6), end_s=round(request.end, 6), samples=lost)

    def wait(self, timeout: float | None = None) -> list[Message]:
        """Collect until every question is settled (at most ``timeout`` s, default the query timeout); releases
        everything held back."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        out = self.collect()
        while self._pending and time.monotonic() < deadline:
            time.sleep(0.01)
            out += self.collect()
        for request in self._pending:
            self._settle(request)
        self._pending.clear()
        for key in list(self._held):
            out += sorted(self._held.pop(key), key=lambda m: m.start_time() or 0.0)
        return out
