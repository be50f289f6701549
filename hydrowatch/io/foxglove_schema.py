"""JSON Schemas of the messages :mod:`hydrowatch.io.foxglove` writes for Foxglove, built from the declarations in
``schemas/`` (descriptions carry the units), one per topic kind; the module docstring of
:mod:`hydrowatch.io.foxglove` says what each message holds."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import pyarrow as pa

from hydrowatch.schemas import schema_by_name

KINDS: dict[str, str] = {"sensors": "sensor_chunk", "health": "health_verdict", "kl": "kl_window",
                         "forecast": "forecast", "expected": "expected_window", "cycle_health": "cycle_verdict"}
"""Topic kinds written for Foxglove → the hydrowatch schema of their messages."""
FORECAST_PART_FIELDS = ("alert_in_s", "low_s", "high_s", "rate_per_h", "level", "model", "points", "reset_at", "reason",
                        "untold_from")
"""Fields of a ``forecast`` row kept under its part's ``fault`` (the others describe the forecast as a whole)."""
EXPECTED_SENSOR_FIELDS = ("measured", "expected", "source", "unit")
"""Fields of an ``expected_window`` row kept under its ``sensor``, one point's value for the lists."""
COMPONENT_FIELDS = ("state", "probability", "probabilities", "novelty", "reason", "truth", "healthy")
"""Fields of a ``cycle_verdict`` row kept under its ``component`` (the others describe the cycle)."""
_JSON_TYPES = {"double": "number", "float": "number", "int64": "number", "int32": "number", "bool": "boolean",
               "string": "string"}


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
    kind : {"sensors", "health", "kl", "forecast", "expected", "cycle_health"}
    example : mapping, optional
        A first message: its ``probabilities`` states (health), ``relative_entropy`` sensors and
        states (kl), ``parts`` faults (forecast), ``sensors`` (expected) or ``components`` and their states
        (cycle_health) are listed as properties, so that Foxglove offers them in its path completion; others are
        still allowed.
    """
    declared = schema_by_name(KINDS[kind])
    replaced = {"sensors": set(), "health": {"probabilities", "degradation"},
                "kl": {"sensor", "state", "relative_entropy"}, "forecast": {"fault", *FORECAST_PART_FIELDS},
                "expected": {"sensor", *EXPECTED_SENSOR_FIELDS}, "cycle_health": {"component", *COMPONENT_FIELDS}}[kind]
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
    elif kind == "expected":
        title, description = "hydrowatch.expected_point", ("One point (the mean over step seconds) of what the model "
                                                           "expected each sensor to read, beside what it read; log "
                                                           "time = t, the point's middle.")
        properties["t"] = {"type": "number", "description": "Middle of the point's time, window_start + (i + 0.5)·step "
                                                            "[s]"}
        point_fields = {f.name: _property(f) for f in declared if f.name in EXPECTED_SENSOR_FIELDS}
        for name in ("measured", "expected"):
            point_fields[name]["type"] = "number"  # one point of the declared list
        sensor = {"type": "object", "properties": point_fields}
        properties["sensors"] = {
            "type": "object", "description": "Each sensor the model predicts: measured and expected at this point, in "
                                             "the sensor's unit (unit), and what expected it (source).",
            "properties": {s: sensor for s in example.get("sensors", {})}, "additionalProperties": sensor}
        required += ["t", "sensors"]
    elif kind == "cycle_health":
        title = "hydrowatch.cycle_verdicts"
        description = "The verdicts of one cycle, one per component; log time = window_end."
        fields = {f.name: _property(f) for f in declared if f.name in COMPONENT_FIELDS}
        fields["probabilities"] = {"type": "object", "additionalProperties": number,
                                   "description": "Probability of every trained state of the component, 0 to 1."}
        component = {"type": "object", "properties": fields, "required": ["state", "probability", "probabilities"]}
        properties["components"] = {
            "type": "object", "description": "Each component's verdict on the cycle (cycle_verdict's fields; null and "
                                             "non-finite left out).",
            "properties": {c: {**component, "properties": {**fields, "probabilities": {
                **fields["probabilities"], "properties": {k: number for k in v.get("probabilities", {})}}}}
                for c, v in example.get("components", {}).items()},
            "additionalProperties": component}
        required.append("components")
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


__all__ = ["COMPONENT_FIELDS", "EXPECTED_SENSOR_FIELDS", "FORECAST_PART_FIELDS", "KINDS", "json_schema"]
