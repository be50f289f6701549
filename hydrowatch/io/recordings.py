"""Read and write a :class:`~hydrowatch.recording.Recording` as MCAP, Parquet or CSV (by suffix).

Every read ends in the same checks (:mod:`hydrowatch.io.checks`): the command and at least one
sensor (any subset of flow, speed, torque; other channels are kept as they are), units, a
strictly increasing 200 Hz time base, no NaN, known health labels. Per-row labels that vary
within a file are kept in ``recording.meta["labels"]`` (ndarray of str, shape (n,)) with
``meta["state"] = None``; a constant label becomes ``meta["state"]``.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.io.checks import check_channels, check_labels, check_state, check_time_base, check_unit
from hydrowatch.io.codec import LABEL_FIELD, arrays_from_sensor_chunk, sensor_chunk_from_arrays
from hydrowatch.io.mcap_io import METADATA_NAME, McapWriter, Recovery, iter_messages, topic
from hydrowatch.io.tabular import Table, read_csv, read_parquet, table_from_arrow, write_table
from hydrowatch.log import event, get_logger
from hydrowatch.recording import SAMPLE_RATE_HZ, UNITS, Recording
from hydrowatch.schemas import SCHEMA_VERSION

SUFFIXES = (".mcap", ".parquet", ".csv")
CHUNK_SECONDS = 0.5
"""Samples per MCAP message, s (100 samples at 200 Hz)."""
DEFAULT_FLEET = "default"
_PLAIN_META = ("fleet", "machine", "state")
_NOT_STORED = ("labels", "source", "recovered")
_log = get_logger(__name__)


def _suffix(path: Path) -> str:
    if path.suffix not in SUFFIXES:
        raise DataError(f"file suffix must be one of {', '.join(SUFFIXES)}. Got {path.suffix!r}.", str(path))
    return path.suffix


def _ids(meta: dict[str, Any], path: Path) -> tuple[str, str]:
    return str(meta.get("fleet") or DEFAULT_FLEET), str(meta.get("machine") or path.stem.split(".")[0] or "machine")


def mcap_metadata(meta: dict[str, Any], fleet: str, machine: str, channels: list[str]) -> dict[str, str]:
    """The ``hydrowatch`` metadata record of a recording: plain ids and label, the rest JSON."""
    extra = {k: v for k, v in meta.items() if k not in (*_PLAIN_META, *_NOT_STORED)}
    record = {
        "fleet": fleet,
        "machine": machine,
        "schema_version": str(SCHEMA_VERSION),
        "sample_rate_hz": f"{SAMPLE_RATE_HZ:g}",
        "units": json.dumps({c: UNITS[c] for c in ["t", *channels] if c in UNITS}, ensure_ascii=False),
        "extra": json.dumps(extra, default=str),
    }
    if meta.get("state") is not None:
        record["state"] = str(meta["state"])
    return record


def write_recording(
    recording: Recording, path: str | Path, *, chunk_seconds: float = CHUNK_SECONDS, compression: str = "zstd"
) -> Path:
    """Write ``recording`` to ``path``; the format follows the suffix (.mcap, .parquet, .csv).

    MCAP: one channel ``hydro/<fleet>/<machine>/sensors``, one message per ``chunk_seconds`` of
    samples with log time = time of its first sample (ns), metadata record ``hydrowatch``.
    ``fleet`` defaults to ``default`` and ``machine`` to the file name's stem.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    meta = dict(recording.meta)
    labels = meta.get("labels")
    if labels is None and meta.get("state") is not None:
        labels = np.full(len(recording), str(meta["state"]), dtype=object)
    if _suffix(path) != ".mcap":
        write_table(
            path, recording.t, recording.channels, labels, {k: v for k, v in meta.items() if k not in _NOT_STORED}
        )
        return path
    if chunk_seconds <= 0:
        raise ParameterError(f"chunk_seconds must be > 0 s. Got {chunk_seconds}.")
    if len(recording) and recording.t[0] < 0:
        raise DataError(f"recording times must be >= 0 s for MCAP log times. Got t[0]={recording.t[0]}.", str(path))
    fleet, machine = _ids(meta, path)
    key = topic(fleet, machine, "sensors")
    step = max(1, round(chunk_seconds * SAMPLE_RATE_HZ))
    record = mcap_metadata(meta, fleet, machine, list(recording.channels))
    with McapWriter(path, compression=compression, metadata=record) as writer:
        for start in range(0, len(recording), step):
            stop = min(start + step, len(recording))
            columns = {k: v[start:stop] for k, v in recording.channels.items()}
            if labels is not None:
                columns[LABEL_FIELD] = labels[start:stop]
            batch = sensor_chunk_from_arrays(recording.t[start:stop], columns)
            writer.write(key, batch, int(round(recording.t[start] * 1e9)))
    return path


