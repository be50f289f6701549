"""Arrow encoding of bus and MCAP messages: one message = one Arrow IPC stream (schema + one batch).

The IPC stream carries the schema with its metadata (``hydrowatch.schema``,
``hydrowatch.schema_version``, field units), so a subscriber can tell garbage, another schema and
another version apart (:class:`UndecodableMessageError`, :class:`SchemaMismatchError`,
:class:`SchemaVersionError`, all :class:`DataError`), and any Arrow library in any language can read
a message without hydrowatch. The price is the schema bytes in every message; the trade-off is
measured in ``benchmarks/bench_io_codec.py`` and written down in ``docs/formats.md``.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable
from typing import NamedTuple

import pyarrow as pa

from hydrowatch.errors import DataError
from hydrowatch.io.sensor_chunk import LABEL_FIELD, arrays_from_sensor_chunk, sensor_chunk_from_arrays
from hydrowatch.schemas import SchemaMismatchError, SchemaVersionError, schema_name, validate

_FRAME = struct.Struct("<Ii")
_CONTINUATION = 0xFFFFFFFF
_END_OF_STREAM = _FRAME.pack(_CONTINUATION, 0)
_U16 = struct.Struct("<H").unpack_from
_I32 = struct.Struct("<i").unpack_from
_U32 = struct.Struct("<I").unpack_from
_I64 = struct.Struct("<q").unpack_from
_F64 = struct.Struct("<d").unpack_from
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
    return b"".join((prefix, batch.serialize(), _END_OF_STREAM))  # join reads the Arrow buffer in place


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
    if stream != b"".join((prefix, batch.serialize().to_pybytes(), _END_OF_STREAM)):
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
        return None if self.first_t is None else _F64(data, self.first_t)[0]

    def end_time(self, data: bytes | memoryview) -> float | None:
        """``t`` of the last row, s, read from the body (no batch built); None without it."""
        return None if self.first_t is None else _F64(data, self.first_t + 8 * (self.rows - 1))[0]


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
    head = _head(data)
    layout = None if head is None else _LAYOUTS.get(head)
    size = data.size if isinstance(data, pa.Buffer) else len(data)
    if layout is not None and layout.expected is expected and layout.size == size:
        if layout.strings and not _strings_ok(data, layout):
            raise UndecodableMessageError(
                f"message string columns must hold valid offsets and UTF-8. Got {size} bytes that do not.", source)
        return layout, None
    buffer = data if isinstance(data, pa.Buffer) else pa.py_buffer(data)
    prefix = _schema_message(data)
    known = None if prefix is None else _DECODE_CACHE.get((prefix, id(expected)))
    if prefix is None or known is None or known.expected is not expected:
        batch = _decode_in_full(buffer, prefix, expected, source)
    else:
        try:
            batch = pa.ipc.read_record_batch(buffer.slice(len(prefix)), known.schema)
        except _READ_ERRORS as exc:
            raise _undecodable(buffer, exc, source) from None
        for index, nulls in zip(known.required, _required_null_counts(data, len(prefix), batch, known)):
            if nulls:
                name = known.schema.names[index]
                raise DataError(f"{schema_name(expected)} field '{name}' must have no nulls. Got {nulls}.", source)
        _validate_body(batch, buffer, source)
    layout = Layout(expected, batch.schema, len(prefix or b""), size, None, batch.num_rows)
    strings = _string_buffers(data, len(prefix or b""), len(head or b""), batch)
    if head is not None and prefix is not None and strings is not None:
        layout = layout._replace(first_t=_first_t(data, len(prefix), len(head), batch), strings=strings)
        if len(_LAYOUTS) >= _LAYOUT_CACHE_SIZE:
            _LAYOUTS.clear()
        _LAYOUTS[head] = layout
    return layout, batch


def _head(data: bytes | memoryview | pa.Buffer) -> bytes | None:
    """Schema message + batch message metadata (everything before the body) as bytes; None if unframed."""
    try:
        marker, length = _FRAME.unpack_from(data, 0)
        start = 8 + length
        marker2, length2 = _FRAME.unpack_from(data, start)
    except struct.error:
        return None
    if marker != _CONTINUATION or marker2 != _CONTINUATION or length <= 0 or length2 <= 0:
        return None
    view = memoryview(data)
    end = start + 8 + length2
    return bytes(view[:end]) if end <= view.nbytes else None


def _validate_body(batch: pa.RecordBatch, buffer: pa.Buffer, source: str | None) -> None:
    """Check what reading a batch does not: that every buffer is as large as the batch says, string offsets stay
    inside their data and strings are UTF-8 (else reading a value reads memory outside the message)."""
    full = any(not pa.types.is_primitive(f.type) for f in batch.schema)
    try:
        batch.validate(full=full)
    except (*_READ_ERRORS, UnicodeDecodeError) as exc:
        raise _undecodable(buffer, exc, source) from None


def _string_buffers(
    data: bytes | memoryview | pa.Buffer, start: int, body: int, batch: pa.RecordBatch
) -> tuple[tuple[int, int, int], ...] | None:
    """Where each string column's offsets and data lie in the payload (:attr:`Layout.strings`); None when they
    cannot be located (nested types, a buffer count that does not add up): such a layout is not remembered."""
    kinds = [3 if pa.types.is_string(f.type) else 2 for f in batch.schema]  # buffers: validity, (offsets,) data
    if not batch.num_rows or 3 not in kinds:
        return ()
    if not all(pa.types.is_string(f.type) or pa.types.is_primitive(f.type) for f in batch.schema):
        return None
    try:
        buffers = _buffers_vector(data, start)
        if not buffers or _U32(data, buffers)[0] != sum(kinds):
            return None
        found, index = [], 0
        for kind in kinds:
            if kind == 3:
                offsets, values = (buffers + 4 + 16 * (index + k) for k in (1, 2))
                found.append((body + _I64(data, offsets)[0], body + _I64(data, values)[0], _I64(data, values + 8)[0]))
            index += kind
    except struct.error:
        return None
    return tuple(found)


def _strings_ok(data: bytes | memoryview | pa.Buffer, layout: Layout) -> bool:
    """Whether every string column of a payload with a known head has offsets inside its data, in order, each at
    the start of a UTF-8 character, and UTF-8 data (what :func:`_validate_body` checks, ~1 µs for 20 rows)."""
    view = memoryview(data)
    read = _offsets(layout.rows + 1)
    for offsets_at, values_at, length in layout.strings:
        offsets = list(read(view, offsets_at))
        first, last = offsets[0], offsets[-1]
        if first < 0 or last > length or offsets != sorted(offsets):
            return False
        try:
            text = str(view[values_at + first : values_at + last], "utf-8")
        except UnicodeDecodeError:
            return False
        if not text.isascii() and any(view[values_at + o] & 0xC0 == 0x80 for o in offsets[1:-1] if o < last):
            return False  # a value would begin inside a character
    return True


@functools.lru_cache(maxsize=64)
def _offsets(count: int) -> Callable[[memoryview, int], tuple[int, ...]]:
    """Reader of ``count`` int32 string offsets."""
    return struct.Struct(f"<{count}i").unpack_from


def _buffers_vector(data: bytes | memoryview | pa.Buffer, start: int) -> int:
    """Position of the batch message's ``RecordBatch.buffers`` vector (its length, then ``Buffer{offset, length}``
    pairs of int64 relative to the body) in a payload whose batch message starts at ``start``; 0 when absent.
    Raises ``struct.error`` past the end of the payload."""
    fb = start + 8
    root = fb + _U32(data, fb)[0]
    header = _table_field(data, root, 2)  # Message.header: the RecordBatch table
    if not header:
        return 0
    table = header + _U32(data, header)[0]
    buffers_at = _table_field(data, table, 2)
    return buffers_at + _U32(data, buffers_at)[0] if buffers_at else 0


def _first_t(data: bytes | memoryview | pa.Buffer, start: int, body: int, batch: pa.RecordBatch) -> int | None:
    """Byte offset of ``t``'s first value when ``t`` is the first column, float64, without a validity
    buffer (checked against the batch read the slow way); else None."""
    if not batch.num_rows or batch.schema.names[:1] != ["t"] or batch.schema.field(0).type != pa.float64():
        return None
    try:
        buffers = _buffers_vector(data, start)
        offset = body + _I64(data, buffers + 4 + 16)[0]  # buffer 1: the data of column 0
        ok = buffers and _F64(data, offset)[0] == batch.column(0)[0].as_py()
    except struct.error:
        return None
    return offset if ok and batch.column(0).null_count == 0 else None


def _required_null_counts(
    data: bytes | memoryview | pa.Buffer, start: int, batch: pa.RecordBatch, known: _KnownSchema
) -> list[int]:
    """Null counts of the required columns, read from the batch message's field nodes (a flatbuffer
    Arrow has already verified; ~1.6 µs instead of ~5.7 µs through the columns) when the schema is
    flat, else from the columns."""
    if known.flat:
        try:
            fb = start + 8  # after the continuation marker and the metadata length
            root = fb + _U32(data, fb)[0]
            header = _table_field(data, root, 2)  # Message.header: the RecordBatch table
            table = header + _U32(data, header)[0]
            nodes_at = _table_field(data, table, 1)  # RecordBatch.nodes: [FieldNode{length, null_count}]
            nodes = nodes_at + _U32(data, nodes_at)[0]
            if header and nodes_at and _U32(data, nodes)[0] == len(known.schema):
                return [_I64(data, nodes + 12 + 16 * i)[0] for i in known.required]
        except struct.error:
            pass
    return [batch.column(i).null_count for i in known.required]


def _table_field(data: bytes | memoryview | pa.Buffer, table: int, index: int) -> int:
    """Position of field ``index`` of the flatbuffer table at ``table`` (0 when absent)."""
    vtable = table - _I32(data, table)[0]
    slot = 4 + 2 * index
    if slot >= _U16(data, vtable)[0]:
        return 0
    offset = _U16(data, vtable + slot)[0]
    return table + offset if offset else 0


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


def _schema_message(data: bytes | memoryview | pa.Buffer) -> bytes | None:
    """The stream's first message (continuation marker, length, flatbuffer) as bytes; None if unframed."""
    try:
        marker, length = _FRAME.unpack_from(data, 0)
    except struct.error:
        return None
    view = memoryview(data)
    if marker != _CONTINUATION or not 0 < length <= view.nbytes - 8:
        return None
    return bytes(view[: 8 + length])


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
