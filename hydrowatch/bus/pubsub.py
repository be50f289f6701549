"""Arrow record batches over zenoh: a publisher per key and a decoding, shard-aware subscriber.

Every payload is one Arrow IPC message made by :func:`hydrowatch.io.encode_batch` (its schema
metadata carries the schema name and version); the attachment holds the publish wall-clock time
(int64 little-endian, ns since the Unix epoch) so receivers can measure latency. A subscriber
that gets a payload it cannot decode, or one of another schema or version, counts it, logs it
once per key and goes on (contract, "Bus"); with ``HYDROWATCH_QUARANTINE`` set it also keeps the first rejected
payloads byte for byte (:mod:`hydrowatch.bus.quarantine`).
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections import Counter
from collections.abc import Iterator, Sequence

import pyarrow as pa
import zenoh

from hydrowatch.bus.channel import WakingChannel
from hydrowatch.bus.keys import Key, parse_key
from hydrowatch.bus.quarantine import Quarantine
from hydrowatch.bus.shard import Shard
from hydrowatch.bus.takeover import ShardTakeover
from hydrowatch.errors import DataError
from hydrowatch.io.codec import Layout, check_payload, encode_batch
from hydrowatch.io.mcap_io import TOPIC_KINDS
from hydrowatch.log import event, get_logger
from hydrowatch.schemas import schema_by_name

log = get_logger(__name__)
STAMP = struct.Struct("<q")
"""The attachment every message carries: when it was published, int64 ns since the Unix epoch."""


def publish_time(sample: zenoh.Sample) -> int:
    """A received sample's publish time from its attachment, ns since the epoch (0 when it has none)."""
    attachment = sample.attachment
    stamp = attachment.to_bytes() if attachment is not None else b""
    return STAMP.unpack(stamp)[0] if len(stamp) == STAMP.size else 0

SETTLE_S = 0.5
"""Seconds a publisher waits after its keys first match, for the subscribers it learns of later."""


