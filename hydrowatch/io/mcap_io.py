"""MCAP recordings of bus messages: a streaming writer and a reader that recovers unfinished files.

Layout (../shared/docs/contract.md): one channel per key expression ``hydro/<fleet>/<machine>/<kind>``
with ``message_encoding="x-arrow-ipc-stream"``; each message is one Arrow IPC stream
(:mod:`hydrowatch.io.codec`); each channel's schema record is named ``hydrowatch.<name>.v<version>``
with ``encoding="x-arrow-schema"`` and the serialised Arrow schema as data. The file metadata
record ``hydrowatch`` holds the recording metadata (string values; others JSON-encoded).

A file whose writer died before :meth:`McapWriter.close` has no summary; :func:`iter_messages`
then reads it sequentially and yields every message of every complete chunk, and says how much
it recovered through :class:`Recovery` and a warning.
"""

from __future__ import annotations

import json
import logging
import struct
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import pyarrow as pa
import zstandard
from mcap.exceptions import McapError
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.io.codec import decode_batch, encode_batch
from hydrowatch.io.mcap_chunks import ChunkedWriter
from hydrowatch.log import event, get_logger
from hydrowatch.schemas import schema_by_name, schema_name, schema_version, validate, wire_schema

MESSAGE_ENCODING = "x-arrow-ipc-stream"
SCHEMA_ENCODING = "x-arrow-schema"
METADATA_NAME = "hydrowatch"
"""Name of the file metadata record with fleet, machine, state, schema_version, units."""
TOPIC_KINDS: dict[str, str] = {
    "sensors": "sensor_chunk",
    "kl": "kl_window",
    "health": "health_verdict",
    "status": "status",
    "forecast": "forecast",
    "expected": "expected_window",
    "cycles": "rig_cycles",
    "cycle_health": "cycle_verdict",
}
"""Last part of a key expression → schema name."""

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
_READ_ERRORS = (McapError, ValueError, struct.error, zstandard.ZstdError, KeyError, EOFError)
_log = get_logger(__name__)


def topic(fleet: str, machine: str, kind: str = "sensors") -> str:
    """Key expression ``hydro/<fleet>/<machine>/<kind>``; ids must be non-empty and free of ``/``."""
    for what, value in (("fleet", fleet), ("machine", machine)):
        if not value or "/" in value or "*" in value:
            raise ParameterError(f"{what} id must be non-empty without '/' or '*'. Got {value!r}.")
    if kind not in TOPIC_KINDS:
        raise ParameterError(f"topic kind must be one of {sorted(TOPIC_KINDS)}. Got {kind!r}.")
    return f"hydro/{fleet}/{machine}/{kind}"


def _metadata_strings(metadata: Mapping[str, Any]) -> dict[str, str]:
    return {k: v if isinstance(v, str) else json.dumps(v, default=str) for k, v in metadata.items() if v is not None}


