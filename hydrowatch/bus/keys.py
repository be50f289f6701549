"""Key expressions of the bus (contract: ``hydro/<fleet>/<machine>/<topic>``).

``<fleet>`` and ``<machine>`` are free-form ids without ``/``; a zenoh wildcard (``*`` a whole
chunk, ``**`` any number of chunks) may stand for either in a subscription.
"""

from __future__ import annotations

from typing import NamedTuple

from hydrowatch.errors import DataError, ParameterError

PREFIX = "hydro"
TOPICS: tuple[str, ...] = ("sensors", "kl", "health", "status", "forecast", "expected", "cycles", "cycle_health")
"""Topics of the contract, the last chunk of every key (``cycles`` and ``cycle_health``: a rig's whole cycles and
their per-component verdicts, docs/rigs.md)."""

_FORBIDDEN = set("/*$?#@ ")


class Key(NamedTuple):
    """A parsed key ``hydro/<fleet>/<machine>/<topic>``."""

    fleet: str
    machine: str
    topic: str

    def __str__(self) -> str:
        return f"{PREFIX}/{self.fleet}/{self.machine}/{self.topic}"


def _valid_id(value: str) -> bool:
    """Whether ``value`` may be a fleet or machine id (it names a folder of recordings: not ``.`` or ``..``)."""
    return bool(value) and value not in (".", "..") and not _FORBIDDEN.intersection(value)


def _check_id(what: str, value: str) -> str:
    if not _valid_id(value):
        raise ParameterError(
            f"{what} must be a non-empty id without any of '/*$?#@' or spaces, and not '.' or '..'. Got {value!r}. "
            "Use letters, digits, '-', '_' or '.'."
        )
    return value


def _check_topic(topic: str) -> str:
    if topic not in TOPICS:
        raise ParameterError(f"topic must be one of {TOPICS}. Got {topic!r}.")
    return topic


def key(fleet: str, machine: str, topic: str) -> str:
    """The concrete key of one machine and topic, e.g. ``key("f1", "m007", "sensors")``."""
    return str(Key(_check_id("fleet", fleet), _check_id("machine", machine), _check_topic(topic)))


def key_expr(fleet: str = "*", machine: str = "*", topic: str = "sensors") -> str:
    """A subscription key expression; ``*`` for fleet or machine matches every id."""
    fleet = fleet if fleet == "*" else _check_id("fleet", fleet)
    machine = machine if machine == "*" else _check_id("machine", machine)
    return f"{PREFIX}/{fleet}/{machine}/{topic if topic == '*' else _check_topic(topic)}"


def parse_key(text: str) -> Key:
    """Split a concrete key into fleet, machine and topic; DataError when it is not a contract key."""
    parts = str(text).split("/")
    if len(parts) != 4 or parts[0] != PREFIX or not all(map(_valid_id, parts[1:3])) or parts[3] not in TOPICS:
        raise DataError(
            f"key must look like '{PREFIX}/<fleet>/<machine>/<topic>' with topic in {TOPICS} and ids without "
            f"'/*$?#@' or spaces, not '.' or '..'. Got {text!r}."
        )
    return Key(parts[1], parts[2], parts[3])
