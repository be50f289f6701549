"""A rig description: the channels of a hydraulic rig, how its data is cut into windows, its labels.

A description is a small TOML file (docs/rigs.md gives every key); :func:`load_rig` reads and
validates one, :func:`parse_rig` validates the parsed tables, and every error names the file,
the key and what is wrong. The channels build on :class:`hydrowatch.channels.ChannelSet`, so
a rig without a command channel (one that repeats a fixed load cycle) is allowed. What a
description holds (:class:`RigDescription`, :class:`Window`, :class:`Sampling`, :class:`Label`)
is :mod:`hydrowatch.rig.spec`; this module reads, validates and finds descriptions.

Shape of a description::

    name = "uci-hydraulic"
    [window]      kind = "cycle" | "fixed", length_s, hop_s (fixed only), grid_hz
    [layout]      kind = "wide" | "long", delimiter (wide), time_column (long)
    [channels.<name>]  unit, role, rate_hz, source (file or column), scale, offset, note
    [labels]      source (file; absent: a per-row column of the recording), delimiter
    [labels.<component>]  column, values, healthy, unit, names, component (false for a flag)

A channel's value in hydrowatch is ``scale * raw + offset`` (its ``unit`` is the unit after
scaling).
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from hydrowatch.channels import ROLES, Channel, ChannelSet
from hydrowatch.errors import DataError, ParameterError
from hydrowatch.rig.spec import (
    LAYOUTS,
    WINDOW_KINDS,
    Label,
    LabelValue,
    RigDescription,
    Sampling,
    Window,
    label_text,
)

__all__ = [  # the description's data lives in hydrowatch.rig.spec; importable from here as before
    "BUILTIN",
    "DATA_ENV",
    "LAYOUTS",
    "WINDOW_KINDS",
    "Label",
    "LabelValue",
    "RigDescription",
    "Sampling",
    "Window",
    "builtin_rig",
    "data_root",
    "label_text",
    "load_rig",
    "parse_rig",
    "rig_from_text",
    "rig_text",
]

class _Reader:
    """Typed access to one table of the description; errors name the file and the dotted key."""

    def __init__(self, table: Mapping[str, Any], key: str, source: str) -> None:
        self.table, self.key, self.source = table, key, source

    def where(self, name: str) -> str:
        return f"{self.key}.{name}" if self.key else name

    def fail(self, name: str, what: str, got: Any) -> DataError:
        return DataError(f"key '{self.where(name)}' must be {what}. Got {got!r}.", self.source)

    def get(self, name: str, kinds: tuple[type, ...], what: str, default: Any = ...) -> Any:
        if name not in self.table:
            if default is ...:
                raise DataError(f"key '{self.where(name)}' must be given ({what}). It is missing.", self.source)
            return default
        value = self.table[name]
        if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
            raise self.fail(name, what, value)
        return value

    def text(self, name: str, default: Any = ...) -> Any:
        return self.get(name, (str,), "a string", default)

    def number(self, name: str, default: Any = ..., positive: bool = False) -> Any:
        what = "a positive number" if positive else "a finite number"
        if name not in self.table and default is not ...:
            return default
        value = self.get(name, (int, float), what)
        if not math.isfinite(value) or (positive and value <= 0):
            raise self.fail(name, what, value)
        return float(value)

    def choice(self, name: str, options: tuple[str, ...], default: Any = ...) -> Any:
        value = self.text(name, default)
        if value not in options:
            raise self.fail(name, f"one of {list(options)}", value)
        return value

    def sub(self, name: str, default: Any = ...) -> _Reader:
        table = self.get(name, (dict,), "a table", {} if default is not ... else ...)
        return _Reader(table, self.where(name), self.source)

    def only(self, allowed: tuple[str, ...], tables: bool = False) -> None:
        """Refuse unknown keys (a typo must not be ignored); ``tables``: sub-tables are allowed too."""
        for name, value in self.table.items():
            if name not in allowed and not (tables and isinstance(value, dict)):
                raise DataError(
                    f"key '{self.where(name)}' is not a known key. Known keys here: {list(allowed)}.", self.source
                )


def _window(reader: _Reader) -> Window:
    reader.only(("kind", "length_s", "hop_s", "grid_hz"))
    kind = reader.choice("kind", WINDOW_KINDS)
    length = reader.number("length_s", positive=True)
    hop = reader.number("hop_s", positive=True) if kind == "fixed" else reader.number("hop_s", length, True)
    if kind == "cycle" and hop != length:
        raise reader.fail("hop_s", f"the cycle length {length} for kind 'cycle' (or absent)", hop)
    grid = reader.number("grid_hz", positive=True)
    for key, seconds in (("length_s", length), ("hop_s", hop)):
        samples = seconds * grid
        if abs(samples - round(samples)) > 1e-9 * samples:
            raise reader.fail("grid_hz", f"such that {key} * grid_hz is a whole number of samples ({seconds} s)", grid)
    return Window(kind, length, hop, grid)


def _channel(reader: _Reader, name: str, grid_hz: float) -> tuple[Channel, Sampling]:
    reader.only(("unit", "role", "rate_hz", "recorded_hz", "source", "scale", "offset", "note", "optional"))
    role = reader.choice("role", ROLES)
    rate = reader.number("rate_hz", positive=True)
    ratio = rate / grid_hz
    if ratio < 1 or abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise reader.fail("rate_hz", f"a whole multiple of window.grid_hz = {grid_hz} Hz (block means)", rate)
    scale = reader.number("scale", 1.0)
    if scale == 0:
        raise reader.fail("scale", "non-zero", scale)
    try:
        channel = Channel(name, reader.text("unit"), role, reader.get("optional", (bool,), "true or false", False))
    except ParameterError as e:
        raise DataError(f"table '{reader.key}': {e}", reader.source) from None
    recorded = reader.number("recorded_hz", None, positive=True)
    if recorded is not None and recorded < rate:
        raise reader.fail("recorded_hz", f"at least rate_hz = {rate} (stored values come from the recording)", recorded)
    sampling = Sampling(
        rate, reader.text("source", name), scale, reader.number("offset", 0.0), reader.text("note", ""), recorded
    )
    return channel, sampling


def _label_value(reader: _Reader, name: str, value: Any) -> LabelValue:
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise reader.fail(name, "a string or a number", value)
    return value if isinstance(value, str) else float(value)


def _label(reader: _Reader, name: str, has_file: bool) -> Label:
    reader.only(("column", "values", "healthy", "unit", "names", "component"))
    column = reader.get("column", (int,), "a column index from 0", None)
    if has_file and (column is None or column < 0):
        raise reader.fail("column", "a column index from 0 (labels.source names a file)", column)
    raw = reader.get("values", (list,), "a non-empty list of the label's values")
    values = tuple(_label_value(reader, "values", v) for v in raw)
    if not values or len({type(v) for v in values}) != 1 or len(set(values)) != len(values):
        raise reader.fail("values", "a non-empty list of distinct values, all strings or all numbers", raw)
    healthy = _label_value(reader, "healthy", reader.get("healthy", (str, int, float), "one of the values"))
    if healthy not in values:
        raise reader.fail("healthy", f"one of the values {list(raw)}", healthy)
    names = {}
    for key, meaning in reader.sub("names", {}).table.items():
        value = key if isinstance(values[0], str) else _number_key(reader, key)
        if value not in values or not isinstance(meaning, str):
            raise reader.fail(f"names.{key}", f"a string naming one of the values {list(raw)}", meaning)
        names[value] = meaning
    component = reader.get("component", (bool,), "true or false", True)
    return Label(name, column, values, healthy, reader.text("unit", ""), names, component)


def _number_key(reader: _Reader, key: str) -> float:
    try:
        return float(key)
    except ValueError:
        raise reader.fail(f"names.{key}", "keyed by one of the numeric values", key) from None


def parse_rig(data: Mapping[str, Any], source: str = "<rig>") -> RigDescription:
    """Validate parsed TOML tables into a :class:`RigDescription` (errors name ``source`` and the key)."""
    top = _Reader(data, "", source)
    top.only(("name", "description", "window", "layout", "channels", "labels"))
    window = _window(top.sub("window"))
    layout = top.sub("layout")
    layout.only(("kind", "delimiter", "time_column"))
    kind = layout.choice("kind", LAYOUTS)
    channels_table = top.sub("channels")
    if not channels_table.table:
        raise DataError("table 'channels' must declare at least one channel. It is empty.", source)
    channels, sampling = [], {}
    for name in channels_table.table:
        channel, sampled = _channel(channels_table.sub(name), name, window.grid_hz)
        channels.append(channel)
        sampling[name] = sampled
    try:
        channel_set = ChannelSet(tuple(channels))
    except ParameterError as e:
        raise DataError(f"table 'channels': {e}", source) from None
    labels_table = top.sub("labels", {})
    labels_table.only(("source", "delimiter"), tables=True)
    label_file = labels_table.text("source", None)
    labels = tuple(
        _label(labels_table.sub(n), n, label_file is not None)
        for n, v in labels_table.table.items()
        if isinstance(v, dict)
    )
    columns = [label.column for label in labels if label.column is not None]
    if len(set(columns)) != len(columns):
        raise DataError(f"table 'labels' must give each label its own column. Got columns {columns}.", source)
    return RigDescription(
        name=top.text("name"),
        channels=channel_set,
        sampling=sampling,
        window=window,
        layout=kind,
        labels=labels,
        label_source=label_file,
        delimiter=layout.text("delimiter", "\t"),
        time_column=layout.text("time_column", "t"),
        description=top.text("description", ""),
    )


def load_rig(path: str | Path) -> RigDescription:
    """Read and validate a rig description file (TOML)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DataError("rig description file must exist. It does not.", str(path)) from None
    return rig_from_text(text, str(path))


