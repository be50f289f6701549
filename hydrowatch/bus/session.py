"""Zenoh session configuration: embedded loopback mesh by default, a router when one is given.

Two ways to run the bus (../shared/docs/stack-notes.md):

* **Embedded** (default): every process is a zenoh *peer* that listens on the loopback rendezvous
  port (``tcp/127.0.0.1:7447``, or ``--bus-port``) *and* on a free loopback port, and connects to
  the rendezvous. The first process gets the rendezvous port; later ones meet it there and learn
  each other's free ports by gossip, so every pair talks directly. No router, no multicast.
* **Router**: ``--connect tcp/HOST:7447`` (or ``HYDROWATCH_ZENOH_CONNECT``) makes the process a
  zenoh *client* of that router (a zenohd, e.g. the ``eclipse/zenoh`` container of compose.yaml).
  The client waits for the router when it is not up yet.

Environment variables (flags win): ``HYDROWATCH_ZENOH_CONNECT`` (comma-separated endpoints),
``HYDROWATCH_ZENOH_LISTEN`` (extra listen endpoints, e.g. ``tcp/0.0.0.0:7448`` to be reachable
from other hosts), ``HYDROWATCH_ZENOH_MODE`` (peer, client or router), ``HYDROWATCH_ZENOH_PORT``
(the loopback rendezvous port) and ``HYDROWATCH_ZENOH_CONFIG`` (a zenoh JSON5 file to start from).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import socket
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from hydrowatch.errors import ParameterError

DEFAULT_PORT = 7447
"""Loopback rendezvous port of the embedded mesh."""

ENV_CONNECT = "HYDROWATCH_ZENOH_CONNECT"
ENV_LISTEN = "HYDROWATCH_ZENOH_LISTEN"
ENV_MODE = "HYDROWATCH_ZENOH_MODE"
ENV_PORT = "HYDROWATCH_ZENOH_PORT"
ENV_CONFIG = "HYDROWATCH_ZENOH_CONFIG"
MODES = ("peer", "client", "router")


def _split(text: str | None) -> tuple[str, ...]:
    return tuple(e.strip() for e in (text or "").split(",") if e.strip())


@dataclass(frozen=True)
class BusSettings:
    """Where a process meets the bus.

    Parameters
    ----------
    mode : {"peer", "client", "router"} or None
        None picks ``client`` when ``connect`` is given, else ``peer``.
    connect : tuple of str
        Router (or peer) endpoints, e.g. ``("tcp/10.0.0.5:7447",)``.
    listen : tuple of str
        Extra listen endpoints.
    port : int
        Loopback rendezvous port of the embedded mesh (peer mode without ``connect``).
    config_file : str or None
        A zenoh JSON5 configuration to start from; the settings above override it.
    """

    mode: str | None = None
    connect: tuple[str, ...] = field(default_factory=tuple)
    listen: tuple[str, ...] = field(default_factory=tuple)
    port: int = DEFAULT_PORT
    config_file: str | None = None

    def __post_init__(self) -> None:
        if self.mode is not None and self.mode not in MODES:
            raise ParameterError(f"zenoh mode must be one of {MODES}. Got {self.mode!r}.")
        if not 0 < self.port < 65536:
            raise ParameterError(f"bus port must be in 1..65535. Got {self.port}. Pick a free TCP port.")
        if self.resolved_mode == "client" and not self.connect:
            raise ParameterError(
                "zenoh client mode must have a router to connect to. Got no --connect. "
                f"Pass --connect tcp/HOST:7447 or set {ENV_CONNECT}."
            )

    @property
    def resolved_mode(self) -> str:
        """The zenoh mode this process runs in."""
        return self.mode or ("client" if self.connect else "peer")

    @classmethod
    def from_env(
        cls,
        env: Mapping[str, str] | None = None,
        *,
        mode: str | None = None,
        connect: Sequence[str] = (),
        listen: Sequence[str] = (),
        port: int | None = None,
        config_file: str | None = None,
    ) -> BusSettings:
        """Settings from arguments, falling back to the ``HYDROWATCH_ZENOH_*`` variables."""
        env = os.environ if env is None else env
        try:
            env_port = int(env.get(ENV_PORT, DEFAULT_PORT))
        except ValueError:
            raise ParameterError(f"{ENV_PORT} must be an integer port. Got {env.get(ENV_PORT)!r}.") from None
        return cls(
            mode=mode or env.get(ENV_MODE) or None,
            connect=tuple(connect) or _split(env.get(ENV_CONNECT)),
            listen=tuple(listen) or _split(env.get(ENV_LISTEN)),
            port=port if port is not None else env_port,
            config_file=config_file or env.get(ENV_CONFIG) or None,
        )

    def to_json(self) -> dict:
        """The zenoh configuration overrides as a JSON-able dict."""
        mode = self.resolved_mode
        conf: dict = {"mode": mode, "scouting": {"multicast": {"enabled": False}}}
        if mode == "peer" and not self.connect:
            rendezvous = f"tcp/127.0.0.1:{self.port}"
            conf["listen"] = {"endpoints": [rendezvous, "tcp/127.0.0.1:0", *self.listen], "exit_on_failure": False}
            conf["connect"] = {"endpoints": [rendezvous], "exit_on_failure": False, "timeout_ms": 2000}
        else:
            default_listen = [f"tcp/127.0.0.1:{self.port}"] if mode == "router" else []
            conf["listen"] = {"endpoints": list(self.listen) or default_listen}
            # a client waits for its router (-1: forever, retried in the background)
            conf["connect"] = {"endpoints": list(self.connect), "timeout_ms": -1 if mode == "client" else 2000}
        return conf

    def to_config(self) -> zenoh.Config:
        """A ``zenoh.Config`` for :func:`zenoh.open`."""
        if self.config_file:
            conf = zenoh.Config.from_file(self.config_file)
            for name, value in self.to_json().items():
                conf.insert_json5(name, json.dumps(value))
            return conf
        return zenoh.Config.from_json5(json.dumps(self.to_json()))

    def to_argv(self) -> list[str]:
        """Command-line flags that reproduce these settings in a child process."""
        argv = ["--bus-port", str(self.port)]
        if self.mode:
            argv += ["--mode", self.mode]
        for endpoint in self.connect:
            argv += ["--connect", endpoint]
        for endpoint in self.listen:
            argv += ["--listen", endpoint]
        if self.config_file:
            argv += ["--zenoh-config", self.config_file]
        return argv


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--connect``, ``--listen``, ``--mode``, ``--bus-port``, ``--zenoh-config``."""
    group = parser.add_argument_group("bus (Eclipse Zenoh)")
    group.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                       help=f"router endpoint, e.g. tcp/HOST:7447 (repeatable; env {ENV_CONNECT})")
    group.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                       help=f"extra listen endpoint (repeatable; env {ENV_LISTEN})")
    group.add_argument("--mode", choices=MODES, default=None,
                       help=f"zenoh mode (default: client with --connect, else peer; env {ENV_MODE})")
    group.add_argument("--bus-port", type=int, default=None, metavar="PORT",
                       help=f"loopback rendezvous port of the embedded bus (default {DEFAULT_PORT}; env {ENV_PORT})")
    group.add_argument("--zenoh-config", default=None, metavar="FILE",
                       help=f"zenoh JSON5 config to start from (env {ENV_CONFIG})")