class Publisher:
    """Publishes record batches on contract keys, one declared zenoh publisher per key.

    Parameters
    ----------
    session : zenoh.Session
        An open session (the caller closes it).
    congestion_control : zenoh.CongestionControl
        ``BLOCK`` (default) never drops: use it for anything recorded.
    express : bool
        Send each message at once instead of batching small ones (lower latency, fewer msgs/s).
    """

    def __init__(
        self,
        session: zenoh.Session,
        *,
        congestion_control: zenoh.CongestionControl = zenoh.CongestionControl.BLOCK,
        express: bool = False,
    ) -> None:
        self.session = session
        self.congestion_control = congestion_control
        self.express = express
        self._publishers: dict[str, zenoh.Publisher] = {}
        self.messages_out = 0

    def _publisher(self, key: str) -> zenoh.Publisher:
        pub = self._publishers.get(key)
        if pub is None:
            pub = self.session.declare_publisher(
                key, congestion_control=self.congestion_control, express=self.express
            )
            self._publishers[key] = pub
        return pub

    def wait_for_subscribers(self, keys: Sequence[str], timeout: float, settle: float = SETTLE_S,
                             stop: threading.Event | None = None) -> bool:
        """Declare the publishers of ``keys``, wait until each has a matching subscriber, then
        ``settle`` seconds more.

        Zenoh delivers only to subscribers it already knows of, so a publisher whose first
        messages must not be lost waits here. Matching turns true with the *first* subscriber; in
        an embedded bus a peer hears of the others by gossip and connects to them a moment later
        (two recorder shards: the second one's declaration came mid-way through the first burst
        and it missed those messages), hence the settling time. Returns False when ``timeout``
        seconds pass before every key matches, or at once when ``stop`` is set (a service told to
        stop while it waits). Until 2026-11-27 this tested the ``MatchingStatus`` object, which is always
        true, instead of its ``matching``: it never waited for a subscriber, only ``settle`` seconds.
        """
        stop = stop if stop is not None else threading.Event()
        deadline = time.monotonic() + timeout
        publishers = [self._publisher(k) for k in keys]
        # zenoh's stub says bool; it returns a MatchingStatus, whose truth is always True
        while not all(p.matching_status.matching for p in publishers):  # type: ignore[attr-defined]
            if time.monotonic() >= deadline or stop.wait(0.01):
                return False
        return not stop.wait(settle)

    def put_payload(self, key: str, payload: bytes, publish_time_ns: int | None = None) -> None:
        """Publish already-encoded bytes on ``key`` (replay uses this to avoid re-encoding)."""
        stamp = STAMP.pack(time.time_ns() if publish_time_ns is None else publish_time_ns)
        self._publisher(key).put(payload, attachment=stamp)
        self.messages_out += 1

    def put(self, key: str, batch: pa.RecordBatch) -> None:
        """Encode ``batch`` (its schema metadata names schema and version) and publish it on ``key``."""
        self.put_payload(key, encode_batch(batch))

    def close(self) -> None:
        """Undeclare every publisher (safe to call twice)."""
        for pub in self._publishers.values():
            pub.undeclare()
        self._publishers.clear()

    def __enter__(self) -> Publisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Message:
    """One received message, validated on receipt; its record batch is read on first access.

    Attributes
    ----------
    key : Key
        Fleet, machine and topic of the key it came on.
    batch : pyarrow.RecordBatch
        The decoded, validated record batch (read from ``payload`` when first asked for: a
        consumer that stores payloads, like the recorder, never pays for it).
    payload : bytes
        The bytes as received (the recorder stores them unchanged).
    receive_time_ns, publish_time_ns : int
        Wall-clock receive and publish times, ns since the Unix epoch (publish time 0 when the
        publisher sent no attachment).
    layout : hydrowatch.io.codec.Layout or None
        What validation found (schema, where ``t`` starts); None when ``batch`` was given.
    """

    __slots__ = ("_batch", "key", "layout", "payload", "publish_time_ns", "receive_time_ns")

    def __init__(
        self,
        key: Key,
        batch: pa.RecordBatch | None,
        payload: bytes,
        receive_time_ns: int,
        publish_time_ns: int,
        layout: Layout | None = None,
    ) -> None:
        if batch is None and layout is None:
            raise ValueError("a Message needs its batch or the layout check_payload returned")
        self.key, self._batch, self.payload, self.layout = key, batch, payload, layout
        self.receive_time_ns, self.publish_time_ns = receive_time_ns, publish_time_ns

    @property
    def batch(self) -> pa.RecordBatch:
        if self._batch is None:
            assert self.layout is not None
            self._batch = self.layout.read(self.payload)
        return self._batch

    @property
    def schema(self) -> pa.Schema:
        """The message's Arrow schema (with its metadata), without reading the batch."""
        return self.layout.schema if self.layout is not None else self.batch.schema

    def start_time(self) -> float | None:
        """``t`` of the first row, s (None when the message has no ``t`` column or no rows)."""
        if self.layout is not None and self.layout.first_t is not None:
            return self.layout.start_time(self.payload)
        batch = self.batch
        if "t" not in batch.schema.names or not batch.num_rows:
            return None
        return float(batch.column("t")[0].as_py())

    def time_span(self) -> tuple[float, float, int] | None:
        """(``t`` of the first row s, of the last row s, rows); None without a ``t`` column or rows."""
        layout = self.layout
        if layout is not None and layout.first_t is not None:
            return layout.start_time(self.payload), layout.end_time(self.payload), layout.rows  # type: ignore[return-value]
        batch = self.batch
        if "t" not in batch.schema.names or not batch.num_rows:
            return None
        t = batch.column("t")
        return float(t[0].as_py()), float(t[-1].as_py()), batch.num_rows

    def __repr__(self) -> str:
        return f"Message({self.key}, {len(self.payload)} bytes, received {self.receive_time_ns})"


