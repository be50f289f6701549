"""Import of the long layout through a rig description: one CSV/Parquet table, a time column and a
column per channel, cut into the description's windows.

Each channel is read from its ``source`` column (the rename), scaled (``scale * raw + offset``),
resampled onto the window grid by block means (:func:`hydrowatch.io.wide.block_means`) and cut
into windows of ``length_s`` every ``hop_s`` (a ``cycle`` window: back to back). A label whose
``column`` is not set is read per row from the column named like the label; a window whose rows
carry more than one value of it is left out (counted in :attr:`Windows.mixed`).

Refused, naming file, column and row (from 0): a missing time or required channel column, a
non-numeric or empty cell, a time base that is not 1/``rate_hz`` apart, a label outside its
declared values, channels of one table declared at different rates, a CSV header unit other than
the description's, a table shorter than one window.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from hydrowatch.errors import DataError
from hydrowatch.io.checks import UNIT_ALIASES, check_time_base
from hydrowatch.io.tabular import as_float
from hydrowatch.io.wide import Cycles, block_means
from hydrowatch.rig.description import Label, RigDescription

_HEADER = re.compile(r"^\s*(?P<name>[^\[\]]+?)\s*(\[(?P<unit>[^\]]*)\])?\s*$")


@dataclass(frozen=True)
class Windows(Cycles):
    """Windows of a long table: :class:`Cycles` plus where each window starts.

    Attributes
    ----------
    start_s : ndarray, shape (n_windows,)
        Time of each window's first sample, s (the table's time column).
    mixed : int
        Windows left out because a per-row label changed inside them.
    """

    start_s: np.ndarray
    mixed: int


def _read_table(path: Path, rig: RigDescription) -> pa.Table:
    """The table with CSV header units stripped from the names; a declared unit other than the
    description's (CSV ``name [unit]``, Parquet field metadata ``unit``) is refused."""
    source = str(path)
    try:
        if path.suffix == ".parquet":
            table = pq.read_table(path)
            declared = [(f.name, (f.metadata or {}).get(b"unit", b"").decode() or None) for f in table.schema]
        elif path.suffix == ".csv":
            table = pa_csv.read_csv(path)
            matches = [(raw, _HEADER.match(raw)) for raw in table.column_names]
            declared = [(m["name"], m["unit"]) if m else (raw, None) for raw, m in matches]
        else:
            raise DataError(f"table file suffix must be .csv or .parquet. Got {path.suffix!r}.", source)
    except (OSError, pa.ArrowInvalid) as exc:
        raise DataError(f"file must be a readable table. Got: {str(exc).splitlines()[0]}.", source) from None
    units = {rig.sampling[channel.name].source: channel.unit for channel in rig.channels}
    for name, unit in declared:
        expected = units.get(name)
        if unit is not None and expected is not None and unit.strip() not in UNIT_ALIASES.get(expected, {expected}):
            raise DataError(
                f"column '{name}' must be in {expected} (the rig description's unit). Got [{unit}]. "
                "Convert it, or declare the unit and a scale in the description.",
                source,
            )
    return table.rename_columns([name for name, _ in declared])


def _labels(table: pa.Table, label: Label, source: str) -> np.ndarray:
    column = table.column(label.name)
    if column.null_count:
        row = next(r for r, v in enumerate(column.to_pylist()) if v is None)
        raise DataError(f"column '{label.name}' must have a label in every row. Got an empty one in row {row}.", source)
    numeric = not isinstance(label.values[0], str)
    values = as_float(label.name, column, source) if numeric else np.asarray(column.cast(pa.string()).to_pylist())
    allowed = np.asarray(label.values, dtype=values.dtype)
    bad = np.flatnonzero(~np.isin(values, allowed))
    if bad.size:
        raise DataError(
            f"row {int(bad[0])}, column '{label.name}' must be one of {list(label.values)}. Got {values[bad[0]]!r}. "
            "Declare the value in the description or fix the file.",
            source,
        )
    return values


def read_windows(path: str | Path, rig: RigDescription) -> Windows:
    """Read a long CSV/Parquet table through ``rig`` and cut it into the rig's windows."""
    path = Path(path)
    source = str(path)
    if rig.layout != "long":
        raise DataError(
            f"layout must be 'long' to read a table with a time column. Got {rig.layout!r} for rig {rig.name!r}.",
            source,
        )
    rates = {rig.sampling[c].rate_hz for c in rig.channels.names}
    if len(rates) != 1:
        raise DataError(
            f"channels of one long table must share one rate_hz. Got {sorted(rates)} in rig {rig.name!r}.", source
        )
    rate = rates.pop()
    table = _read_table(path, rig)
    if rig.time_column not in table.column_names:
        raise DataError(
            f"column '{rig.time_column}' [s] must be present (the rig's time column). Got {table.column_names}.", source
        )
    t = as_float(rig.time_column, table.column(rig.time_column), source)
    check_time_base(t, source, rate, rig.time_column)
    names, values = [], []
    for channel in rig.channels:
        sampling = rig.sampling[channel.name]
        if sampling.source not in table.column_names:
            if channel.optional:
                continue
            raise DataError(
                f"column '{sampling.source}' (channel '{channel.name}') must be present. Got "
                f"{table.column_names}. Add it or rename it with the description's 'source'.",
                source,
            )
        raw = as_float(sampling.source, table.column(sampling.source), source)
        empty = np.flatnonzero(~np.isfinite(raw))
        if empty.size:
            raise DataError(
                f"row {int(empty[0])}, column '{sampling.source}' must be a finite number. Got {raw[empty[0]]}.", source
            )
        names.append(channel.name)
        values.append(sampling.scale * raw + sampling.offset)
    labels = {
        label.name: _labels(table, label, source)
        for label in rig.labels
        if label.column is None and label.name in table.column_names
    }
    return _cut(np.stack(values), t, labels, rig, rate, tuple(names), source)


def _cut(
    values: np.ndarray,
    t: np.ndarray,
    labels: dict[str, np.ndarray],
    rig: RigDescription,
    rate: float,
    names: tuple[str, ...],
    source: str,
) -> Windows:
    """Block-average (channels, rows) onto the grid and cut windows; keep those with one label each."""
    factor = round(rate / rig.window.grid_hz)
    usable = (values.shape[1] // factor) * factor
    grid = block_means(values[:, :usable], rate, rig.window.grid_hz)
    length = rig.window.samples
    hop = round(rig.window.hop_s * rig.window.grid_hz)
    if grid.shape[1] < length:
        raise DataError(
            f"table must hold at least one window of {rig.window.length_s:g} s. Got {values.shape[1] / rate:g} s.",
            source,
        )
    starts = np.arange(0, grid.shape[1] - length + 1, hop)
    keep: list[int] = []
    window_labels: dict[str, list[object]] = {name: [] for name in labels}
    for start in starts:
        rows = slice(start * factor, (start + length) * factor)
        parts = {name: np.unique(column[rows]) for name, column in labels.items()}
        if all(p.size == 1 for p in parts.values()):
            keep.append(start)
            for name, p in parts.items():
                window_labels[name].append(p[0])
    windows = np.stack([grid[:, s : s + length] for s in keep]) if keep else np.zeros((0, len(names), length))
    return Windows(
        values=windows,
        channels=names,
        labels={n: np.asarray(v) for n, v in window_labels.items()},
        grid_hz=rig.window.grid_hz,
        source=source,
        start_s=t[np.asarray(keep, dtype=int) * factor],
        mixed=len(starts) - len(keep),
    )
