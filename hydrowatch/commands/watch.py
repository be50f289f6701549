"""``hydrowatch watch``: a live terminal table of the fleet, fed only by ``hydro/<fleet>/*/health``.

One row per machine: state, probability, since when (window time) and the latest window. The
table is redrawn every ``--refresh`` seconds; ``--seconds T`` stops after T seconds and
``--once`` prints the table once after the first verdict (or after ``--seconds``), for scripts.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

from hydrowatch.bus import Subscriber, add_bus_arguments, key_expr, open_session
from hydrowatch.bus.service import command_run
from hydrowatch.bus.session import settings_from_args
from hydrowatch.report.fleet_table import FleetTable, verdict_rows

NAME = "watch"
HELP = "live table of the fleet's health (one row per machine), from the health topic only"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--fleet``, ``--refresh``, ``--seconds``, ``--once`` and the bus flags."""
    parser.add_argument("--fleet", default="*", help="fleet to watch (default: every fleet)")
    parser.add_argument("--refresh", type=float, default=1.0, help="seconds between redraws (default 1)")
    parser.add_argument("--seconds", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--once", action="store_true", help="print the table once (after the first verdict) and exit")
    add_bus_arguments(parser)


def _watch(args: argparse.Namespace, stop: threading.Event) -> int:
    table = FleetTable()
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    live = sys.stdout.isatty() and not args.once
    next_draw = time.monotonic() + args.refresh
    with open_session(settings_from_args(args)) as session, \
            Subscriber(session, key_expr(args.fleet, "*", "health")) as subscriber:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            message = subscriber.recv(timeout=0.1)
            if message is not None:
                for row in verdict_rows(message.batch):
                    table.update(f"{message.key.fleet}/{message.key.machine}", row)
                if args.once and deadline is None:
                    break
            if live and time.monotonic() >= next_draw:
                print("\x1b[2J\x1b[H" + table.render(), flush=True)
                next_draw = time.monotonic() + args.refresh
    print(table.render(), flush=True)
    return 0


run = command_run(_watch)
