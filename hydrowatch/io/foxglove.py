"""Recordings that Foxglove plots: hydrowatch messages re-encoded as JSON with a JSON Schema.

Foxglove decodes protobuf, JSON (schema encoding ``jsonschema``, message encoding ``json``),
FlatBuffers, ROS and OMG IDL, not Arrow IPC. :class:`FoxgloveWriter` writes each hydrowatch message
as JSON on topic ``/<key>`` (``/hydro/<fleet>/<machine>/<kind>``: a leading ``/`` as ROS topics have,
so Foxglove message paths read ``/hydro/f1/m1/sensors.flow``), with a JSON Schema built from the
declaration in ``schemas/`` (descriptions carry the units):

- ``sensors`` → one message **per sample**, log time = the sample's ``t``, scalar fields ``t``
  [s], ``voltage`` [V], ``flow`` [L/min], ``speed`` [rad/s], ``torque`` [N·m] (and the optional
  columns present; NaN and null are left out). Foxglove's Plot panel draws one point per message
  at its log time for a scalar path: a chunk as one message of arrays would plot as one point per
  chunk, or, with ``[:]``, as 100 points at the same time.
- ``health`` → one message per verdict, log time = ``window_end``: ``window_start``/``window_end``
  [s], ``state``, ``probability``, ``probabilities`` ({state: p}), ``reason`` when given,
  ``model_version``.
- ``kl`` → one message per window, log time = ``window_end``: window bounds, ``model_version`` and
  ``relative_entropy`` ({sensor: {state: D [nats]}}).
- ``forecast`` → one message per forecast, log time = ``window_start`` (the start of the machine's last window
  with an index, which ``alert_in_s`` counts from): ``window_start`` [s], ``history_windows``,
  ``model_version`` and ``parts`` ({fault: {alert_in_s [s], low_s, high_s, rate_per_h [1/h], level, model,
  points, reset_at [s], reason}}; null fields left out), so Foxglove plots ``….forecast.parts.load.alert_in_s``.

Every channel thus shares the recording's time base (sample time, s → ns). The time the message
was logged in the source (a recorder's receive time) is kept as publish time. ``status``
heartbeats are left out: their time is Unix time, which would stretch the timeline by decades.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa

from hydrowatch.errors import DataError
from hydrowatch.io.codec import decode_batch
from hydrowatch.io.mcap_io import McapWriter, Recovery, expected_schema, iter_records
from hydrowatch.schemas import schema_by_name

JSON_ENCODING = "json"
JSON_SCHEMA_ENCODING = "jsonschema"
KINDS: dict[str, str] = {"sensors": "sensor_chunk", "health": "health_verdict", "kl": "kl_window",
                         "forecast": "forecast"}
"""Topic kinds written for Foxglove → the hydrowatch schema of their messages."""
FORECAST_PART_FIELDS = ("alert_in_s", "low_s", "high_s", "rate_per_h", "level", "model", "points", "reset_at", "reason")
"""Fields of a ``forecast`` row kept under its part's ``fault`` (the others describe the forecast as a whole)."""
_JSON_TYPES = {"double": "number", "float": "number", "int64": "number", "int32": "number", "bool": "boolean",
               "string": "string"}


def foxglove_topic(key: str) -> str:
    """Foxglove topic of a key expression: ``hydro/f1/m1/sensors`` → ``/hydro/f1/m1/sensors``."""
    return key if key.startswith("/") else f"/{key}"


def _property(arrow_field: pa.Field) -> dict[str, Any]:
    """JSON Schema of one scalar declared field; the description ends with its unit."""
    meta = {k.decode(): v.decode() for k, v in (arrow_field.metadata or {}).items()}
    unit = meta.get("unit", "")
    description = meta.get("description", "") + (f" [{unit}]" if unit and unit != "1" else "")
    return {"type": _JSON_TYPES.get(str(arrow_field.type), "string"), "description": description}


