"""Arrow schemas of every hydrowatch message, built from the declarations in ``schemas/``.

The JSON files ``schemas/<name>.v<version>.json`` at the repository root are the one source of
truth (language-neutral, so a rig gateway in another language can read them); this module turns
them into :class:`pyarrow.Schema` objects. Every field carries metadata ``unit`` and
``description``; every schema carries ``hydrowatch.schema`` (its name) and
``hydrowatch.schema_version``. Set ``HYDROWATCH_SCHEMAS`` to a folder to read the declarations from
elsewhere (an installed wheel that does not ship the repository).
"""

from __future__ import annotations

import json
import os
import re
import sys
from functools import cache
from pathlib import Path
from typing import Any, NamedTuple

import pyarrow as pa

from hydrowatch.errors import DataError

SCHEMA_VERSION = 2
"""Version of ``sensor_chunk`` (the samples a recording holds) that hydrowatch writes, kept for readers of recording
metadata (a test keeps it equal to ``current_version("sensor_chunk")``); each schema has its own current version
(:func:`current_version`): the highest one declared in ``schemas/``."""

NAME_KEY = b"hydrowatch.schema"
VERSION_KEY = b"hydrowatch.schema_version"
ONE_OR_MORE_KEY = b"hydrowatch.one_or_more_of"
"""Schema metadata of a declaration with ``one_or_more_of``: the JSON list of optional fields of which every message
must have at least one (``sensor_chunk`` v2: the sensors)."""
OPTIONAL_KEY = b"optional"
"""Field metadata of a declared field with ``"optional": true``: it may be left out of a message but, when
present, holds no nulls (unlike a ``nullable`` field, which may also be null)."""

_FILE_NAME = re.compile(r"^(?P<name>[a-z_]+)\.v(?P<version>\d+)\.json$")
_SCALAR_TYPES: dict[str, pa.DataType] = {
    "float64": pa.float64(),
    "float32": pa.float32(),
    "int64": pa.int64(),
    "int32": pa.int32(),
    "bool": pa.bool_(),
    "string": pa.string(),
}


class SchemaMismatchError(DataError):
    """A message of another schema (or with no hydrowatch schema metadata) than the one expected."""


class SchemaVersionError(DataError):
    """A message of the expected schema but another version."""


def schemas_dir() -> Path:
    """Folder that holds the schema declarations.

    ``$HYDROWATCH_SCHEMAS`` when set, else ``schemas/`` next to the ``hydrowatch`` package (a
    repository checkout or an editable install), else ``<prefix>/share/hydrowatch/schemas`` where a
    wheel installs them (pyproject's data-files).
    """
    override = os.environ.get("HYDROWATCH_SCHEMAS")
    folder = Path(override) if override else Path(__file__).resolve().parent.parent / "schemas"
    if not override and not folder.is_dir():
        folder = Path(sys.prefix) / "share" / "hydrowatch" / "schemas"
    if not folder.is_dir():
        raise DataError(
            f"the schema folder must exist. Got {str(folder)!r}. Set HYDROWATCH_SCHEMAS to the "
            "repository's schemas/ folder or install hydrowatch in editable mode (pip install -e .)."
        )
    return folder


def _arrow_type(spec: Any, source: str) -> pa.DataType:
    if isinstance(spec, str):
        if spec not in _SCALAR_TYPES:
            raise DataError(f"field type must be one of {sorted(_SCALAR_TYPES)}. Got {spec!r}.", source)
        return _SCALAR_TYPES[spec]
    if isinstance(spec, dict) and set(spec) == {"list"}:
        return pa.list_(_arrow_type(spec["list"], source))
    if isinstance(spec, dict) and set(spec) == {"struct"}:
        return pa.struct([_arrow_field(f, source) for f in spec["struct"]])
    raise DataError(f"field type must be a name, {{'list': T}} or {{'struct': [fields]}}. Got {spec!r}.", source)


