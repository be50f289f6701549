"""Arrow encoding of bus and MCAP messages: one message = one Arrow IPC stream (schema + one batch).

The IPC stream carries the schema with its metadata (``hydrowatch.schema``,
``hydrowatch.schema_version``, field units), so a subscriber can tell garbage, another schema and
another version apart (:class:`UndecodableMessageError`, :class:`SchemaMismatchError`,
:class:`SchemaVersionError`, all :class:`DataError`), and any Arrow library in any language can read
a message without hydrowatch. The price is the schema bytes in every message; the trade-off is
measured in ``benchmarks/bench_io_codec.py`` and written down in ``docs/formats.md``. What is read from a
payload's bytes without building its batch (its head, the null counts of its field nodes, where ``t`` and the string
columns lie) is :mod:`hydrowatch.io.ipc_bytes`.
"""

from __future__ import annotations

from typing import NamedTuple

import pyarrow as pa

from hydrowatch.errors import DataError
from hydrowatch.io.ipc_bytes import (
    END_OF_STREAM,
    F64,
    first_t_offset,
    head,
    required_null_counts,
    schema_message,
    string_buffers,
    strings_ok,
)
from hydrowatch.io.sensor_chunk import LABEL_FIELD, arrays_from_sensor_chunk, sensor_chunk_from_arrays
from hydrowatch.schemas import SchemaMismatchError, SchemaVersionError, schema_name, validate

_READ_ERRORS = (pa.ArrowException, EOFError, OSError)
"""What reading a corrupted message raises (ArrowInvalid, ArrowKeyError for a dictionary id, ...)."""
_CACHE_SIZE = 64
"""Distinct schemas each cache holds (a handful in practice: one per message kind and column set)."""
_ENCODE_CACHE: list[tuple[pa.Schema, bytes | None]] = []
"""Schema → its serialised schema message (None: encode with a stream writer)."""
_DECODE_CACHE: dict[tuple[bytes, int], _KnownSchema] = {}
"""(schema message bytes, id of the expected schema) → what full validation found for them."""
_LAYOUT_CACHE_SIZE = 4096
"""Distinct message heads remembered (one per schema, row count, label length and null counts)."""
_LAYOUTS: dict[bytes, Layout] = {}
"""Message head → its layout (the expected schema is part of the layout and compared)."""


class UndecodableMessageError(DataError):
    """A payload that is not an Arrow IPC stream holding a record batch."""


def encode_batch(batch: pa.RecordBatch) -> bytes:
    """Serialise one record batch as an Arrow IPC stream (schema message, batch, end marker).

    The schema message is the same for every batch of a schema, so it is serialised once and
    cached: a message costs one ``batch.serialize()`` (~3x faster than a stream writer per call,
    same bytes).

    Parameters
    ----------
    batch : pyarrow.RecordBatch
        A message built against a schema of :mod:`hydrowatch.schemas` (its metadata travels along).

    Returns
    -------
    bytes
        The payload to publish on the bus or store in an MCAP message.
    """
    prefix = _schema_prefix(batch)
    if prefix is None:
        return _stream_bytes(batch)
    return b"".join((prefix, batch.serialize(), END_OF_STREAM))  # join reads the Arrow buffer in place


def _stream_bytes(batch: pa.RecordBatch) -> bytes:
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, batch.schema) as writer:
        writer.write_batch(batch)
    return sink.getvalue().to_pybytes()


def _schema_prefix(batch: pa.RecordBatch) -> bytes | None:
    """The cached schema message of ``batch``'s schema (None: encode with a stream writer)."""
    schema = batch.schema
    for known, prefix in _ENCODE_CACHE:
        if known.equals(schema, check_metadata=True):
            return prefix
    return _cache_schema_prefix(batch)


def _cache_schema_prefix(batch: pa.RecordBatch) -> bytes | None:
    """Remember the schema message of ``batch``'s schema when schema + ``serialize()`` + end marker
    gives exactly the bytes of a stream writer (not so with dictionaries); None: use the writer."""
    stream = _stream_bytes(batch)
    prefix = batch.schema.serialize().to_pybytes()
    if stream != b"".join((prefix, batch.serialize().to_pybytes(), END_OF_STREAM)):
        prefix = None
    if len(_ENCODE_CACHE) >= _CACHE_SIZE:
        _ENCODE_CACHE.pop(0)
    _ENCODE_CACHE.append((batch.schema, prefix))
    return prefix


