"""Parquet and CSV tables of samples: columns ``t`` [s], the channels and an optional ``state``.

Reading turns a file into plain arrays and checks types and declared units; the checks on values
(time base, NaN, labels) are :mod:`hydrowatch.io.checks`, shared with MCAP. Units are declared in a
CSV header as ``flow [L/min]`` (optional) and in Parquet as field metadata ``unit`` (optional).
Recording metadata travels in Parquet schema metadata ``hydrowatch.recording`` (JSON).
"""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from hydrowatch.errors import DataError
from hydrowatch.io.checks import check_unit
from hydrowatch.io.codec import LABEL_FIELD, sensor_chunk_from_arrays
from hydrowatch.log import event, get_logger
from hydrowatch.recording import UNITS

META_KEY = b"hydrowatch.recording"
"""Parquet schema metadata key holding the recording metadata as JSON."""

_HEADER = re.compile(r"^\s*(?P<name>[^\[\]]+?)\s*(\[(?P<unit>[^\]]*)\])?\s*$")
_log = get_logger(__name__)


@dataclass
class Table:
    """Columns of a tabular file, types checked, values not yet.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times, s (NaN where empty).
    channels : dict of str to ndarray, shape (n,)
        Known channel columns as float64 (NaN where empty).
    labels : ndarray of str, shape (n,), or None
        The ``state`` column when present.
    meta : dict
        Recording metadata stored in the file (Parquet only), else empty.
    """

    t: np.ndarray
    channels: dict[str, np.ndarray]
    labels: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)


def _first_non_number(column: pa.ChunkedArray) -> tuple[int, Any]:
    for row, value in enumerate(column.to_pylist()):
        if value is None:
            continue
        try:
            float(value)
        except (TypeError, ValueError):
            return row, value
    return -1, None


def as_float(name: str, column: pa.ChunkedArray, source: str) -> np.ndarray:
    """A column as float64 (NaN where empty); a non-numeric cell is refused naming column and row."""
    if pa.types.is_null(column.type):
        return np.full(len(column), np.nan)
    if pa.types.is_floating(column.type) or pa.types.is_integer(column.type):
        return column.cast(pa.float64()).to_numpy().astype(np.float64, copy=False)
    if pa.types.is_string(column.type) or pa.types.is_large_string(column.type):
        row, value = _first_non_number(column)
        if row < 0:
            return np.asarray([np.nan if v is None else float(v) for v in column.to_pylist()], dtype=np.float64)
        raise DataError(f"column '{name}' must be numeric. Got {value!r} in row {row}.", source)
    raise DataError(f"column '{name}' must be numeric. Got type {column.type}.", source)


def table_from_arrow(table: pa.Table, column_units: Mapping[str, str | None], source: str) -> Table:
    """Split an Arrow table into time, channels and labels; check types and units."""
    unknown = [n for n in table.column_names if n not in UNITS and n != LABEL_FIELD]
    if unknown:
        event(_log, "ignoring unknown columns", source=source, columns=",".join(unknown))
    if len(set(table.column_names)) != len(table.column_names):
        raise DataError(f"column names must be unique. Got {table.column_names}.", source)
    for name, unit in column_units.items():
        check_unit(name, unit, source)
    if "t" not in table.column_names:
        raise DataError("column 't' [s] must be present. Got none. Add the sample times in seconds.", source)
    channels = {
        name: as_float(name, table.column(name), source)
        for name in table.column_names
        if name in UNITS and name != "t"
    }
    labels = None
    if LABEL_FIELD in table.column_names:
        column = table.column(LABEL_FIELD)
        if column.null_count:
            raise DataError(
                f"column '{LABEL_FIELD}' must have a label in every row. Got {column.null_count} empty.", source
            )
        labels = np.asarray(column.cast(pa.string()).to_pylist(), dtype=object)
    return Table(as_float("t", table.column("t"), source), channels, labels)


def read_csv(path: str | Path) -> Table:
    """Read a CSV file (header row; ``name`` or ``name [unit]`` per column)."""
    source = str(path)
    try:
        with open(path, encoding="utf-8") as f:
            header = f.readline().rstrip("\r\n")
        table = pa_csv.read_csv(path)
    except (OSError, UnicodeDecodeError, pa.ArrowInvalid) as exc:
        raise DataError(
            f"file must be a readable CSV with a header row. Got: {str(exc).splitlines()[0]}.", source
        ) from None
    names, units = [], {}
    for raw in next(csv.reader([header])):
        match = _HEADER.match(raw)
        name = match["name"] if match else raw
        names.append(name)
        units[name] = match["unit"] if match else None
    if len(names) != table.num_columns:
        raise DataError(
            f"header must name every column. Got {len(names)} names for {table.num_columns} columns.", source
        )
    return table_from_arrow(table.rename_columns(names), units, source)


def read_parquet(path: str | Path) -> Table:
    """Read a Parquet file; units from field metadata, recording metadata from schema metadata."""
    source = str(path)
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowInvalid) as exc:
        raise DataError(f"file must be a readable Parquet file. Got: {str(exc).splitlines()[0]}.", source) from None
    units = {f.name: (f.metadata or {}).get(b"unit", b"").decode() or None for f in table.schema}
    out = table_from_arrow(table, units, source)
    raw = (table.schema.metadata or {}).get(META_KEY)
    if raw is not None:
        try:
            out.meta = json.loads(raw)
        except json.JSONDecodeError:
            raise DataError(f"schema metadata '{META_KEY.decode()}' must be JSON. Got {raw[:60]!r}.", source) from None
    return out


def to_arrow(t: np.ndarray, channels: Mapping[str, np.ndarray], labels: np.ndarray | None) -> pa.Table:
    """Arrow table with the sensor chunk schema (units in field metadata), labels as ``state``."""
    columns = dict(channels)
    if labels is not None:
        columns[LABEL_FIELD] = labels
    return pa.Table.from_batches([sensor_chunk_from_arrays(t, columns)])


def write_table(
    path: str | Path,
    t: np.ndarray,
    channels: Mapping[str, np.ndarray],
    labels: np.ndarray | None,
    meta: Mapping[str, Any],
) -> None:
    """Write samples as Parquet or CSV (by suffix). Parquet keeps ``meta`` (JSON) and units.

    CSV gets a plain header (contract column names, no units) so any tool can read it back.
    """
    path = Path(path)
    table = to_arrow(t, channels, labels)
    if path.suffix == ".parquet":
        metadata = dict(table.schema.metadata or {})
        metadata[META_KEY] = json.dumps(dict(meta), default=str).encode()
        pq.write_table(table.replace_schema_metadata(metadata), path, compression="zstd")
    elif path.suffix == ".csv":
        pa_csv.write_csv(table, path)
    else:
        raise DataError(f"table file suffix must be .parquet or .csv. Got {path.suffix!r}.", str(path))


__all__ = ["META_KEY", "Table", "as_float", "read_csv", "read_parquet", "to_arrow", "write_table"]
