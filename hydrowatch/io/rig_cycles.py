"""A rig's cycles as messages and recordings: ``rig_cycles`` on the bus and in MCAP (docs/rigs.md, issue 17).

A rig that is not the project's plant has its own channels, rates and windows, so its data travels as whole
cycles (or windows) on the description's grid rather than as ``sensor_chunk`` samples: one ``rig_cycles`` message
holds some cycles of one machine, one row per cycle (``schemas/rig_cycles.v1.json``). ``hydrowatch import --rig``
writes them to an MCAP file on ``hydro/<fleet>/<machine>/cycles`` whose ``hydrowatch`` metadata record keeps the
description's TOML text, so the file reads back without the description; the scorer judges them off the bus.

:func:`read_rig_data` is the one reader of a rig's data for every command: a folder of per-cycle files (wide
layout), a CSV/Parquet table (long layout) or such an MCAP file.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pyarrow as pa

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.io.long_table import Windows, read_windows
from hydrowatch.io.mcap_io import METADATA_NAME, McapWriter, Recovery, iter_messages, topic
from hydrowatch.io.wide import Cycles, read_cycles
from hydrowatch.rig.description import Label, LabelValue, RigDescription, label_text, rig_from_text
from hydrowatch.schemas import RIG_CYCLES, current_version, wire_schema

CYCLES_PER_MESSAGE = 16
"""Cycles per ``rig_cycles`` message that ``import --rig`` writes (a UCI cycle of 17 channels × 60 s is 8 kB)."""
RIG_TEXT_KEY = "rig_description"
"""Key of the ``hydrowatch`` metadata record that holds the description's TOML text."""


def start_times(cycles: Cycles, rig: RigDescription) -> np.ndarray:
    """Each cycle's start, s: the long layout's own, else cycle index × the description's hop."""
    if isinstance(cycles, Windows):
        return np.asarray(cycles.start_s, dtype=np.float64)
    return np.arange(len(cycles)) * rig.window.hop_s


def rig_cycles_batch(cycles: Cycles, rows: Iterable[int], rig_name: str, start_s: np.ndarray,
                     first_index: int = 0) -> pa.RecordBatch:
    """One ``rig_cycles`` message holding the cycles ``rows`` of ``cycles`` (``cycle`` = row + ``first_index``)."""
    rows = list(rows)
    names = list(cycles.channels)
    labels = [[{"name": n, "value": label_text(column[r])} for n, column in cycles.labels.items()] or None
              for r in rows]
    data = {
        "cycle": [r + first_index for r in rows], "start_s": [float(start_s[r]) for r in rows],
        "rig": [rig_name] * len(rows), "grid_hz": [float(cycles.grid_hz)] * len(rows),
        "channels": [names] * len(rows), "values": [cycles.values[r].reshape(-1).tolist() for r in rows],
        "labels": labels,
    }
    return pa.RecordBatch.from_pydict(data, schema=wire_schema(RIG_CYCLES))


def _label_value(label: Label, text: str, where: str) -> LabelValue:
    """A label's value from its text, checked against the declared values."""
    for value in label.values:
        if label_text(value) == text:
            return value
    raise DataError(f"label '{label.name}' must be one of {[label_text(v) for v in label.values]}. Got {text!r}.",
                    where)


def cycles_from_batches(batches: Iterable[pa.RecordBatch], rig: RigDescription,
                        source: str) -> tuple[Windows, np.ndarray]:
    """The cycles of ``rig_cycles`` messages (in order, with their ``start_s``) and their ``cycle`` indexes.

    Raises
    ------
    DataError
        A message of another rig, grid or channels than ``rig``'s, values that do not fill the channels × the
        window's samples, a label the description does not declare or a value outside its set; naming the
        message and row.
    """
    names = tuple(rig.channels.names)
    samples = rig.window.samples
    values: list[np.ndarray] = []
    index: list[int] = []
    starts: list[float] = []
    labels: dict[str, list[LabelValue]] = {}
    for m, batch in enumerate(batches):
        columns = batch.to_pydict()
        for r in range(batch.num_rows):
            where = f"{source}: message {m}, row {r}"
            channels = tuple(columns["channels"][r])
            if columns["rig"][r] != rig.name or columns["grid_hz"][r] != rig.window.grid_hz:
                raise DataError(f"cycles must be of rig {rig.name!r} on a {rig.window.grid_hz:g} Hz grid. Got rig "
                                f"{columns['rig'][r]!r} at {columns['grid_hz'][r]:g} Hz.", where)
            if channels != names or len(columns["values"][r]) != len(names) * samples:
                raise DataError(f"a cycle must hold channels {list(names)} × {samples} samples. Got "
                                f"{list(channels)} and {len(columns['values'][r])} values.", where)
            values.append(np.asarray(columns["values"][r], dtype=np.float64).reshape(len(names), samples))
            index.append(int(columns["cycle"][r]))
            starts.append(float(columns["start_s"][r]))
            for item in columns["labels"][r] or ():
                try:
                    label = rig.label(item["name"])
                except ParameterError:
                    raise DataError(f"labels must be among {[x.name for x in rig.labels]}. Got {item['name']!r}.",
                                    where) from None
                labels.setdefault(item["name"], []).append(_label_value(label, item["value"], where))
    if any(len(v) != len(values) for v in labels.values()):
        counts = {k: len(v) for k, v in labels.items()}
        raise DataError(f"every cycle must carry the same labels. Got counts {counts} for {len(values)} cycles.",
                        source)
    stacked = np.stack(values) if values else np.zeros((0, len(names), samples))
    as_arrays = {k: np.asarray(v) for k, v in labels.items()}
    cycles = Windows(values=stacked, channels=names, labels=as_arrays, grid_hz=rig.window.grid_hz, source=source,
                     start_s=np.asarray(starts), mixed=0)
    return cycles, np.asarray(index, dtype=np.int64)