class Layout(NamedTuple):
    """What validation found for one message *head* (schema message + batch metadata, i.e. every
    byte before the body): a payload with the same head and size is the same schema, row count,
    buffer layout and null counts, so it passes the same checks (the body is only values)."""

    expected: pa.Schema
    schema: pa.Schema
    schema_length: int
    """Bytes of the schema message: the batch message starts here."""
    size: int
    """Bytes of the whole payload."""
    first_t: int | None
    """Byte offset of the first value of a float64 column ``t`` (None: no such column or no rows)."""
    rows: int = 0
    """Rows of the batch (part of the head, so the same for every payload of this layout)."""
    strings: tuple[tuple[int, int, int], ...] = ()
    """Per string column: byte offsets of its offsets buffer and of its data, and the data's length. Both lie in
    the body, which the head does not vouch for: :func:`check_payload` checks them in every payload."""

    def read(self, data: bytes | memoryview | pa.Buffer) -> pa.RecordBatch:
        """The record batch of a payload that :func:`check_payload` accepted with this layout."""
        buffer = data if isinstance(data, pa.Buffer) else pa.py_buffer(data)
        if not self.schema_length:  # a stream without continuation markers (Arrow < 0.15 format)
            return pa.ipc.open_stream(buffer).read_next_batch()
        return pa.ipc.read_record_batch(buffer.slice(self.schema_length), self.schema)

    def start_time(self, data: bytes | memoryview) -> float | None:
        """``t`` of the first row, s, read from the body (no batch built); None without it."""
        return None if self.first_t is None else F64(data, self.first_t)[0]

    def end_time(self, data: bytes | memoryview) -> float | None:
        """``t`` of the last row, s, read from the body (no batch built); None without it."""
        return None if self.first_t is None else F64(data, self.first_t + 8 * (self.rows - 1))[0]


def check_payload(data: bytes | memoryview | pa.Buffer, expected: pa.Schema, source: str | None = None) -> Layout:
    """Validate one message like :func:`decode_batch` does, without building the record batch.

    A payload whose head and size equal those of one validated before is accepted on a dictionary
    lookup (~1 µs); otherwise it is decoded and checked (see :func:`decode_batch`). Read the batch
    later, if at all, with :meth:`Layout.read`. Raises what :func:`decode_batch` raises.
    """
    return _check(data, expected, source)[0]


def decode_batch(
    data: bytes | memoryview | pa.Buffer, expected: pa.Schema, source: str | None = None
) -> pa.RecordBatch:
    """Decode one message and check it against ``expected``.

    Three levels, same checks: a payload whose head (everything before the body) and size match a
    validated one only needs its batch read; one whose schema message matches a validated one is
    read and its required fields' null counts checked; any other is read and validated in full.

    Parameters
    ----------
    data : bytes
        Payload made by :func:`encode_batch`.
    expected : pyarrow.Schema
        A schema of :mod:`hydrowatch.schemas` (name and version are compared).
    source : str, optional
        Where the message came from (file and message number, or key expression) for errors.

    Raises
    ------
    UndecodableMessageError
        The payload is not an Arrow IPC stream with a record batch (garbage, truncated).
    SchemaMismatchError
        It is Arrow, but of another schema or without hydrowatch schema metadata.
    SchemaVersionError
        It is the expected schema at another version.
    DataError
        Right schema and version but a field is missing, mistyped or null where it must not be.
    """
    layout, batch = _check(data, expected, source)
    if batch is not None:
        return batch
    try:
        return layout.read(data)
    except _READ_ERRORS as exc:
        raise _undecodable(pa.py_buffer(data), exc, source) from None


