"""Checks every recording passes on its way in, whatever its format: time base, NaN, labels, units.

Rows are counted from 0 (the first data row; a CSV header is not a row). Each check raises a
one-line :class:`DataError` that names the file, the row (and its time) and the fix.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

import numpy as np

from hydrowatch.channels import PLANT
from hydrowatch.errors import DataError
from hydrowatch.recording import SAMPLE_RATE_HZ, UNITS

FAULTS: tuple[str, ...] = ("load", "pump_leak", "motor_leak", "valve_leak", "valve_coil", "relief_spring")
"""Faults a recording may be labelled with (the plant's fault catalogue)."""
SEVERITIES: tuple[str, ...] = ("warning", "alert")
HEALTH_STATE = re.compile(rf"^(healthy|({'|'.join(FAULTS)})_({'|'.join(SEVERITIES)}))$")
"""A known health label: ``healthy`` or ``<fault>_<warning|alert>``."""

TIME_TOLERANCE = 0.05
"""Allowed deviation of a sample spacing from 1/200 s, as a fraction of it (0.25 ms)."""

UNIT_ALIASES: dict[str, frozenset[str]] = {
    "s": frozenset({"s", "sec", "seconds"}),
    "V": frozenset({"V", "v", "volt", "volts"}),
    "L/min": frozenset({"L/min", "l/min", "lpm", "LPM"}),
    "rad/s": frozenset({"rad/s", "rad s-1"}),
    "N·m": frozenset({"N·m", "N*m", "Nm", "N m", "N.m"}),
    "bar": frozenset({"bar"}),
    "°C": frozenset({"°C", "degC", "C", "deg C"}),
}
"""Spellings accepted for each contract unit (no conversion is done: other units are an error)."""


def check_state(label: str, source: str | None = None, where: str = "") -> str:
    """Return ``label`` if it is a known health state, else raise :class:`DataError`."""
    if not isinstance(label, str) or not HEALTH_STATE.match(label):
        raise DataError(
            f"health label{where} must be 'healthy' or '<fault>_<warning|alert>' with fault one of "
            f"{', '.join(FAULTS)}. Got {label!r}. Fix the label or leave it out.",
            source,
        )
    return label


def check_labels(labels: np.ndarray, t: np.ndarray, source: str | None = None) -> str | None:
    """Check a per-row ``state`` column; return its value when constant, else None.

    Parameters
    ----------
    labels : ndarray of str, shape (n,)
    t : ndarray, shape (n,)
        Sample times, s (to name the row of a bad label).
    """
    values, first = np.unique(labels.astype(str), return_index=True)
    for value, row in zip(values, first):
        check_state(str(value), source, f" in row {row} (t={t[row]:.3f} s)")
    return str(values[0]) if len(values) == 1 else None


def check_unit(column: str, unit: str | None, source: str | None = None) -> None:
    """Check that the unit a file declares for ``column`` is the contract's (None: not declared)."""
    expected = UNITS.get(column)
    if unit is None or not unit or expected is None:
        return
    if unit.strip() not in UNIT_ALIASES.get(expected, frozenset({expected})):
        raise DataError(f"column '{column}' must be in {expected}. Got {unit!r}. Convert it to {expected}.", source)


def check_time_base(
    t: np.ndarray, source: str | None = None, rate_hz: float = SAMPLE_RATE_HZ, column: str = "t"
) -> None:
    """Check that ``t`` [s] (the file's ``column``) is finite, strictly increasing and 1/``rate_hz`` apart.

    Raises
    ------
    DataError
        At the first bad row, with its time and the size of the step.
    """
    if t.shape[0] == 0:
        raise DataError("recording must have at least one sample. Got none.", source)
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise DataError(f"column '{column}' must be finite. Got {t[bad[0]]} in row {bad[0]}.", source)
    dt = 1.0 / rate_hz
    step = np.diff(t)
    back = np.flatnonzero(step <= 0)
    if back.size:
        row = int(back[0]) + 1
        raise DataError(
            f"column '{column}' must be strictly increasing. Got {column}={t[row]:.6f} s in row {row} after "
            f"{column}={t[row - 1]:.6f} s. Sort the rows and drop duplicates.",
            source,
        )
    off = np.flatnonzero(np.abs(step - dt) > TIME_TOLERANCE * dt)
    if off.size:
        row = int(off[0]) + 1
        missing = step[off[0]] / dt - 1.0
        raise DataError(
            f"samples must be {dt * 1e3:g} ms apart ({rate_hz:g} Hz). Got a step of {step[off[0]] * 1e3:.3f} ms "
            f"before row {row} ({column}={t[row]:.6f} s, about {missing:.1f} samples missing); {off.size} such steps "
            f"in all. Split the recording at gaps or resample it to {rate_hz:g} Hz.",
            source,
        )


def nan_runs(values: np.ndarray) -> list[tuple[int, int]]:
    """Runs of consecutive NaN as ``(first_row, last_row)`` pairs, in order."""
    isnan = np.isnan(values)
    if not isnan.any():
        return []
    edges = np.diff(np.concatenate(([0], isnan.astype(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(int(a), int(b)) for a, b in zip(starts, stops)]


def check_channels(
    t: np.ndarray, channels: Mapping[str, np.ndarray], source: str | None = None,
    required: Sequence[str] | None = None,
) -> dict[str, np.ndarray]:
    """Check the channels a use needs are present and NaN-free; drop the others that are all NaN.

    ``required``: the channels this use needs; None (default) is the plant's rule, the command and at least one
    sensor (:meth:`PLANT.missing <hydrowatch.channels.ChannelSet.missing>`: a recording of any subset of the
    sensors reads); ``identify`` needs only its input and output. A channel outside it that is all NaN is dropped
    like an optional one (a sensor column left empty is a sensor the machine does not have).

    Returns
    -------
    dict of str to ndarray
        The channels to keep (an optional channel with no value at all is left out).
    """
    needed = tuple(c for c in PLANT.required if c in channels) if required is None else tuple(required)
    present = [c for c in channels if c in needed or not np.isnan(channels[c]).all()]
    missing = PLANT.missing(present) if required is None else [c for c in needed if c not in channels]
    if missing:
        add = [c for c in missing if c in UNITS] + [c for c in PLANT.sensors if c not in present and len(missing) >
                                                     sum(m in UNITS for m in missing)]
        units = ", ".join(f"{c} [{UNITS[c]}]" for c in add)
        wanted = (f"the command '{PLANT.command}' and at least one sensor of {list(PLANT.sensors)}"
                  if required is None else f"columns {['t', *needed]}")
        raise DataError(f"{wanted} must be present. Got no {missing}; the file has {['t', *present]}. "
                        f"Add them (units: {units}).", source)
    kept = {}
    for name, values in channels.items():
        if name not in needed and np.isnan(values).all():
            continue
        runs = nan_runs(values)
        if runs:
            first, last = runs[0]
            raise DataError(
                f"column '{name}' must have no NaN. Got NaN in rows {first}-{last} "
                f"(t={t[first]:.3f}-{t[last]:.3f} s, {last - first + 1} samples; {len(runs)} run(s) in all). "
                "Cut the recording around the gap or fill it.",
                source,
            )
        kept[name] = values
    return kept


__all__ = [
    "FAULTS",
    "HEALTH_STATE",
    "SEVERITIES",
    "TIME_TOLERANCE",
    "UNIT_ALIASES",
    "check_channels",
    "check_labels",
    "check_state",
    "check_time_base",
    "check_unit",
    "nan_runs",
]