def _arrow_field(spec: dict[str, Any], source: str) -> pa.Field:
    missing = {"name", "type", "unit", "nullable", "description"} - set(spec)
    if missing:
        raise DataError(f"field declaration must have keys {sorted(missing)}. Got {sorted(spec)}.", source)
    metadata = {"unit": spec["unit"], "description": spec["description"]}
    if spec.get("optional"):
        metadata[OPTIONAL_KEY.decode()] = "true"
    return pa.field(spec["name"], _arrow_type(spec["type"], source), nullable=bool(spec["nullable"]), metadata=metadata)


def may_be_absent(field: pa.Field) -> bool:
    """Whether a declared field may be left out of a message (``nullable`` or ``optional`` in its declaration)."""
    return bool(field.nullable) or (field.metadata or {}).get(OPTIONAL_KEY) == b"true"


def _load(path: Path) -> pa.Schema:
    source = str(path)
    try:
        spec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(f"schema declaration must be readable JSON. Got: {exc}.", source) from None
    match = _FILE_NAME.match(path.name)
    if match is None or spec.get("name") != match["name"] or spec.get("version") != int(match["version"]):
        raise DataError(
            f"schema declaration name and version must match its file name. Got name={spec.get('name')!r}, "
            f"version={spec.get('version')!r}.",
            source,
        )
    fields = [_arrow_field(f, source) for f in spec["fields"]]
    metadata = {
        NAME_KEY: spec["name"].encode(),
        VERSION_KEY: str(spec["version"]).encode(),
        b"hydrowatch.description": spec.get("description", "").encode(),
    }
    group = spec.get("one_or_more_of")
    if group is not None:
        optional = {f.name for f in fields if may_be_absent(f)}
        if not isinstance(group, list) or not group or not set(group) <= optional:
            raise DataError(f"one_or_more_of must be a non-empty list of fields among the optional ones "
                            f"{sorted(optional)}. Got {group!r}.", source)
        metadata[ONE_OR_MORE_KEY] = json.dumps(group).encode()
    return pa.schema(fields, metadata=metadata)


@cache
def _all_schemas() -> dict[tuple[str, int], pa.Schema]:
    found: dict[tuple[str, int], pa.Schema] = {}
    for path in sorted(schemas_dir().glob("*.json")):
        match = _FILE_NAME.match(path.name)
        if match is not None:
            found[(match["name"], int(match["version"]))] = _load(path)
    return found


def current_version(name: str) -> int:
    """The version of schema ``name`` that hydrowatch writes: the highest declared (``schemas/<name>.v<N>.json``).

    Older declared versions stay readable (:func:`validate`); a message of a newer one is refused.
    """
    versions = [v for n, v in _all_schemas() if n == name]
    if not versions:
        raise DataError(f"schema must be one of {sorted({n for n, _ in _all_schemas()})}. Got {name!r}.")
    return max(versions)


def schema_by_name(name: str, version: int | None = None) -> pa.Schema:
    """The declared schema ``name`` at ``version`` (default: its :func:`current_version`).

    Raises
    ------
    DataError
        When no declaration ``schemas/<name>.v<version>.json`` exists.
    """
    version = current_version(name) if version is None else int(version)
    schemas = _all_schemas()
    if (name, version) not in schemas:
        known = sorted(f"{n}.v{v}" for n, v in schemas)
        raise DataError(f"schema must be one of {known}. Got {name}.v{version}.")
    return schemas[(name, version)]


def schema_name(schema: pa.Schema) -> str | None:
    """Name in the schema's ``hydrowatch.schema`` metadata, or None when it has none."""
    value = (schema.metadata or {}).get(NAME_KEY)
    return value.decode() if value is not None else None


def schema_version(schema: pa.Schema) -> int | None:
    """Version in the schema's ``hydrowatch.schema_version`` metadata, or None when absent or not an integer."""
    value = (schema.metadata or {}).get(VERSION_KEY)
    try:
        return int(value) if value is not None else None
    except ValueError:
        return None


