"""``hydrowatch watch``: a live terminal table of the fleet, fed by ``hydro/<fleet>/*/health`` and ``…/forecast``.

One row per machine: state, probability, since when (window time) and the latest window; below it, each machine's
worn parts (index, trend, time to alert, most urgent first; :func:`~hydrowatch.report.fleet_table.render_wear`). The
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
from hydrowatch.report.fleet_table import FleetTable, FleetWear, forecast_parts, render_wear, verdict_rows

NAME = "watch"
HELP = "live table of the fleet's health (one row per machine) and its worn parts, from the health and forecast topics"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--fleet``, ``--refresh``, ``--seconds``, ``--once`` and the bus flags."""
    parser.add_argument("--fleet", default="*", help="fleet to watch (default: every fleet)")
    parser.add_argument("--refresh", type=float, default=1.0, help="seconds between redraws (default 1)")
    parser.add_argument("--seconds", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--once", action="store_true", help="print the table once (after the first verdict) and exit")
    add_bus_arguments(parser)


def _render(table: FleetTable, wear: FleetWear) -> str:
    worn = render_wear(wear.by_machine())
    return table.render() + (f"\n\n{worn}" if worn else "")


def _watch(args: argparse.Namespace, stop: threading.Event) -> int:
    table, wear = FleetTable(), FleetWear()
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    live = sys.stdout.isatty() and not args.once
    next_draw = time.monotonic() + args.refresh
    with open_session(settings_from_args(args)) as session, \
            Subscriber(session, [key_expr(args.fleet, "*", t) for t in ("health", "forecast")]) as subscriber:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            message = subscriber.recv(timeout=0.1)
            if message is not None and message.key.topic == "forecast":
                wear.add_forecast(f"{message.key.fleet}/{message.key.machine}", forecast_parts(message.batch)[1])
            elif message is not None:
                for row in verdict_rows(message.batch):
                    table.update(f"{message.key.fleet}/{message.key.machine}", row)
                    wear.add_verdict(f"{message.key.fleet}/{message.key.machine}", row)
                if args.once and deadline is None:
                    break
            if live and time.monotonic() >= next_draw:
                print("\x1b[2J\x1b[H" + _render(table, wear), flush=True)
                next_draw = time.monotonic() + args.refresh
    print(_render(table, wear), flush=True)
    return 0


run = command_run(_watch)