def _check(
    data: bytes | memoryview | pa.Buffer, expected: pa.Schema, source: str | None
) -> tuple[Layout, pa.RecordBatch | None]:
    """The layout of a valid payload, and its batch when checking it had to read it."""
    found = head(data)
    layout = None if found is None else _LAYOUTS.get(found)
    size = data.size if isinstance(data, pa.Buffer) else len(data)
    if layout is not None and layout.expected is expected and layout.size == size:
        if layout.strings and not strings_ok(data, layout.rows, layout.strings):
            raise UndecodableMessageError(
                f"message string columns must hold valid offsets and UTF-8. Got {size} bytes that do not.", source)
        return layout, None
    buffer = data if isinstance(data, pa.Buffer) else pa.py_buffer(data)
    prefix = schema_message(data)
    known = None if prefix is None else _DECODE_CACHE.get((prefix, id(expected)))
    if prefix is None or known is None or known.expected is not expected:
        batch = _decode_in_full(buffer, prefix, expected, source)
    else:
        try:
            batch = pa.ipc.read_record_batch(buffer.slice(len(prefix)), known.schema)
        except _READ_ERRORS as exc:
            raise _undecodable(buffer, exc, source) from None
        nulls_found = required_null_counts(data, len(prefix), batch, known.required, known.flat)
        for index, nulls in zip(known.required, nulls_found):
            if nulls:
                name = known.schema.names[index]
                raise DataError(f"{schema_name(expected)} field '{name}' must have no nulls. Got {nulls}.", source)
        _validate_body(batch, buffer, source)
    layout = Layout(expected, batch.schema, len(prefix or b""), size, None, batch.num_rows)
    strings = string_buffers(data, len(prefix or b""), len(found or b""), batch)
    if found is not None and prefix is not None and strings is not None:
        layout = layout._replace(first_t=first_t_offset(data, len(prefix), len(found), batch), strings=strings)
        if len(_LAYOUTS) >= _LAYOUT_CACHE_SIZE:
            _LAYOUTS.clear()
        _LAYOUTS[found] = layout
    return layout, batch


def _validate_body(batch: pa.RecordBatch, buffer: pa.Buffer, source: str | None) -> None:
    """Check what reading a batch does not: that every buffer is as large as the batch says, string offsets stay
    inside their data and strings are UTF-8 (else reading a value reads memory outside the message)."""
    full = any(not pa.types.is_primitive(f.type) for f in batch.schema)
    try:
        batch.validate(full=full)
    except (*_READ_ERRORS, UnicodeDecodeError) as exc:
        raise _undecodable(buffer, exc, source) from None


class _KnownSchema(NamedTuple):
    """A schema message that passed full validation against ``expected``."""

    expected: pa.Schema
    schema: pa.Schema
    required: tuple[int, ...]
    """Column indexes of the fields that must hold no nulls."""
    flat: bool
    """No nested types: field node i is column i."""


def _undecodable(buffer: pa.Buffer, exc: BaseException, source: str | None) -> UndecodableMessageError:
    reason = str(exc).splitlines()[0] if str(exc) else "no record batch"
    return UndecodableMessageError(
        f"message must be an Arrow IPC stream with one record batch. Got {buffer.size} bytes that are not ({reason}).",
        source,
    )


def _decode_in_full(
    buffer: pa.Buffer, prefix: bytes | None, expected: pa.Schema, source: str | None
) -> pa.RecordBatch:
    """Read the stream and validate every field; remember the schema message when it passes."""
    try:
        reader = pa.ipc.open_stream(buffer)
        batch = reader.read_next_batch()
        # names and metadata are decoded as UTF-8 when read: corrupted bytes there are a corrupted message
        validate(batch, expected, source, require_metadata=True)
    except (*_READ_ERRORS, StopIteration, UnicodeDecodeError) as exc:
        raise _undecodable(buffer, exc, source) from None
    _validate_body(batch, buffer, source)
    if prefix is not None:
        if len(_DECODE_CACHE) >= _CACHE_SIZE:
            _DECODE_CACHE.clear()
        names = batch.schema.names
        required = tuple(names.index(f.name) for f in expected if not f.nullable and f.name in names)
        flat = all(f.type.num_fields == 0 for f in batch.schema)
        _DECODE_CACHE[(prefix, id(expected))] = _KnownSchema(expected, batch.schema, required, flat)
    return batch


__all__ = [
    "LABEL_FIELD",
    "Layout",
    "SchemaMismatchError",
    "SchemaVersionError",
    "UndecodableMessageError",
    "arrays_from_sensor_chunk",
    "check_payload",
    "decode_batch",
    "encode_batch",
    "sensor_chunk_from_arrays",
]
