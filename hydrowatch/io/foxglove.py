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
  points, reset_at [s], reason, untold_from}}; null fields left out), so Foxglove plots
  ``….forecast.parts.load.alert_in_s``.
- ``expected`` → one message **per point** (a 0.1 s block mean), log time = the point's middle ``t`` =
  ``window_start + (i + ½)·step``: ``t``, ``window_start``, ``window_end``, ``step`` [s], ``model_version`` and
  ``sensors`` ({sensor: {measured, expected, source, unit}}; a non-finite value left out), so Foxglove plots
  ``….expected.sensors.flow.measured`` against ``….expected.sensors.flow.expected`` (and the raw
  ``….sensors.flow`` beside them). Windows that overlap (an entropy bundle with hop < window) give two points
  at some times.
- ``cycle_health`` → one message **per cycle**, log time = ``window_end`` (when the cycle's verdicts are
  known, as ``health``): ``cycle``, ``window_start``/``window_end`` [s], ``model_version`` and ``components``
  ({component: {state, probability, probabilities ({state: p}), novelty, reason, truth, healthy}}; null and non-finite
  left out), so Foxglove plots ``….cycle_health.components.valve.probability`` and its State Transitions panel
  ``….cycle_health.components.valve.state``.

Every channel thus shares the recording's time base (sample time, s → ns). The time the message
was logged in the source (a recorder's receive time) is kept as publish time. ``status``
heartbeats are left out: their time is Unix time, which would stretch the timeline by decades; so are a rig's
``cycles`` (whole cycles of the rig's own channels; their verdicts, ``cycle_health``, are exported).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa

from hydrowatch.errors import DataError
from hydrowatch.io.codec import decode_batch
from hydrowatch.io.foxglove_schema import (
    COMPONENT_FIELDS,
    EXPECTED_SENSOR_FIELDS,
    FORECAST_PART_FIELDS,
    KINDS,
    json_schema,
)
from hydrowatch.io.mcap_io import McapWriter, Recovery, expected_schema, iter_records

JSON_ENCODING = "json"
JSON_SCHEMA_ENCODING = "jsonschema"


def foxglove_topic(key: str) -> str:
    """Foxglove topic of a key expression: ``hydro/f1/m1/sensors`` → ``/hydro/f1/m1/sensors``."""
    return key if key.startswith("/") else f"/{key}"


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
        parts[row["fault"]] = {k: row[k] for k in FORECAST_PART_FIELDS if _finite(row.get(k))}  # v1: no untold_from
    for (start, windows, version), parts in found.items():
        yield _ns(start, where, "window_start"), {"window_start": start, "history_windows": windows,
                                                  "model_version": version, "parts": parts}


def expected_points(batch: pa.RecordBatch, where: str) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(log_time_ns, point)`` per point of an expected_window message: point i of every sensor of a window at
    ``t = window_start + (i + ½)·step`` [s], with {sensor: {measured, expected, source, unit}} (a non-finite value
    left out), in time order."""
    points: dict[int, dict[str, Any]] = {}
    for row in batch.to_pylist():
        head = {k: row[k] for k in ("window_start", "window_end", "step", "model_version")}
        if len(row["measured"]) != len(row["expected"]):
            raise DataError(f"expected must have as many points as measured. Got {len(row['expected'])} and "
                            f"{len(row['measured'])} for sensor {row['sensor']!r}.", where)
        for i, (measured, expected) in enumerate(zip(row["measured"], row["expected"])):
            t = row["window_start"] + (i + 0.5) * row["step"]
            point = points.setdefault(_ns(t, where, "window_start + (i + 0.5)·step"), {"t": t, **head, "sensors": {}})
            values = {"measured": measured, "expected": expected, "source": row["source"], "unit": row["unit"]}
            point["sensors"][row["sensor"]] = {k: v for k, v in values.items() if _finite(v)}
    yield from sorted(points.items(), key=lambda item: item[0])


def cycle_verdicts(batch: pa.RecordBatch, where: str) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(log_time_ns, cycle)`` per cycle of a cycle_verdict message: the rows (one per component) gathered under
    ``components`` as {component: {state, probability, probabilities ({state: p}), novelty, reason, truth,
    healthy}} (null and non-finite left out), log time = ``window_end``."""
    found: dict[tuple[int, float, float, str], dict[str, dict[str, Any]]] = {}
    for row in batch.to_pylist():
        components = found.setdefault((row["cycle"], row["window_start"], row["window_end"], row["model_version"]), {})
        verdict = {k: row[k] for k in COMPONENT_FIELDS if k != "probabilities" and _finite(row[k])}
        verdict["probabilities"] = {p["state"]: p["probability"] for p in row["probabilities"] or []
                                    if _finite(p["probability"])}
        components[row["component"]] = verdict
    for (cycle, start, end, version), components in found.items():
        yield _ns(end, where, "window_end"), {"cycle": cycle, "window_start": start, "window_end": end,
                                              "model_version": version, "components": components}


_CONVERT = {"sensors": sensor_samples, "health": verdicts, "kl": kl_windows, "forecast": forecasts,
            "expected": expected_points, "cycle_health": cycle_verdicts}


class FoxgloveWriter(McapWriter):
    """MCAP writer of hydrowatch messages as JSON for Foxglove: :class:`McapWriter` (same options, a
    context manager) plus :meth:`write_message`.

    Attributes
    ----------
    written : dict
        Foxglove topic → JSON messages written.
    skipped : dict
        Key → messages left out (kinds without a conversion: ``status`` heartbeats and a rig's ``cycles``).
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
            Its key expression; the last part picks the conversion (sensors, health, kl, forecast, expected,
            cycle_health).
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
            When a sample, point or window time is negative or not finite (it cannot be a log time).
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


_COUNTED = (("sensors", "samples"), ("health", "verdicts"), ("kl", "relative-entropy windows"),
            ("forecast", "forecasts"), ("expected", "expected points"), ("cycle_health", "cycle verdicts"))
"""How :meth:`FoxgloveExport.describe` names the JSON messages of each kind (those written)."""


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
        counts = ", ".join(f"{per_kind[kind]} {label}" for kind, label in _COUNTED if per_kind[kind]) or "nothing"
        return (f"wrote {self.out}: {counts} on {len(self.written)} channels "
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
    "COMPONENT_FIELDS",
    "EXPECTED_SENSOR_FIELDS",
    "FORECAST_PART_FIELDS",
    "cycle_verdicts",
    "expected_points",
    "forecasts",
    "foxglove_topic",
    "json_schema",
    "kl_windows",
    "sensor_samples",
    "verdicts",
]