BUILTIN = ("uci-hydraulic",)
"""Rig descriptions shipped with hydrowatch (``hydrowatch/rig/<name>.toml``); the plant is
:func:`hydrowatch.rig.plant.plant_rig`, built from :data:`hydrowatch.channels.PLANT`."""


def builtin_rig(name: str) -> RigDescription:
    """A rig description shipped with hydrowatch, by name (one of :data:`BUILTIN`)."""
    if name not in BUILTIN:
        raise ParameterError(f"rig must be one of {list(BUILTIN)} or a path to a .toml file. Got {name!r}.")
    with resources.as_file(resources.files("hydrowatch.rig") / f"{name}.toml") as path:
        return load_rig(path)


def rig_text(rig: str) -> tuple[RigDescription, str]:
    """A shipped description (by name) or a .toml file, and its TOML text (what a model bundle keeps of its rig).

    Raises
    ------
    DataError, ParameterError
        As :func:`load_rig` and :func:`builtin_rig`.
    """
    if rig in BUILTIN:
        with resources.as_file(resources.files("hydrowatch.rig") / f"{rig}.toml") as path:
            return load_rig(path), path.read_text(encoding="utf-8")
    if not rig.endswith(".toml"):
        raise ParameterError(f"rig must be one of {list(BUILTIN)} or a path to a .toml file. Got {rig!r}.")
    return load_rig(rig), Path(rig).read_text(encoding="utf-8")


def rig_from_text(text: str, source: str) -> RigDescription:
    """Parse and validate a description's TOML ``text`` (``source`` names it in errors)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"rig description must be valid TOML: {e}.", source) from None
    return parse_rig(data, source)


DATA_ENV = "HYDROWATCH_DATA"
"""Environment variable naming the shared data folder (default: ``../shared/data`` from the repository)."""


def data_root() -> Path:
    """The shared data folder: ``$HYDROWATCH_DATA``, else ``../shared/data`` beside the repository root.

    Real recordings (the UCI rig's ``uci-hydraulic/``) live there, never in the project's git.
    """
    configured = os.environ.get(DATA_ENV)
    return Path(configured) if configured else Path(__file__).resolve().parents[2].parent / "shared" / "data"