def write_rig_recording(path: str | Path, cycles: Cycles, rig: RigDescription, rig_text: str, *, fleet: str,
                        machine: str, per_message: int = CYCLES_PER_MESSAGE) -> Path:
    """Write ``cycles`` to an MCAP file: ``rig_cycles`` messages on ``hydro/<fleet>/<machine>/cycles`` (log time =
    the first cycle's start), metadata record ``hydrowatch`` with ``fleet``, ``machine``, ``rig``, the description's
    TOML text (:data:`RIG_TEXT_KEY`), ``cycles`` and the schema's version."""
    path = Path(path)
    start = start_times(cycles, rig)
    if len(cycles) and start[0] < 0:
        raise DataError(f"cycle start times must be >= 0 s for MCAP log times. Got {start[0]}.", str(path))
    record = {"fleet": fleet, "machine": machine, "rig": rig.name, RIG_TEXT_KEY: rig_text, "cycles": str(len(cycles)),
              "schema": "rig_cycles", "schema_version": str(current_version("rig_cycles")),
              "source": cycles.source}
    key = topic(fleet, machine, "cycles")
    with McapWriter(path, metadata=record) as writer:
        for first in range(0, len(cycles), per_message):
            rows = range(first, min(first + per_message, len(cycles)))
            writer.write(key, rig_cycles_batch(cycles, rows, rig.name, start), int(round(start[first] * 1e9)))
    return path


def read_rig_recording(path: str | Path) -> tuple[str, Cycles]:
    """The description's TOML text and the cycles of an MCAP file written by :func:`write_rig_recording`.

    Raises
    ------
    DataError
        An unfinished file, one without a description in its metadata, without ``cycles`` messages, or with
        several machines' cycles; as :func:`cycles_from_batches` for the messages.
    """
    source = str(path)
    recovery = Recovery(source)
    batches, keys = [], set()
    for key, batch, _ in iter_messages(path, recovery=recovery):
        if key.rsplit("/", 1)[-1] == "cycles":
            batches.append(batch)
            keys.add(key)
    if not recovery.finished:
        raise DataError(f"file must be a finished MCAP. Got {recovery.describe()}.", source)
    text = recovery.metadata.get(METADATA_NAME, {}).get(RIG_TEXT_KEY)
    if text is None:
        raise DataError(f"file must hold a rig description in its '{METADATA_NAME}' metadata (written by "
                        "`hydrowatch import --rig`). Got none.", source)
    if len(keys) != 1:
        raise DataError(f"file must hold one machine's cycles on hydro/<fleet>/<machine>/cycles. Got "
                        f"{sorted(keys) or 'none'}.", source)
    rig = rig_from_text(text, f"{source} ({RIG_TEXT_KEY})")
    return text, cycles_from_batches(batches, rig, source)[0]


def read_rig_data(path: str | Path, rig: RigDescription) -> Cycles:
    """A rig's data as cycles: an MCAP file of ``import --rig`` (its description must be ``rig``'s), a folder of
    per-cycle files (wide layout; without the label file, unlabelled), or a CSV/Parquet table (long layout)."""
    path = Path(path)
    if path.suffix == ".mcap":
        text, cycles = read_rig_recording(path)
        found = rig_from_text(text, str(path)).name
        if found != rig.name:
            raise DataError(f"the file's cycles must be of rig {rig.name!r}. Got rig {found!r}.", str(path))
        return cycles
    if rig.layout == "long":
        return read_windows(path, rig)
    if rig.label_source is not None and path.is_dir() and not (path / rig.label_source).is_file():
        rig = dataclasses.replace(rig, label_source=None)
    return read_cycles(path, rig)


__all__ = ["CYCLES_PER_MESSAGE", "cycles_from_batches", "read_rig_data", "read_rig_recording", "rig_cycles_batch",
           "start_times", "write_rig_recording"]
