"""Arrow encoding of bus and MCAP messages: one message = one Arrow IPC stream (schema + one batch).

The IPC stream carries the schema with its metadata (``hydrowatch.schema``,
``hydrowatch.schema_version``, field units), so a subscriber can tell garbage, another schema and
another version apart (:class:`UndecodableMessageError`, :class:`SchemaMismatchError`,
:class:`SchemaVersionError`, all :class:`DataError`), and any Arrow library in any language can read
a message without hydrowatch. The price is the schema bytes in every message; the trade-off is
measured in ``benchmarks/bench_io_codec.py`` and written down in ``docs/formats.md``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pyarrow as pa

from hydrowatch.errors import DataError
from hydrowatch.schemas import (
    SENSOR_CHUNK,
    SchemaMismatchError,
    SchemaVersionError,
    validate,
    wire_schema,
)

LABEL_FIELD = "state"
"""Optional per-sample health label column of a sensor chunk."""


_WIRE = wire_schema(SENSOR_CHUNK)


class UndecodableMessageError(DataError):
    """A payload that is not an Arrow IPC stream holding a record batch."""


def encode_batch(batch: pa.RecordBatch) -> bytes:
    """Serialise one record batch as an Arrow IPC stream (schema message, batch, end marker).

    Parameters
    ----------
    batch : pyarrow.RecordBatch
        A message built against a schema of :mod:`hydrowatch.schemas` (its metadata travels along).

    Returns
    -------
    bytes
        The payload to publish on the bus or store in an MCAP message.
    """
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, batch.schema) as writer:
        writer.write_batch(batch)
    return sink.getvalue().to_pybytes()


def decode_batch(
    data: bytes | memoryview | pa.Buffer, expected: pa.Schema, source: str | None = None
) -> pa.RecordBatch:
    """Decode one message and check it against ``expected``.

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
    try:
        reader = pa.ipc.open_stream(pa.py_buffer(data))
        batch = reader.read_next_batch()
    except (pa.ArrowInvalid, pa.ArrowIOError, StopIteration, OSError) as exc:
        size = len(data) if not isinstance(data, pa.Buffer) else data.size
        reason = str(exc).splitlines()[0] if str(exc) else "no record batch"
        raise UndecodableMessageError(
            f"message must be an Arrow IPC stream with one record batch. Got {size} bytes that are not ({reason}).",
            source,
        ) from None
    validate(batch, expected, source, require_metadata=True)
    return batch


def sensor_chunk_from_arrays(t: np.ndarray, channels: Mapping[str, np.ndarray]) -> pa.RecordBatch:
    """Build a ``sensor_chunk`` message from sample arrays.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Sample times, s.
    channels : mapping of str to ndarray, shape (n,)
        ``voltage`` [V], ``flow`` [L/min], ``speed`` [rad/s], ``torque`` [N·m], optionally
        ``supply_pressure``/``load_pressure`` [bar], ``temperature`` [°C] and ``state`` (labels, str).

    Returns
    -------
    pyarrow.RecordBatch
        Columns in schema order, absent optional columns left out, schema metadata attached.
    """
    columns = {"t": t, **channels}
    unknown = sorted(set(columns) - set(SENSOR_CHUNK.names))
    if unknown:
        raise DataError(f"sensor chunk channels must be among {SENSOR_CHUNK.names[1:]}. Got unknown {unknown}.")
    fields, arrays = [], []
    for field in _WIRE:
        if field.name not in columns:
            if not field.nullable:
                raise DataError(f"sensor chunk channel '{field.name}' must be given. Got {sorted(columns)}.")
            continue
        values = columns[field.name]
        if field.name == LABEL_FIELD:
            arrays.append(pa.array(np.asarray(values, dtype=object), type=pa.string()))
        else:
            arrays.append(pa.array(np.asarray(values, dtype=np.float64)))
        fields.append(field)
    return pa.RecordBatch.from_arrays(arrays, schema=pa.schema(fields, metadata=_WIRE.metadata))


def arrays_from_sensor_chunk(batch: pa.RecordBatch) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Sample arrays of a ``sensor_chunk`` message (inverse of :func:`sensor_chunk_from_arrays`).

    Returns
    -------
    t : ndarray, shape (n,)
        Sample times, s, float64.
    channels : dict of str to ndarray, shape (n,)
        Every other column: float64 (nulls become NaN), ``state`` as an object array of str.
    """
    t = batch.column("t").to_numpy(zero_copy_only=False)
    channels: dict[str, np.ndarray] = {}
    for name, column in zip(batch.schema.names, batch.columns):
        if name == "t":
            continue
        if name == LABEL_FIELD:
            channels[name] = np.asarray(column.to_pylist(), dtype=object)
        else:
            channels[name] = column.to_numpy(zero_copy_only=False).astype(np.float64, copy=False)
    return t, channels


__all__ = [
    "LABEL_FIELD",
    "SchemaMismatchError",
    "SchemaVersionError",
    "UndecodableMessageError",
    "arrays_from_sensor_chunk",
    "decode_batch",
    "encode_batch",
    "sensor_chunk_from_arrays",
]
