"""What a rig description says: its window, each channel's sampling, its labels, the whole :class:`RigDescription`.

Plain frozen data; reading and validating a description's TOML is :mod:`hydrowatch.rig.description` (docs/rigs.md
gives every key).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field

from hydrowatch.channels import ChannelSet
from hydrowatch.errors import ParameterError

WINDOW_KINDS = ("cycle", "fixed")
"""``cycle``: one window per load cycle of ``length_s``; ``fixed``: windows of ``length_s`` every ``hop_s``."""
LAYOUTS = ("wide", "long")
"""``wide``: one file per channel, rows = cycles, columns = samples (the UCI layout);
``long``: one table, rows = samples, a time column and one column per channel (CSV/Parquet)."""
LabelValue = str | float
"""A label value: a name (``"healthy"``) or a number (a cooler efficiency of 20 %)."""


def label_text(value: object) -> str:
    """A label value as text, as a description writes it: ``100`` for 100.0, ``2.5``, or the name itself."""
    return f"{value:g}" if isinstance(value, numbers.Real) else str(value)


@dataclass(frozen=True)
class Window:
    """How a rig's data is cut into the windows that are judged.

    Parameters
    ----------
    kind : str
        One of :data:`WINDOW_KINDS`.
    length_s : float
        Cycle length (``cycle``) or window length (``fixed``), s.
    hop_s : float
        Time between the starts of consecutive windows, s (``length_s`` for ``cycle``).
    grid_hz : float
        Common sample rate every channel is resampled onto, Hz; every channel's ``rate_hz`` is an
        integer multiple of it (block means, :func:`hydrowatch.io.wide.block_means`).
    """

    kind: str
    length_s: float
    hop_s: float
    grid_hz: float

    @property
    def samples(self) -> int:
        """Samples per window on the common grid."""
        return round(self.length_s * self.grid_hz)


@dataclass(frozen=True)
class Sampling:
    """Where a channel's values come from and how they are turned into the channel's unit.

    Parameters
    ----------
    rate_hz : float
        Sample rate of the values as stored, Hz.
    source : str
        File name (``wide`` layout) or column name (``long``) holding the channel.
    scale, offset : float
        The channel's value is ``scale * raw + offset``.
    note : str
        Free text, e.g. how the stored values were derived from the original recording.
    recorded_hz : float or None
        Rate the sensor was recorded at, Hz, when the stored values were reduced from a faster
        recording (the UCI copy's 1 s means of 100 Hz pressures); None: ``rate_hz``.
    """

    rate_hz: float
    source: str
    scale: float = 1.0
    offset: float = 0.0
    note: str = ""
    recorded_hz: float | None = None

    @property
    def original_hz(self) -> float:
        """Rate the sensor was recorded at, Hz (``recorded_hz``, else ``rate_hz``)."""
        return self.rate_hz if self.recorded_hz is None else self.recorded_hz


@dataclass(frozen=True)
class Label:
    """A condition label: one component's state (or a flag) given per cycle or per row.

    Parameters
    ----------
    name : str
        Component name, e.g. ``"accumulator"``.
    column : int or None
        Column (from 0) in the label file; None when labels are a per-row column of the recording.
    values : tuple
        Every value the label may take, in the order the description lists them.
    healthy : str or float
        The value of a healthy component (one of ``values``).
    unit : str
        Unit of numeric values ("" for names).
    names : dict
        Optional meaning of each value, e.g. ``{3.0: "close to total failure"}``.
    component : bool
        False for a flag that is not a component's condition (the UCI "stable" flag).
    """

    name: str
    column: int | None
    values: tuple[LabelValue, ...]
    healthy: LabelValue
    unit: str = ""
    names: dict[LabelValue, str] = field(default_factory=dict)
    component: bool = True


@dataclass(frozen=True)
class RigDescription:
    """One rig: channels, their sampling, the window, the layout of its files and its labels."""

    name: str
    channels: ChannelSet
    sampling: dict[str, Sampling]
    window: Window
    layout: str
    labels: tuple[Label, ...]
    label_source: str | None = None
    delimiter: str = "\t"
    time_column: str = "t"
    description: str = ""

    @property
    def components(self) -> tuple[str, ...]:
        """Names of the labels that are component conditions (flags excluded)."""
        return tuple(label.name for label in self.labels if label.component)

    def recorded_at_least(self, hz: float) -> tuple[str, ...]:
        """Channels recorded at ``hz`` or faster (before any reduction of the stored copy), in order."""
        return tuple(name for name in self.channels.names if self.sampling[name].original_hz >= hz)

    def label(self, name: str) -> Label:
        """The label called ``name``."""
        for label in self.labels:
            if label.name == name:
                return label
        raise ParameterError(f"label must be one of {[x.name for x in self.labels]}. Got {name!r}.")