def settings_from_args(args: argparse.Namespace) -> BusSettings:
    """:class:`BusSettings` from the flags of :func:`add_bus_arguments` plus the environment."""
    return BusSettings.from_env(
        mode=args.mode, connect=args.connect, listen=args.listen, port=args.bus_port, config_file=args.zenoh_config
    )


EPHEMERAL_RANGE = Path("/proc/sys/net/ipv4/ip_local_port_range")
"""Where Linux keeps the range it gives outgoing connections' source ports (32768–60999 by default)."""
BELOW_EPHEMERAL = 12000
"""How many ports below that range :func:`free_port` chooses from."""


def _ephemeral_low() -> int:
    """Lowest port the kernel hands out as an outgoing connection's source port (32768 where not readable)."""
    try:
        return int(EPHEMERAL_RANGE.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def free_port(host: str = "127.0.0.1", avoid: Collection[int] = ()) -> int:
    """A TCP port free on ``host`` right now (for a private bus in tests or ``hydrowatch up``), none of ``avoid``
    (ports already chosen for other services that have not bound them yet: two picks from the same range can
    coincide, seen once as a web page and its bus handed one port, ``Address already in use``).

    Chosen at random among the :data:`BELOW_EPHEMERAL` ports below the kernel's ephemeral range, not by binding
    port 0: a port from that range, released here and bound by a service seconds later, can meanwhile become the
    source port of any outgoing connection on the host, and zenoh does not retry a listen that failed — every peer
    then waits for a rendezvous that never comes up (reproduced by holding the port: "record did not come up"
    after 60 s, the once-seen failure of the two-recorder-shard test in a full run).
    """
    low = _ephemeral_low()
    pick = random.SystemRandom()
    for _ in range(200):
        port = pick.randrange(max(1024, low - BELOW_EPHEMERAL), low)
        if port in avoid:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            try:
                sock.bind((host, port))
            except OSError:
                continue
            return port
    while True:  # every try taken: let the kernel choose
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.bind((host, 0))
            port = int(sock.getsockname()[1])
        if port not in avoid:
            return port


def open_session(settings: BusSettings | None = None) -> zenoh.Session:
    """Open a zenoh session; use it as ``with open_session(s) as session:`` so it always closes.

    zenoh's own log (links opening and closing, congestion) goes to standard output when ``RUST_LOG`` is set,
    e.g. ``RUST_LOG=zenoh=debug``; otherwise it stays off.
    """
    if os.environ.get("RUST_LOG"):
        zenoh.try_init_log_from_env()  # a no-op after the first call
    return zenoh.open((settings or BusSettings.from_env()).to_config())
