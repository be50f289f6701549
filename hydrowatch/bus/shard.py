"""Shards of a fleet: ``--shard i/n`` gives a service the machines whose stable hash is ``i mod n``.

The hash is CRC-32 of the machine id's UTF-8 bytes: the same on every host, process and Python
version (unlike ``hash()``), so recorders and scorers started with ``0/n`` … ``n-1/n`` on any
hosts together handle every machine exactly once.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

from hydrowatch.errors import ParameterError


def machine_hash(machine: str) -> int:
    """Stable 32-bit hash of a machine id (CRC-32 of its UTF-8 bytes)."""
    return zlib.crc32(machine.encode("utf-8"))


@dataclass(frozen=True)
class Shard:
    """Shard ``index`` of ``count``; ``Shard(0, 1)`` is the whole fleet."""

    index: int = 0
    count: int = 1

    def __post_init__(self) -> None:
        if self.count < 1 or not 0 <= self.index < self.count:
            raise ParameterError(
                f"shard must be i/n with n >= 1 and 0 <= i < n. Got {self.index}/{self.count}. "
                "Number shards from 0, e.g. --shard 0/2 and --shard 1/2."
            )

    def includes(self, machine: str) -> bool:
        """Whether this shard handles ``machine``."""
        return self.count == 1 or machine_hash(machine) % self.count == self.index

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"


def parse_shard(text: str) -> Shard:
    """Parse ``"i/n"`` (e.g. ``"1/4"``) into a :class:`Shard`; ParameterError when malformed."""
    index, sep, count = str(text).partition("/")
    try:
        if not sep:
            raise ValueError
        return Shard(int(index), int(count))
    except ValueError:
        raise ParameterError(
            f"shard must be 'i/n' with integers, e.g. '0/2'. Got {text!r}."
        ) from None
