"""``hydrowatch watch``: a live terminal table of the fleet, fed by ``hydro/<fleet>/*/health``, ``…/forecast`` and a
rig's ``…/cycle_health``.

One row per machine: state, probability, since when (window time) and the latest window; below it, each machine's
worn parts (index, trend, time to alert, most urgent first; :func:`~hydrowatch.report.fleet_table.render_wear`) and
each cycles machine's components (its latest verdict per component, since which cycle;
:mod:`hydrowatch.report.cycle_table`: the machine's row is its verdict on its latest cycle). The
table is redrawn every ``--refresh`` seconds; ``--seconds T`` stops after T seconds and
``--once`` prints the table once after the first verdict (or after ``--seconds``), for scripts.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

from hydrowatch.bus import Message, Subscriber, add_bus_arguments, key_expr, open_session
from hydrowatch.bus.service import command_run
from hydrowatch.bus.session import settings_from_args
from hydrowatch.report.cycle_table import CycleTable, cycle_rows, render_components
from hydrowatch.report.fleet_table import FleetTable, FleetWear, forecast_parts, render_wear, verdict_rows

NAME = "watch"
HELP = ("live table of the fleet's health (one row per machine), its worn parts and a rig's components, from the "
        "health, forecast and cycle_health topics")
TOPICS = ("health", "forecast", "cycle_health")
"""What ``watch`` subscribes to, for each machine of ``--fleet``."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--fleet``, ``--refresh``, ``--seconds``, ``--once`` and the bus flags."""
    parser.add_argument("--fleet", default="*", help="fleet to watch (default: every fleet)")
    parser.add_argument("--refresh", type=float, default=1.0, help="seconds between redraws (default 1)")
    parser.add_argument("--seconds", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--once", action="store_true", help="print the table once (after the first verdict) and exit")
    add_bus_arguments(parser)


def _render(table: FleetTable, wear: FleetWear, cycles: CycleTable) -> str:
    below = [text for text in (render_wear(wear.by_machine()), render_components(cycles.by_machine())) if text]
    return "\n\n".join([table.render(), *below])


def _take(message: Message, table: FleetTable, wear: FleetWear, cycles: CycleTable) -> None:
    """Feed one message: a forecast to ``wear``; verdicts (health, or a cycles machine's verdict per cycle) to
    ``table``."""
    machine = f"{message.key.fleet}/{message.key.machine}"
    if message.key.topic == "forecast":
        wear.add_forecast(machine, forecast_parts(message.batch)[1])
    elif message.key.topic == "cycle_health":
        for row in cycles.update(machine, cycle_rows(message.batch)):
            table.update(machine, row)
    else:
        for row in verdict_rows(message.batch):
            table.update(machine, row)
            wear.add_verdict(machine, row)


def _watch(args: argparse.Namespace, stop: threading.Event) -> int:
    table, wear, cycles = FleetTable(), FleetWear(), CycleTable()
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    live = sys.stdout.isatty() and not args.once
    next_draw = time.monotonic() + args.refresh
    with open_session(settings_from_args(args)) as session, \
            Subscriber(session, [key_expr(args.fleet, "*", t) for t in TOPICS]) as subscriber:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            message = subscriber.recv(timeout=0.1)
            if message is not None:
                _take(message, table, wear, cycles)
                if message.key.topic != "forecast" and args.once and deadline is None:
                    break
            if live and time.monotonic() >= next_draw:
                print("\x1b[2J\x1b[H" + _render(table, wear, cycles), flush=True)
                next_draw = time.monotonic() + args.refresh
    print(_render(table, wear, cycles), flush=True)
    return 0


run = command_run(_watch)