def units(schema: pa.Schema) -> dict[str, str]:
    """Unit of every field that has one, e.g. ``{"t": "s", "flow": "L/min", ...}``."""
    out = {}
    for f in schema:
        unit = (f.metadata or {}).get(b"unit", b"").decode()
        if unit:
            out[f.name] = unit
    return out


@cache
def _wire_schema(name: str, version: int) -> pa.Schema:
    declared = schema_by_name(name, version)
    fields = [f.with_metadata({b"unit": (f.metadata or {}).get(b"unit", b"")}) for f in declared]
    return pa.schema(fields, metadata={NAME_KEY: name.encode(), VERSION_KEY: str(version).encode()})


def wire_schema(schema: pa.Schema) -> pa.Schema:
    """``schema`` as sent in messages: field metadata ``unit`` only, schema metadata name and version.

    Field descriptions stay in ``schemas/`` (they would add ~1.6 kB to every sensor chunk); build
    messages against this schema. Nested fields keep their declared metadata.
    """
    name, version = schema_name(schema), schema_version(schema)
    if name is None or version is None:
        raise DataError(f"schema must carry hydrowatch name and version metadata. Got {schema.metadata}.")
    return _wire_schema(name, version)


def one_or_more_of(schema: pa.Schema) -> tuple[str, ...]:
    """Fields of which every message of the declared ``schema`` must have at least one (empty: no such rule)."""
    raw = (schema.metadata or {}).get(ONE_OR_MORE_KEY)
    return tuple(json.loads(raw)) if raw else ()


def describe(schema: pa.Schema) -> str:
    """One line per field: ``name type [unit] (optional) — description``."""
    lines = [f"{schema_name(schema)} v{schema_version(schema)}"]
    for f in schema:
        meta = f.metadata or {}
        unit = meta.get(b"unit", b"").decode()
        optional = " (optional)" if may_be_absent(f) else ""
        lines.append(
            f"  {f.name} {f.type}{f' [{unit}]' if unit else ''}{optional} — {meta.get(b'description', b'').decode()}"
        )
    return "\n".join(lines)


class _Spec(NamedTuple):
    name: bytes
    version: bytes
    fields: dict[str, tuple[pa.DataType, bool, bool]]
    """Name → (type, nullable, may be absent)."""
    names: frozenset[str]
    one_or_more: tuple[str, ...]


_SPECS: dict[int, tuple[pa.Schema, _Spec]] = {}


def _spec(schema: pa.Schema) -> _Spec:
    """What :func:`validate` compares, cached per schema object (validation is on the hot path)."""
    cached = _SPECS.get(id(schema))
    if cached is None or cached[0] is not schema:
        meta = schema.metadata or {}
        fields = {f.name: (f.type, f.nullable, may_be_absent(f)) for f in schema}
        spec = _Spec(meta.get(NAME_KEY, b""), meta.get(VERSION_KEY, b""), fields, frozenset(fields),
                     one_or_more_of(schema))
        cached = (schema, spec)
        _SPECS[id(schema)] = cached
    return cached[1]