def json_schema(kind: str, example: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of the Foxglove messages of topic ``kind``.

    Parameters
    ----------
    kind : {"sensors", "health", "kl", "forecast"}
    example : mapping, optional
        A first message: its ``probabilities`` states (health), ``relative_entropy`` sensors and
        states (kl) or ``parts`` faults (forecast) are listed as properties, so that Foxglove offers
        them in its path completion; others are still allowed.
    """
    declared = schema_by_name(KINDS[kind])
    replaced = {"sensors": set(), "health": {"probabilities", "degradation"},
                "kl": {"sensor", "state", "relative_entropy"}, "forecast": {"fault", *FORECAST_PART_FIELDS}}[kind]
    properties = {f.name: _property(f) for f in declared if f.name not in replaced}
    required = [f.name for f in declared if not f.nullable and f.name not in replaced]
    title, description = f"hydrowatch.{KINDS[kind]}", declared.metadata[b"hydrowatch.description"].decode()
    number, example = {"type": "number"}, example or {}
    if kind == "sensors":
        title, description = "hydrowatch.sensor_sample", "One sample of one machine at 200 Hz; log time = t."
        required = ["t"]  # a NaN reading is left out of its sample
    elif kind == "health":
        properties["probabilities"] = {
            "type": "object", "description": "Probability of every trained state, 0 to 1.",
            "properties": {s: number for s in example.get("probabilities", {})}, "additionalProperties": number}
        required.append("probabilities")
        part: dict[str, Any] = {"type": "object", "properties": {k: number for k in ("index", "low", "high")}}
        properties["degradation"] = {
            "type": "object", "description": "Degradation index of each part (0 healthy, 1 at the alert level) with "
                                             "its 95 % interval [1]; absent when the window has none.",
            "additionalProperties": part}
    elif kind == "forecast":
        part = {"type": "object", "properties": {f.name: _property(f) for f in declared
                                                 if f.name in FORECAST_PART_FIELDS}}
        properties["parts"] = {
            "type": "object", "description": "Each part's forecast of the alert (index 1.0); fields as the forecast "
                                             "schema's rows, a null one left out.",
            "properties": {fault: part for fault in example.get("parts", {})}, "additionalProperties": part}
        required.append("parts")
    else:
        per_state = {"type": "object", "additionalProperties": number}
        rows = example.get("relative_entropy", {})
        properties["relative_entropy"] = {
            "type": "object",
            "description": "Relative entropy of the window's prediction errors from each state's base distribution, "
                           "per sensor and state [nats]; parity bundles: the score of each component relation "
                           "(load, motor, valve) under each state [1, >= 1].",
            "properties": {s: {**per_state, "properties": {k: number for k in states}} for s, states in rows.items()},
            "additionalProperties": per_state}
        required.append("relative_entropy")
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "description": description,
            "type": "object", "properties": properties, "required": required}


def _finite(value: Any) -> bool:
    return value is not None and not (isinstance(value, float) and not math.isfinite(value))


def _ns(seconds: float, where: str, name: str) -> int:
    if not _finite(seconds) or seconds < 0:
        raise DataError(f"{name} must be a finite time >= 0 s to serve as Foxglove log time. Got {seconds}.", where)
    return int(round(seconds * 1e9))


def sensor_samples(batch: pa.RecordBatch, where: str) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(log_time_ns, sample)`` per row of a sensor chunk; NaN and null values are left out."""
    columns = {name: batch.column(name).to_pylist() for name in batch.schema.names}
    names = list(columns)
    for row in zip(*columns.values()):
        sample = {n: v for n, v in zip(names, row) if _finite(v)}
        yield _ns(sample.get("t", math.nan), where, "t"), sample


def verdicts(batch: pa.RecordBatch, where: str) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(log_time_ns, verdict)`` per row of a health verdict; ``probabilities`` as {state: p}, ``degradation`` (v2,
    when the window has one) as {fault: {index, low, high}}."""
    for row in batch.to_pylist():
        verdict = {k: v for k, v in row.items() if k not in ("probabilities", "degradation") and _finite(v)}
        verdict["probabilities"] = {p["state"]: p["probability"] for p in row["probabilities"] or []
                                    if _finite(p["probability"])}
        if row.get("degradation"):  # health_verdict v2: {fault: {index, low, high}}, plottable per part
            verdict["degradation"] = {d["fault"]: {k: d[k] for k in ("index", "low", "high") if _finite(d[k])}
                                      for d in row["degradation"]}
        yield _ns(row["window_end"], where, "window_end"), verdict


def kl_windows(batch: pa.RecordBatch, where: str) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(log_time_ns, window)`` per window of a kl message (long rows pivoted to {sensor: {state: D}})."""
    windows: dict[tuple[float, float, str], dict[str, dict[str, float]]] = {}
    for row in batch.to_pylist():
        rows = windows.setdefault((row["window_start"], row["window_end"], row["model_version"]), {})
        if _finite(row["relative_entropy"]):  # a non-finite score is left out (JSON has no NaN or inf)
            rows.setdefault(row["sensor"], {})[row["state"]] = row["relative_entropy"]
    for (start, end, version), rows in windows.items():
        yield _ns(end, where, "window_end"), {"window_start": start, "window_end": end, "model_version": version,
                                              "relative_entropy": rows}


def forecasts(batch: pa.RecordBatch, where: str) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(log_time_ns, forecast)`` per forecast message: the rows (one per part) gathered under ``parts`` as
    {fault: {alert_in_s, low_s, high_s, …}} (null and non-finite fields left out), log time = ``window_start``."""
    found: dict[tuple[float, int, str], dict[str, dict[str, Any]]] = {}
    for row in batch.to_pylist():
        parts = found.setdefault((row["window_start"], row["history_windows"], row["model_version"]), {})
        parts[row["fault"]] = {k: row[k] for k in FORECAST_PART_FIELDS if _finite(row[k])}
    for (start, windows, version), parts in found.items():
        yield _ns(start, where, "window_start"), {"window_start": start, "history_windows": windows,
                                                  "model_version": version, "parts": parts}


_CONVERT = {"sensors": sensor_samples, "health": verdicts, "kl": kl_windows, "forecast": forecasts}


class FoxgloveWriter(McapWriter):
    """MCAP writer of hydrowatch messages as JSON for Foxglove: :class:`McapWriter` (same options, a
    context manager) plus :meth:`write_message`.

    Attributes
    ----------
    written : dict
        Foxglove topic → JSON messages written.
    skipped : dict
        Key → messages left out (kinds without a conversion: ``status`` heartbeats, ``expected``, ``cycles``,
        ``cycle_health``).
    """

    def __init__(self, path: str | Path, **options: Any) -> None:
        super().__init__(path, **options)
        self._json_channels: dict[str, int] = {}
        self.written: dict[str, int] = {}
        self.skipped: dict[str, int] = {}

    def write_message(self, key: str, batch: pa.RecordBatch, publish_time_ns: int | None = None) -> int:
        """Write one decoded hydrowatch message of key ``hydro/<fleet>/<machine>/<kind>`` as JSON.

        Parameters
        ----------
        key : str
            Its key expression; the last part picks the conversion (sensors, health, kl, forecast).
        batch : pyarrow.RecordBatch
            The decoded message.
        publish_time_ns : int, optional
            Kept as the JSON messages' publish time (default: their log time), ns.

        Returns
        -------
        int
            JSON messages written (0 for a message of a kind without a conversion, e.g. ``status``).

        Raises
        ------
        DataError
            When a sample time or window end is negative or not finite (it cannot be a log time).
        """
        kind = key.rsplit("/", 1)[-1]
        if kind not in _CONVERT:
            self.skipped[key] = self.skipped.get(key, 0) + 1
            return 0
        topic, where = foxglove_topic(key), f"{self.path}: {key}"
        count = 0
        for log_time_ns, message in _CONVERT[kind](batch, where):
            channel = self._json_channels.get(topic)
            if channel is None:
                schema = json_schema(kind, message)
                channel = self._json_channels[topic] = self.add_channel(
                    topic, JSON_ENCODING, schema["title"], JSON_SCHEMA_ENCODING, json.dumps(schema).encode(),
                    {"hydrowatch.key": key, "hydrowatch.schema": KINDS[kind]})
            data = json.dumps(message, separators=(",", ":"), allow_nan=False).encode()
            self.write_channel(channel, data, log_time_ns, log_time_ns if publish_time_ns is None else publish_time_ns)
            count += 1
        self.written[topic] = self.written.get(topic, 0) + count
        return count


@dataclass
class FoxgloveExport:
    """What :func:`export_foxglove` wrote: JSON messages per Foxglove topic, Arrow messages read."""

    source: str
    out: str
    messages_in: int = 0
    written: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)
    recovered: str | None = None

    def describe(self) -> str:
        """One line for people: what was written where."""
        per_kind = {kind: sum(n for t, n in self.written.items() if t.endswith(f"/{kind}")) for kind in KINDS}
        kinds = sorted({key.rsplit("/", 1)[-1] for key in self.skipped})
        left_out = (f"; left out {sum(self.skipped.values())} messages Foxglove is not given ({', '.join(kinds)})"
                    if self.skipped else "")
        return (f"wrote {self.out}: {per_kind['sensors']} samples, {per_kind['health']} verdicts, "
                f"{per_kind['kl']} relative-entropy windows, {per_kind['forecast']} forecasts on {len(self.written)} "
                "channels "
                f"(JSON with JSON Schema, for Foxglove) from {self.messages_in} messages{left_out}"
                + (f"; {self.recovered}" if self.recovered else ""))


def export_foxglove(source: str | Path, out: str | Path, *, recover: bool = False) -> FoxgloveExport:
    """Re-encode a hydrowatch MCAP recording as JSON that Foxglove decodes; every metadata record is kept.

    The output is written to ``OUT.part`` and renamed when complete, so a failed export leaves nothing.

    Parameters
    ----------
    source : str or Path
        A hydrowatch MCAP file (Arrow IPC channels ``hydro/<fleet>/<machine>/<kind>``).
    out : str or Path
        The MCAP file to write.
    recover : bool, default False
        Export the complete chunks of an unfinished file (writer killed) instead of refusing it.

    Raises
    ------
    DataError
        When the file is not an MCAP file, holds no hydrowatch channel, is unfinished (without
        ``recover``), or a message does not decode (naming the message, topic and log time).
    """
    source, out = str(source), Path(out)
    recovery = Recovery(source)
    result = FoxgloveExport(source, str(out))
    foreign: dict[str, str] = {}
    partial = out.with_name(out.name + ".part")
    try:
        with FoxgloveWriter(partial) as writer:
            for index, (channel, schema, message) in enumerate(iter_records(source, recovery)):
                expected = expected_schema(channel, schema)
                if expected is None:
                    foreign[channel.topic] = channel.message_encoding
                    continue
                where = f"{source}: message {index} on {channel.topic} (log time {message.log_time / 1e9:.3f} s)"
                writer.write_message(channel.topic, decode_batch(message.data, expected, where), message.log_time)
                result.messages_in += 1
            if not result.messages_in:
                got = ", ".join(f"{t} ({e})" for t, e in sorted(foreign.items())) or "no messages"
                hint = " It looks like a Foxglove export already." if JSON_ENCODING in foreign.values() else ""
                raise DataError("file must be a hydrowatch MCAP recording with messages on hydro/<fleet>/<machine>/"
                                f"<kind> channels in x-arrow-ipc-stream encoding. Got {got}.{hint}", source)
            if not recovery.finished and not recover:
                raise DataError(f"file must be a finished MCAP. Got {recovery.describe()}. Use --recover to export "
                                "the complete chunks.", source)
            for name, record in recovery.metadata.items():
                writer.add_metadata(name, record)
            result.written, result.skipped = dict(writer.written), dict(writer.skipped)
        os.replace(partial, out)
    finally:
        partial.unlink(missing_ok=True)
    result.recovered = None if recovery.finished else recovery.describe()
    return result


__all__ = [
    "JSON_ENCODING",
    "JSON_SCHEMA_ENCODING",
    "KINDS",
    "FoxgloveExport",
    "FoxgloveWriter",
    "export_foxglove",
    "FORECAST_PART_FIELDS",
    "forecasts",
    "foxglove_topic",
    "json_schema",
    "kl_windows",
    "sensor_samples",
    "verdicts",
]
