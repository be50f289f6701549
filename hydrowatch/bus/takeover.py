"""Shards that take over: the machines of a shard that is down go to the live shards, and come back with it.

``--shard i/n`` gives a service the machines whose stable hash is ``i mod n`` (:mod:`hydrowatch.bus.shard`), its
*home* machines. :class:`ShardTakeover` adds the machines of shards that are down: every shard declares a
liveliness token ``hydro/<fleet>/_shards/<service>/<i>-<n>`` and follows the others' (a token vanishes at once when
its process closes or is killed, and after ~10 s when it hangs). A machine belongs to its home shard while that
shard is alive; otherwise to the live shard with the highest rendezvous score (highest-random-weight hashing,
CRC-32 of ``"<machine>#<shard>"``). Every shard computes the same owner from the same set of live shards, so in
steady state each machine is handled by exactly one shard; a shard that comes back takes its home machines back
at once, and a machine moves only when its own shard (or its stand-in) comes or goes.

While the shards' views of who is alive differ (for the moment a token takes to travel), a machine can be handled
twice or not at all; the service's own gap handling (recovery of missing chunks, ``invalid`` windows) covers that.
"""

from __future__ import annotations

import logging
import threading
import zlib

import zenoh

from hydrowatch.bus.shard import Shard, machine_hash
from hydrowatch.log import event, get_logger

log = get_logger(__name__)


def shard_prefix(fleet: str, service: str) -> str:
    """Key prefix of the shard tokens of one service in one fleet (``*``, every fleet, is written ``_all``)."""
    return f"hydro/{'_all' if fleet == '*' else fleet}/_shards/{service}"


def stand_in(machine: str, live: frozenset[int]) -> int:
    """The live shard that takes ``machine`` when its home shard is down (highest rendezvous score)."""
    return max(live, key=lambda j: (zlib.crc32(f"{machine}#{j}".encode()), j))


def owner(machine: str, count: int, live: frozenset[int]) -> int:
    """The shard that handles ``machine``: its home shard when alive, else :func:`stand_in` (home when none is)."""
    home = machine_hash(machine) % count
    return home if home in live or not live else stand_in(machine, live)


class ShardTakeover:
    """Shard ``shard`` of ``service`` in ``fleet`` that also takes the machines of shards that are down.

    A drop-in for :class:`Shard` where the subscriber asks (``count``, ``includes``). Use as a context manager or
    call :meth:`close` to undeclare the token and the liveliness subscriber.
    """

    def __init__(self, session: zenoh.Session, fleet: str, service: str, shard: Shard) -> None:
        self.index, self.count = shard.index, shard.count
        self._lock = threading.Lock()
        self._live: frozenset[int] = frozenset({shard.index})
        self._owned: dict[str, bool] = {}
        prefix = shard_prefix(fleet, service)
        liveliness = session.liveliness()
        self._token = liveliness.declare_token(f"{prefix}/{shard.index}-{shard.count}")
        self._subscriber = liveliness.declare_subscriber(f"{prefix}/*", self._on_change, history=True)

    @property
    def live(self) -> frozenset[int]:
        """Indices of the shards alive now (this one included)."""
        return self._live

    def _on_change(self, sample: zenoh.Sample) -> None:
        """A shard token appeared (PUT) or vanished (DELETE); runs on a zenoh thread, so it only updates a set."""
        index, sep, count = str(sample.key_expr).rsplit("/", 1)[-1].partition("-")
        if not sep or not index.isdigit() or count != str(self.count):
            event(log, "shard token of another layout ignored", logging.WARNING, key=str(sample.key_expr),
                  expected=f"i-{self.count}")
            return
        with self._lock:
            live = set(self._live)
            if sample.kind == zenoh.SampleKind.DELETE and int(index) != self.index:
                live.discard(int(index))
            else:
                live.add(int(index))
            changed = frozenset(live) != self._live
            self._live = frozenset(live)
            self._owned = {}
        if changed:
            event(log, "shards alive", shard=f"{self.index}/{self.count}", live=",".join(map(str, sorted(live))))

    def includes(self, machine: str) -> bool:
        """Whether this shard handles ``machine`` now (cached until the set of live shards changes)."""
        owned = self._owned
        found = owned.get(machine)
        if found is None:
            found = owned[machine] = owner(machine, self.count, self._live) == self.index
        return found

    def close(self) -> None:
        """Undeclare the token (the others take this shard's machines) and stop following theirs."""
        self._subscriber.undeclare()
        self._token.undeclare()

    def __enter__(self) -> ShardTakeover:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"


def sharded(session: zenoh.Session, fleet: str, service: str, shard: Shard) -> Shard | ShardTakeover:
    """What a sharded service filters its machines with: ``shard`` itself when it is the whole fleet, else a
    :class:`ShardTakeover` (close it with :func:`release`)."""
    return shard if shard.count == 1 else ShardTakeover(session, fleet, service, shard)


def release(shard: Shard | ShardTakeover) -> None:
    """Close what :func:`sharded` opened (nothing for a plain :class:`Shard`)."""
    if isinstance(shard, ShardTakeover):
        shard.close()