def validate(
    batch: pa.RecordBatch | pa.Table, schema: pa.Schema, source: str | None = None, *, require_metadata: bool = False
) -> None:
    """Check that ``batch`` is a valid message of ``schema``.

    Every field must have the declared type; a non-nullable field must hold no nulls and be present unless
    declared ``optional``; nullable fields may be absent; at least one of a declaration's ``one_or_more_of``
    must be present; no undeclared field may appear. When the batch carries hydrowatch schema
    metadata (it must with ``require_metadata``), its name must be the expected one and its version the
    expected one or an older declared version of it (then the batch is checked against that version's
    declaration: a reader of version N reads every version up to N).

    Raises
    ------
    SchemaMismatchError, SchemaVersionError
        The batch says it is another schema (or nothing, with ``require_metadata``), or another
        version of this one.
    DataError
        Naming ``source`` and the offending field.
    """
    spec = _spec(schema)
    expected = spec.name.decode()
    got_schema = batch.schema
    meta = got_schema.metadata or {}
    got_name = meta.get(NAME_KEY)
    if got_name is None and require_metadata:
        raise SchemaMismatchError(
            f"message must carry schema metadata 'hydrowatch.schema'={expected!r}. Got none "
            "(a message not built from hydrowatch.schemas).",
            source,
        )
    if got_name is not None and got_name != spec.name:
        raise SchemaMismatchError(f"message schema must be {expected!r}. Got {got_name.decode()!r}.", source)
    if got_name is not None and meta.get(VERSION_KEY) != spec.version:
        got_version, wanted = schema_version(got_schema), int(spec.version.decode())
        if got_version is None or got_version > wanted or (expected, got_version) not in _all_schemas():
            raise SchemaVersionError(
                f"{expected} schema version must be {wanted} or an older declared one. Got {got_version}. "
                "Upgrade the reader so that it speaks the writer's version.",
                source,
            )
        spec = _spec(_all_schemas()[(expected, got_version)])  # an older version: its own declaration
    names = got_schema.names
    got = dict(zip(names, got_schema.types))
    if not spec.names.issuperset(got):
        unknown = sorted(set(got) - spec.names)
        raise DataError(f"{expected} fields must be among {schema.names}. Got unknown {unknown}.", source)
    if spec.one_or_more and not any(name in got for name in spec.one_or_more):
        raise DataError(f"{expected} must have at least one of the fields {list(spec.one_or_more)}. Got "
                        f"{list(names)}.", source)
    for name, (dtype, nullable, optional) in spec.fields.items():
        if name not in got:
            if not optional:
                raise DataError(f"{expected} field '{name}' must be present. Got none.", source)
            continue
        if got[name] != dtype:
            raise DataError(f"{expected} field '{name}' must have type {dtype}. Got {got[name]}.", source)
        if not nullable:
            nulls = batch.column(names.index(name)).null_count
            if nulls:
                raise DataError(f"{expected} field '{name}' must have no nulls. Got {nulls}.", source)


SENSOR_CHUNK = schema_by_name("sensor_chunk")
"""Chunk of consecutive samples (t, voltage, at least one of flow, speed, torque, optional channels and state)."""
KL_WINDOW = schema_by_name("kl_window")
"""Relative entropies of one window, one row per sensor × state."""
HEALTH_VERDICT = schema_by_name("health_verdict")
"""One verdict per window: state, probabilities, window bounds, model version."""
STATUS = schema_by_name("status")
"""Heartbeat of a service: status string and message counters."""
FORECAST = schema_by_name("forecast")
"""When each part of one machine will reach the alert, one row per part (the scorer, every few windows)."""
EXPECTED_WINDOW = schema_by_name("expected_window")
"""What the model expected one window's sensors to read, beside what they read, one row per sensor (chart points)."""
RIG_CYCLES = schema_by_name("rig_cycles")
"""Whole cycles of one machine of any rig, one row per cycle, every channel on the rig's grid (docs/rigs.md)."""
CYCLE_VERDICT = schema_by_name("cycle_verdict")
"""A cycles bundle's verdicts, one row per cycle and component (the scorer)."""

__all__ = [
    "CYCLE_VERDICT",
    "EXPECTED_WINDOW",
    "FORECAST",
    "HEALTH_VERDICT",
    "KL_WINDOW",
    "RIG_CYCLES",
    "SCHEMA_VERSION",
    "SENSOR_CHUNK",
    "STATUS",
    "SchemaMismatchError",
    "SchemaVersionError",
    "current_version",
    "describe",
    "may_be_absent",
    "one_or_more_of",
    "schema_by_name",
    "schema_name",
    "schema_version",
    "schemas_dir",
    "units",
    "validate",
    "wire_schema",
]
