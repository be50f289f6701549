"""The ``sensor_chunk`` message and numpy sample arrays, both ways (the wire format: :mod:`hydrowatch.io.codec`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pyarrow as pa

from hydrowatch.errors import DataError
from hydrowatch.schemas import SENSOR_CHUNK, may_be_absent, one_or_more_of, wire_schema

LABEL_FIELD = "state"
"""Optional per-sample health label column of a sensor chunk."""

_WIRE = wire_schema(SENSOR_CHUNK)
_ONE_OR_MORE = one_or_more_of(SENSOR_CHUNK)
_REQUIRED = frozenset(f.name for f in SENSOR_CHUNK if not may_be_absent(f))


def sensor_chunk_from_arrays(t: np.ndarray, channels: Mapping[str, np.ndarray]) -> pa.RecordBatch:
    """Build a ``sensor_chunk`` message from sample arrays.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Sample times, s.
    channels : mapping of str to ndarray, shape (n,)
        ``voltage`` [V], at least one of ``flow`` [L/min], ``speed`` [rad/s], ``torque`` [N·m], optionally
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
    if _ONE_OR_MORE and not any(c in columns for c in _ONE_OR_MORE):
        raise DataError(f"sensor chunk must have at least one of the sensors {list(_ONE_OR_MORE)}. Got "
                        f"{sorted(columns)}.")
    fields, arrays = [], []
    for field in _WIRE:
        if field.name not in columns:
            if field.name in _REQUIRED:
                raise DataError(f"sensor chunk channel '{field.name}' must be given. Got {sorted(columns)}.")
            continue
        values = columns[field.name]
        if field.name == LABEL_FIELD:
            # a list converts ~70x faster than a numpy object array (pyarrow 25)
            arrays.append(pa.array(list(values), type=pa.string()))
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