class Subscriber:
    """Receives record batches of one schema on one or more key expressions.

    Samples wait in a bounded zenoh FIFO channel per key expression; when it is full the zenoh
    thread waits, which (with ``BLOCK`` publishers) slows the publishers down instead of losing
    data. No Python runs on zenoh's threads: the caller's thread takes samples out, decodes and
    validates them in :meth:`recv` / :meth:`recv_many`, and sleeps while there are none
    (:class:`hydrowatch.bus.channel.WakingChannel`). The receive time is taken when the sample
    is taken out.

    Parameters
    ----------
    session : zenoh.Session
    key_exprs : str or sequence of str
        E.g. ``"hydro/*/*/sensors"`` or ``["hydro/f1/**"]``.
    schema : pyarrow.Schema or None
        Expected schema (from :mod:`hydrowatch.schemas`); others are counted as undecodable.
        None: the schema of each key's topic (``sensors`` → ``sensor_chunk``, ...).
    shard : Shard or ShardTakeover
        Only machines of this shard are kept (asked per message: a :class:`ShardTakeover`'s machines change
        when shards come and go); the others are counted in ``outside_shard``.
    capacity : int
        Messages each key expression's channel holds before the zenoh thread waits.
    quarantine : Quarantine or None
        Where rejected payloads are kept (default: :meth:`Quarantine.from_env`, none unless set).
    """

    def __init__(
        self,
        session: zenoh.Session,
        key_exprs: str | Sequence[str],
        schema: pa.Schema | None = None,
        *,
        shard: Shard | ShardTakeover | None = None,
        capacity: int = 100_000,
        quarantine: Quarantine | None = None,
    ) -> None:
        self.schema = schema
        self.quarantine = quarantine if quarantine is not None else Quarantine.from_env()
        self.shard: Shard | ShardTakeover = shard or Shard()
        self.key_exprs = [key_exprs] if isinstance(key_exprs, str) else list(key_exprs)
        self.received = 0
        self.outside_shard = 0
        self.undecodable: Counter[str] = Counter()
        self._keys: dict[str, tuple[Key, pa.Schema]] = {}
        self._subscribers = [
            session.declare_subscriber(k, zenoh.handlers.FifoChannel(capacity)) for k in self.key_exprs
        ]
        self._ready = threading.Event()
        # the channels outlive their subscribers: after close() they still hold what had arrived
        self._channels = [WakingChannel(sub.handler, self._ready) for sub in self._subscribers]

    def _take(self) -> tuple[str, bytes, int, int] | None:
        """The next queued sample of this shard as (key, payload, receive ns, publish ns), or None."""
        for channel in self._channels:
            while (sample := channel.take()) is not None:
                key = str(sample.key_expr)
                if self.shard.count > 1:
                    parts = key.split("/")
                    if len(parts) > 2 and not self.shard.includes(parts[2]):
                        self.outside_shard += 1
                        continue
                return key, sample.payload.to_bytes(), time.time_ns(), publish_time(sample)
        return None

    def _decode(self, item: tuple[str, bytes, int, int]) -> Message | None:
        key, payload, received, published = item
        self.received += 1
        try:
            known = self._keys.get(key)
            if known is None:
                parsed = parse_key(key)
                schema = self.schema if self.schema is not None else schema_by_name(TOPIC_KINDS[parsed.topic])
                known = self._keys[key] = (parsed, schema)
            return Message(known[0], None, payload, received, published, check_payload(payload, known[1], key))
        except DataError as exc:
            self.undecodable[key] += 1
            if self.undecodable[key] == 1:
                event(log, "undecodable message skipped", logging.WARNING, key=key, reason=exc)
            if self.quarantine is not None:
                self.quarantine.keep(key, payload, str(exc), received, published)
            return None

    def recv(self, timeout: float | None = None) -> Message | None:
        """The next decodable message, or None when none came within ``timeout`` seconds."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            item = self._take()
            if item is not None:
                message = self._decode(item)
                if message is not None:
                    return message
                continue
            # every channel is empty: let the wakers watch them and sleep until one hands a sample over
            self._ready.clear()
            if any([channel.watch() for channel in self._channels]):
                continue
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None
            self._ready.wait(left)

    def recv_many(self, limit: int = 1000, timeout: float | None = None) -> list[Message]:
        """Up to ``limit`` decodable messages: waits up to ``timeout`` seconds for the first, then
        takes only what is already queued (empty when nothing came in time).

        One call per burst instead of one per message: what a consumer that keeps up with
        thousands of messages per second (the recorder) wants.
        """
        first = self.recv(timeout)
        if first is None:
            return []
        messages = [first]
        while len(messages) < limit and (item := self._take()) is not None:
            message = self._decode(item)
            if message is not None:
                messages.append(message)
        return messages

    def drain(self) -> Iterator[Message]:
        """Every message already queued, without waiting (after :meth:`close`, to flush)."""
        while messages := self.recv_many(timeout=0.0):
            yield from messages

    @property
    def undecodable_total(self) -> int:
        """Undecodable messages over every key."""
        return sum(self.undecodable.values())

    def close(self) -> None:
        """Stop receiving (undeclare); queued messages stay available to :meth:`drain`."""
        for sub in self._subscribers:
            sub.undeclare()
        self._subscribers = []
        for channel in self._channels:
            channel.close()

    def __enter__(self) -> Subscriber:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