def _sensor_chunks(path: Path, machine: str | None, recovery: Recovery) -> Iterator[tuple[str, Any]]:
    chosen: str | None = None
    for key, batch, _ in iter_messages(path, recovery=recovery):
        parts = key.split("/")
        if len(parts) != 4 or parts[0] != "hydro" or parts[3] != "sensors":
            continue
        if machine is not None and parts[2] != machine:
            continue
        if chosen is None:
            chosen = key
        elif key != chosen:
            raise DataError(
                f"file must hold one machine's sensors, or pass machine=. Got {chosen} and {key}.", str(path)
            )
        yield key, batch


def _read_mcap(path: Path, machine: str | None, recover: bool) -> tuple[np.ndarray, dict, np.ndarray | None, dict]:
    source = str(path)
    recovery = Recovery(source)
    times: list[np.ndarray] = []
    parts: dict[str, list[np.ndarray]] = {}
    first_names: list[str] | None = None
    for index, (_, batch) in enumerate(_sensor_chunks(path, machine, recovery)):
        t, channels = arrays_from_sensor_chunk(batch)
        if first_names is None:
            first_names = sorted(channels)
        elif sorted(channels) != first_names:
            raise DataError(
                f"every sensor chunk must have the same columns. Got {sorted(channels)} in chunk {index} "
                f"(t={t[0]:.3f} s) after {first_names}.",
                source,
            )
        times.append(t)
        for name, values in channels.items():
            parts.setdefault(name, []).append(values)
    if not recovery.finished and not recover:
        raise DataError(
            f"file must be a finished MCAP. Got {recovery.describe()}. Use recover=True (--recover) to take "
            "the complete messages.",
            source,
        )
    if not times:
        rig = recovery.metadata.get(METADATA_NAME, {}).get("rig")
        found = (f" (it holds whole cycles of rig {rig!r}, written by `import --rig`: give it to `train --rig`, "
                 "`score` or `rig --data`)") if rig else ""
        raise DataError(
            f"file must hold sensor chunks on hydro/<fleet>/{machine or '<machine>'}/sensors. Got none{found}.", source
        )
    meta_record = recovery.metadata.get(METADATA_NAME, {})
    meta: dict[str, Any] = json.loads(meta_record.get("extra", "{}"))
    meta.update({k: meta_record[k] for k in _PLAIN_META if meta_record.get(k)})
    for name, unit in json.loads(meta_record.get("units", "{}")).items():
        check_unit(name, unit, source)
    if not recovery.finished:
        meta["recovered"] = recovery.describe()
    columns = {k: np.concatenate(v) for k, v in parts.items()}
    labels = columns.pop(LABEL_FIELD, None)
    return np.concatenate(times), columns, labels, meta


