"""The channels of a machine, declared once: name, unit, role, whether a recording may lack it.

Every list of channels in hydrowatch is a view of one :class:`ChannelSet`; :data:`PLANT` is the
simulated servo-valve hydrostatic transmission's (contract.md, "Data files"). Its order is the
``sensor_chunk`` schema's (schemas/sensor_chunk.v2.json, which stays the versioned wire form; a
test keeps the two in agreement), and the order of its measured channels is the order of the
plant kernel's output columns (:meth:`ChannelSet.column`).

What a recording must have (:meth:`ChannelSet.missing`): every required channel (the command) and at
least one sensor; each sensor alone is optional, so a machine with any subset of the sensors is a
machine of the set (the health methods train on the sensors their recordings share and record them).

Roles:

- ``command``: the input every reference model is driven by (the valve voltage), at most one;
- ``sensor``: a health sensor, an output the health methods judge (flow, speed, torque);
- ``condition``: a measurement of the operating condition (pressures, oil temperature).

A rig description (:mod:`hydrowatch.rig`) builds another :class:`ChannelSet` from its own channels.
The unit conversions between the plant's SI state and the channels' units live here as well.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator
from dataclasses import dataclass

from hydrowatch.errors import ParameterError

M3S_TO_LPM = 60000.0
"""m³/s → L/min (the flow channel's unit)."""
PA_PER_BAR = 1e5
"""Pa per bar (the pressure channels' unit)."""
PA_TO_BAR = 1.0 / PA_PER_BAR
"""Pa → bar, as a factor."""

TIME = "t"
"""Name of the sample-time column, s (not a channel: every recording and chunk has it)."""
TIME_UNIT = "s"
LABEL = "state"
"""Name of the optional per-sample health-label column (not a channel)."""
ROLES: tuple[str, ...] = ("command", "sensor", "condition")
"""Roles a channel may have (module docstring)."""


@dataclass(frozen=True)
class Channel:
    """One channel of a machine.

    Parameters
    ----------
    name : str
        Column name in recordings, files and bus messages (no ``/``; not ``t`` or ``state``).
    unit : str
        Unit of the values, e.g. ``"L/min"``.
    role : str
        One of :data:`ROLES`.
    optional : bool, default False
        Whether a recording may lack the channel.
    """

    name: str
    unit: str
    role: str
    optional: bool = False

    def __post_init__(self) -> None:
        if not self.name or "/" in self.name or self.name in (TIME, LABEL):
            raise ParameterError(f"channel name must be non-empty, without '/', and not '{TIME}' or '{LABEL}'. "
                             f"Got {self.name!r}. Rename the channel.")
        if self.role not in ROLES:
            raise ParameterError(f"channel '{self.name}' role must be one of {list(ROLES)}. Got {self.role!r}.")


@dataclass(frozen=True)
class ChannelSet:
    """The channels of one kind of machine, in column order.

    Parameters
    ----------
    channels : tuple of Channel
        At most one ``command`` channel, which is required (a rig that repeats one fixed cycle may
        record none), at least one ``sensor``, names unique. A recording has every required channel and
        at least one sensor (:meth:`missing`), whether each sensor is optional or not.
    """

    channels: tuple[Channel, ...]

    def __post_init__(self) -> None:
        names = [c.name for c in self.channels]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ParameterError(f"channel names must be unique. Got {repeated} more than once. Rename them.")
        commands = [c for c in self.channels if c.role == "command"]
        if len(commands) > 1 or any(c.optional for c in commands):
            raise ParameterError(f"a channel set must have at most one command channel, and a required one. Got "
                             f"{[(c.name, 'optional' if c.optional else 'required') for c in commands]}.")
        if not any(c.role == "sensor" for c in self.channels):
            raise ParameterError(f"a channel set must have at least one sensor channel. Got roles "
                             f"{[c.role for c in self.channels]}. Give a measured output role 'sensor'.")

    def __iter__(self) -> Iterator[Channel]:
        return iter(self.channels)

    def __len__(self) -> int:
        return len(self.channels)

    def __contains__(self, name: object) -> bool:
        return any(c.name == name for c in self.channels)

    def __getitem__(self, name: str) -> Channel:
        for c in self.channels:
            if c.name == name:
                return c
        raise KeyError(f"channel must be one of {list(self.names)}. Got {name!r}.")

    @property
    def names(self) -> tuple[str, ...]:
        """Every channel's name, in column order."""
        return tuple(c.name for c in self.channels)

    @property
    def has_command(self) -> bool:
        """Whether a command channel is declared (a rig that repeats a fixed cycle may record none)."""
        return any(c.role == "command" for c in self.channels)

    @property
    def command(self) -> str:
        """Name of the command channel (the reference models' input); an error when there is none."""
        for c in self.channels:
            if c.role == "command":
                return c.name
        raise ParameterError(f"a command channel must be declared for this use. Got only {list(self.names)}. "
                             "Declare the rig's command with role 'command', or use a method that needs none.")

    def with_role(self, role: str) -> tuple[str, ...]:
        """Names of the channels of one role, in column order."""
        if role not in ROLES:
            raise ParameterError(f"role must be one of {list(ROLES)}. Got {role!r}.")
        return tuple(c.name for c in self.channels if c.role == role)

    @property
    def sensors(self) -> tuple[str, ...]:
        """Names of the health sensors, in column order."""
        return self.with_role("sensor")

    @property
    def required(self) -> tuple[str, ...]:
        """Names of the channels every recording must have."""
        return tuple(c.name for c in self.channels if not c.optional)

    @property
    def optional(self) -> tuple[str, ...]:
        """Names of the channels a recording may lack."""
        return tuple(c.name for c in self.channels if c.optional)

    def missing(self, names: Collection[str]) -> list[str]:
        """What a recording with channels ``names`` lacks to be one of this set, e.g. ``["voltage", "one of flow,
        speed, torque"]``: the required channels it does not have, and a sensor when it has none (empty: nothing)."""
        lacking = [c for c in self.required if c not in names]
        if not any(s in names for s in self.sensors):
            lacking.append(f"one of {', '.join(self.sensors)}")
        return lacking

    def select(self, names: str | Collection[str]) -> tuple[str, ...]:
        """The channels ``names`` (a collection, or comma-separated text such as ``"voltage,speed"``) in this set's
        column order, checked to be channels of the set and to make a recording of it (:meth:`missing`).

        Raises
        ------
        ParameterError
            Naming the unknown channels, or what the selection lacks.
        """
        wanted = [n.strip() for n in names.split(",") if n.strip()] if isinstance(names, str) else list(names)
        unknown = [n for n in wanted if n not in self]
        if unknown:
            raise ParameterError(f"channels must be among {list(self.names)}. Got unknown {unknown}.")
        lacking = self.missing(wanted)
        if lacking:
            raise ParameterError(f"channels must include every required channel and at least one sensor. Got "
                                 f"{wanted}, without {lacking}.")
        return tuple(n for n in self.names if n in wanted)

    @property
    def measured(self) -> tuple[str, ...]:
        """Names of every channel but the command: the plant's outputs, in kernel column order."""
        return tuple(c.name for c in self.channels if c.role != "command")

    def column(self, name: str) -> int:
        """Column of a measured channel in the plant kernel's output (:attr:`measured` order)."""
        if name not in self.measured:
            raise KeyError(f"channel must be a measured one of {list(self.measured)}. Got {name!r}.")
        return self.measured.index(name)

    @property
    def units(self) -> dict[str, str]:
        """Unit of ``t`` and of every channel, e.g. ``{"t": "s", "voltage": "V", ...}``."""
        return {TIME: TIME_UNIT, **{c.name: c.unit for c in self.channels}}


PLANT = ChannelSet((
    Channel("voltage", "V", "command"),
    Channel("flow", "L/min", "sensor", optional=True),
    Channel("speed", "rad/s", "sensor", optional=True),
    Channel("torque", "N·m", "sensor", optional=True),
    Channel("supply_pressure", "bar", "condition", optional=True),
    Channel("load_pressure", "bar", "condition", optional=True),
    Channel("temperature", "°C", "condition", optional=True),
))
"""The simulated plant's channels (contract.md): valve command, the three sparse health sensors (a
recording has at least one of them, :meth:`ChannelSet.missing`), and the optional condition measurements."""
STUDY_RIG: tuple[str, ...] = (PLANT.command, *PLANT.sensors, "temperature")
"""Channels a rig like the study's measures: the command, the three sensors and the oil temperature,
no pressures (what the demo's fleet publishes)."""