class McapWriter:
    """Streaming MCAP writer of Arrow messages; a context manager that finishes the file on exit.

    Parameters
    ----------
    path : str or Path
        File to create (overwritten).
    chunk_size : int, default 65536
        Bytes of messages per chunk (before compression). A crash loses at most the chunk in
        memory: about ``chunk_size`` bytes, ~5 s of 200 Hz sensor chunks at the default.
    compression : {"zstd", "lz4", "none"}, default "zstd"
    metadata : mapping, optional
        Written at once as the ``hydrowatch`` metadata record (non-string values JSON-encoded),
        so that even an unfinished file keeps it.
    flush_every_s : float, optional
        Also close the chunk once its messages span this much log time, s (bounds the loss on
        a crash at low message rates).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_size: int = 64 * 1024,
        compression: str = "zstd",
        metadata: Mapping[str, Any] | None = None,
        flush_every_s: float | None = None,
    ) -> None:
        if compression not in _COMPRESSION:
            raise ParameterError(f"compression must be one of {sorted(_COMPRESSION)}. Got {compression!r}.")
        if chunk_size <= 0:
            raise ParameterError(f"chunk_size must be > 0 bytes. Got {chunk_size}.")
        self.path = Path(path)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = ChunkedWriter(self._file, chunk_size=chunk_size, compression=_COMPRESSION[compression])
        self._writer.start(profile="hydrowatch", library="hydrowatch")
        self._schemas: dict[tuple[str, int], int] = {}
        self._channels: dict[str, tuple[int, str, int]] = {}
        self._flush_every_ns = None if flush_every_s is None else int(flush_every_s * 1e9)
        self._chunk_start_ns: int | None = None
        self.messages = 0
        self.closed = False
        if metadata:
            self._writer.add_metadata(METADATA_NAME, _metadata_strings(metadata))

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def add_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """Add a metadata record ``name`` (non-string values JSON-encoded)."""
        self._writer.add_metadata(name, _metadata_strings(data))

    def _channel(self, topic: str, name: str, version: int) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1:] != (name, version):
                raise DataError(
                    f"messages on {topic} must all be {known[1]} v{known[2]}. Got {name} v{version}.", str(self.path)
                )
            return known[0]
        if (name, version) not in self._schemas:
            data = wire_schema(schema_by_name(name, version)).serialize().to_pybytes()
            self._schemas[(name, version)] = self._writer.register_schema(
                name=f"hydrowatch.{name}.v{version}", encoding=SCHEMA_ENCODING, data=data
            )
        channel_id = self._writer.register_channel(
            topic=topic,
            message_encoding=MESSAGE_ENCODING,
            schema_id=self._schemas[(name, version)],
            metadata={"hydrowatch.schema": name, "hydrowatch.schema_version": str(version)},
        )
        self._channels[topic] = (channel_id, name, version)
        return channel_id

    def write(self, topic: str, batch: pa.RecordBatch, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Validate ``batch`` against its declared schema, encode it and append it on ``topic``.

        Parameters
        ----------
        topic : str
            Key expression, e.g. ``hydro/fleet1/m1/sensors``.
        batch : pyarrow.RecordBatch
            A message built against a :mod:`hydrowatch.schemas` schema (its metadata names it).
        log_time_ns : int
            Log time, ns (recording time base or Unix epoch), ≥ 0.
        """
        name, version = schema_name(batch.schema), schema_version(batch.schema)
        if name is None or version is None:
            raise DataError(f"a message on {topic} must carry hydrowatch schema metadata. Got none.", str(self.path))
        validate(batch, schema_by_name(name, version), f"{self.path}: {topic}")
        self.write_encoded(topic, encode_batch(batch), log_time_ns, name, version, publish_time_ns)

    def write_encoded(
        self,
        topic: str,
        data: bytes,
        log_time_ns: int,
        name: str,
        version: int,
        publish_time_ns: int | None = None,
    ) -> None:
        """Append an already encoded payload (a recorder storing what it received, unchanged)."""
        known = self._channels.get(topic)
        channel_id = known[0] if known is not None and known[1] == name and known[2] == version else (
            self._channel(topic, name, version))
        self.write_channel(channel_id, data, log_time_ns, publish_time_ns)

    def add_channel(
        self, topic: str, message_encoding: str, schema_name: str, schema_encoding: str, schema_data: bytes,
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        """Register a channel of another encoding (e.g. JSON for viewers) and its schema; returns its id
        for :meth:`write_channel`."""
        schema_id = self._writer.register_schema(name=schema_name, encoding=schema_encoding, data=schema_data)
        return self._writer.register_channel(
            topic=topic, message_encoding=message_encoding, schema_id=schema_id, metadata=dict(metadata or {}))

    def write_channel(
        self, channel_id: int, data: bytes, log_time_ns: int, publish_time_ns: int | None = None
    ) -> None:
        """Append an encoded message on a registered channel (log and publish time, ns, >= 0)."""
        if self.closed:
            raise DataError("writer must be open to write. Got a closed one.", str(self.path))
        if log_time_ns < 0:
            raise ParameterError(f"log_time_ns must be >= 0. Got {log_time_ns}.")
        log_time_ns = int(log_time_ns)
        publish = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        closed = self._writer.add_encoded(channel_id, log_time_ns, data, publish, self.messages)
        self.messages += 1
        if closed:
            # a finished chunk reaches the OS at once, so SIGKILL loses only the chunk being built
            self._file.flush()
            self._chunk_start_ns = None
        elif self._flush_every_ns is not None:
            if self._chunk_start_ns is None:
                self._chunk_start_ns = log_time_ns
            elif log_time_ns - self._chunk_start_ns >= self._flush_every_ns:
                self.flush()

    def flush(self) -> None:
        """Close the chunk in progress and hand it to the OS (what is flushed survives a crash)."""
        self._writer.flush()
        self._chunk_start_ns = None

    def close(self) -> None:
        """Write the last chunk, indexes and summary, and close the file (idempotent)."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()


@dataclass
class Recovery:
    """How much of a file was read: all of it, or the complete chunks of an unfinished one."""

    path: str
    finished: bool = False
    messages: int = 0
    bytes_read: int = 0
    bytes_total: int = 0
    error: str | None = None
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    @property
    def bytes_lost(self) -> int:
        """Bytes after the last complete record (0 for a finished file)."""
        return 0 if self.finished else self.bytes_total - self.bytes_read

    def describe(self) -> str:
        """One line: complete, or what was recovered and lost."""
        if self.finished:
            return f"complete: {self.messages} messages"
        return (
            f"unfinished file (writer did not close it: {self.error}); recovered {self.messages} messages "
            f"from {self.bytes_read} of {self.bytes_total} bytes, lost the last {self.bytes_lost} bytes "
            "(the chunk being written)"
        )


def mcap_finished(path: str | Path) -> bool:
    """Whether an MCAP file ends with the closing magic bytes (its writer finished it), from its last 8 bytes:
    a cheap test before reading a file that a recorder may still be writing."""
    from mcap.writer import MCAP0_MAGIC

    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            if f.tell() < 2 * len(MCAP0_MAGIC):
                return False
            f.seek(-len(MCAP0_MAGIC), 2)
            return f.read() == MCAP0_MAGIC
    except OSError:
        return False


def iter_records(
    path: str | Path, recovery: Recovery | None = None
) -> Iterator[tuple[Channel, Schema | None, Message]]:
    """Raw messages of a file in write order, with their channel and schema records.

    Reads sequentially, so finished and unfinished files take the same path; stops quietly at the
    first incomplete or corrupt record and fills ``recovery`` (also collects metadata records).

    Raises
    ------
    DataError
        When the file cannot be opened or does not start like an MCAP file.
    """
    source = str(path)
    recovery = recovery if recovery is not None else Recovery(source)
    recovery.path = source
    try:
        stream = open(path, "rb")  # noqa: SIM115 - closed in finally
    except OSError as exc:
        raise DataError(f"file must be readable. Got: {exc.strerror}.", source) from None
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    try:
        recovery.bytes_total = Path(path).stat().st_size
        reader = StreamReader(stream, validate_crcs=True, record_size_limit=max(recovery.bytes_total, 1))
        records = reader.records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except _READ_ERRORS as exc:
                if recovery.bytes_read == 0:
                    raise DataError(f"file must be an MCAP file. Got: {type(exc).__name__} {exc}.", source) from None
                recovery.error = f"{type(exc).__name__} {exc}".strip()
                break
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Metadata):
                recovery.metadata[record.name] = dict(record.metadata)
            elif isinstance(record, Footer):
                recovery.finished = True
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    recovery.error = f"message refers to unknown channel {record.channel_id}"
                    break
                recovery.messages += 1
                yield channel, schemas.get(channel.schema_id), record
            recovery.bytes_read = stream.tell()
        if recovery.finished:
            recovery.bytes_read = recovery.bytes_total
        elif recovery.error is None:
            recovery.error = "no footer"
    finally:
        stream.close()
    if not recovery.finished:
        event(
            _log,
            "recovered unfinished MCAP",
            logging.WARNING,
            path=source,
            messages=recovery.messages,
            lost_bytes=recovery.bytes_lost,
        )


def expected_schema(channel: Channel, schema: Schema | None) -> pa.Schema | None:
    """The current hydrowatch schema a channel's messages must match; None for foreign channels."""
    if channel.message_encoding != MESSAGE_ENCODING:
        return None
    name = channel.metadata.get("hydrowatch.schema")
    if name is None and schema is not None and schema.name.startswith("hydrowatch."):
        name = schema.name.split(".")[1]
    if name is None:
        name = TOPIC_KINDS.get(channel.topic.rsplit("/", 1)[-1])
    return schema_by_name(name) if name is not None else None


def iter_messages(
    path: str | Path, *, topics: set[str] | None = None, recovery: Recovery | None = None
) -> Iterator[tuple[str, pa.RecordBatch, int]]:
    """Decoded hydrowatch messages ``(topic, batch, log_time_ns)`` in write order.

    Recovers unfinished files (see :func:`iter_records`); pass a :class:`Recovery` to learn how
    much. Channels that are not Arrow (e.g. JSON for viewers) are skipped.

    Raises
    ------
    DataError
        On the first message that does not decode, naming the file, message number, topic and
        log time (the messages before it have been yielded).
    """
    for index, (channel, schema, message) in enumerate(iter_records(path, recovery)):
        if topics is not None and channel.topic not in topics:
            continue
        expected = expected_schema(channel, schema)
        if expected is None:
            continue
        where = f"{path}: message {index} on {channel.topic} (log time {message.log_time / 1e9:.3f} s)"
        yield channel.topic, decode_batch(message.data, expected, where), message.log_time


__all__ = [
    "METADATA_NAME",
    "MESSAGE_ENCODING",
    "SCHEMA_ENCODING",
    "TOPIC_KINDS",
    "McapWriter",
    "Recovery",
    "expected_schema",
    "iter_messages",
    "iter_records",
    "topic",
]