def read_recording(path: str | Path, *, machine: str | None = None, recover: bool = False,
                   required: Sequence[str] | None = None) -> Recording:
    """Read and check a recording; the format follows the suffix (.mcap, .parquet, .csv).

    Parameters
    ----------
    path : str or Path
    machine : str, optional
        For an MCAP file with several machines' sensor channels: which one.
    recover : bool, default False
        Accept an unfinished MCAP file (writer killed) and return its complete chunks; the
        recording's ``meta["recovered"]`` then says how much was recovered. Without it such a
        file is an error.
    required : sequence of str, optional
        The channels the caller needs (default: the plant's rule, the command and at least one sensor,
        :meth:`~hydrowatch.channels.ChannelSet.missing`). ``identify`` passes its input and output, so a CSV
        or Parquet file with only those columns reads.

    Raises
    ------
    DataError
        One line naming the file, the row or message and what is wrong.
    """
    path = Path(path)
    source = str(path)
    suffix = _suffix(path)
    if suffix == ".mcap":
        t, channels, labels, meta = _read_mcap(path, machine, recover)
    else:
        table = read_csv(path) if suffix == ".csv" else read_parquet(path)
        t, channels, labels, meta = table.t, table.channels, table.labels, dict(table.meta)
    return _checked(Table(t, channels, labels, meta), source, required)


def recording_from_table(table: pa.Table, source: str, *, required: Sequence[str] | None = None) -> Recording:
    """A checked recording from an Arrow table of samples in memory (columns as in a Parquet file: ``t`` [s], the
    channels, an optional ``state``; other columns are left out), with the same checks as :func:`read_recording`;
    ``source`` names the table in errors (the MLflow model's input, :mod:`hydrowatch.training.mlflow_model`)."""
    return _checked(table_from_arrow(table, {}, source), source, required)


def _checked(table: Table, source: str, required: Sequence[str] | None) -> Recording:
    """The checks every read ends in: time base, channels, labels; ``meta["source"]`` set."""
    t, labels, meta = table.t, table.labels, dict(table.meta)
    check_time_base(t, source)
    channels = check_channels(t, table.channels, source, None if required is None else tuple(required))
    if meta.get("state") is not None:
        check_state(meta["state"], source, " in the file metadata")
    meta.pop("labels", None)
    if labels is not None:
        constant = check_labels(labels, t, source)
        if constant is None:
            meta["state"], meta["labels"] = None, labels
        elif meta.get("state") not in (None, constant):
            raise DataError(
                f"column '{LABEL_FIELD}' must agree with the file's label {meta['state']!r}. Got {constant!r}.", source
            )
        else:
            meta["state"] = constant
    meta["source"] = source
    if "recovered" in meta:
        event(_log, "using recovered recording", source=source, samples=len(t))
    return Recording(t, channels, meta)


def convert(
    source: str | Path,
    out: str | Path,
    *,
    label: str | None = None,
    fleet: str | None = None,
    machine: str | None = None,
    recover: bool = False,
) -> Recording:
    """Read ``source``, check it, optionally label it, and write it to ``out`` (formats by suffix).

    Parameters
    ----------
    label : str, optional
        Health label for the whole recording; must agree with labels the file already has.
    fleet, machine : str, optional
        Ids for the MCAP channel ``hydro/<fleet>/<machine>/sensors`` (default: the file's own,
        else ``default`` and the file name's stem).
    recover : bool, default False
        Accept an unfinished MCAP source (see :func:`read_recording`).

    Returns
    -------
    Recording
        What was written.
    """
    source, out = Path(source), Path(out)
    _suffix(out)
    if source.resolve() == out.resolve():
        raise DataError(f"output must differ from the input. Got --out {out}.", str(source))
    recording = read_recording(source, machine=machine, recover=recover)
    if label is not None:
        check_state(label, str(source), " given with --label")
        if recording.meta.get("labels") is not None or recording.state not in (None, label):
            have = recording.state or "labels that vary by row"
            raise DataError(f"--label {label!r} must agree with the file's labels. Got {have}.", str(source))
        recording.meta["state"] = label
    if fleet is not None:
        recording.meta["fleet"] = fleet
    if machine is not None:
        recording.meta["machine"] = machine
    recording.meta.setdefault("machine", source.stem.split(".")[0])
    write_recording(recording, out)
    return recording


__all__ = ["CHUNK_SECONDS", "SUFFIXES", "convert", "mcap_metadata", "read_recording", "write_recording"]
