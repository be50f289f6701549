"""Router service: a zenoh router that the other services join as clients (``--connect tcp/HOST:7447``).

compose.yaml runs the router as the ``eclipse/zenoh`` image (zenohd); there is no zenohd on PyPI or in Debian
(../shared/docs/stack-notes.md), so this is the same router from zenoh's Python package, as its own process: for
hosts without zenohd and for the tests that start the multi-host topology (tests/test_bus_topology.py). It routes,
holds nothing and publishes nothing; SIGINT/SIGTERM closes it.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Sequence
from dataclasses import replace

from hydrowatch.bus import add_bus_arguments, open_session, settings_from_args
from hydrowatch.bus.service import service_main
from hydrowatch.log import event, get_logger

NAME = "router"
HELP = "a zenoh router the services join as clients (as zenohd: --listen tcp/0.0.0.0:7447)"
log = get_logger("services.router")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=float, default=None, help="stop after this many wall-clock seconds")
    add_bus_arguments(parser)


def run(args: argparse.Namespace, stop: threading.Event) -> int:
    """Route until ``stop`` (or ``--seconds``); returns 0. Listens on ``--listen`` (default loopback ``--bus-port``)."""
    settings = replace(settings_from_args(args), mode="router")
    with open_session(settings):
        event(log, "router started", listen=",".join(settings.to_json()["listen"]["endpoints"]))
        deadline = None if args.seconds is None else time.monotonic() + args.seconds
        while not stop.wait(0.5):
            if deadline is not None and time.monotonic() >= deadline:
                break
    event(log, "router stopped")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.router``."""
    return service_main(NAME, HELP, add_arguments, run, argv)
