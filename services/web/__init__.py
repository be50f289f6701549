"""Web service: the live fleet page, fed by ``hydro/<fleet>/*/health``, ``…/kl``, ``…/forecast`` and a rig's
``…/cycle_health``.

Subscribes to the verdicts and the evidence (relative entropies or parity relation scores) of every
machine of ``--fleet``, keeps them in a :class:`hydrowatch.web.live.FleetLive` and serves the fleet page
and the machine pages on ``http://--host:--port/`` (:mod:`services.web.server`), which update in place by
server-sent events. While a machine's page is open, the service also subscribes to that machine's
``…/sensors`` and ``…/expected`` and keeps its last seconds of samples and its last windows of measured and
expected sensors for the page. Everything the pages need is served
from ``services/web/static`` (no CDN). SIGINT/SIGTERM closes the page streams and the bus session.
docs/web.md describes the pages.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Sequence

import zenoh

from hydrowatch.bus import Message, StatusReporter, Subscriber, add_bus_arguments, key, key_expr, open_session
from hydrowatch.bus.service import service_main
from hydrowatch.bus.session import settings_from_args
from hydrowatch.errors import ParameterError
from hydrowatch.io.sensor_chunk import arrays_from_sensor_chunk
from hydrowatch.log import event, get_logger
from hydrowatch.report.cycle_table import cycle_rows
from hydrowatch.report.fleet_table import forecast_parts, verdict_rows
from hydrowatch.web import DEFAULT_PORT
from hydrowatch.web.live import FleetLive

NAME = "web"
HELP = "live fleet web page (health, evidence, forecast and cycle_health topics) on a local port, updated in place"
TOPICS = ("health", "kl", "forecast", "cycle_health")
"""What the service subscribes to for every machine of ``--fleet``."""
log = get_logger("services.web")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", type=int, default=DEFAULT_PORT,
                        help=f"HTTP port (default {DEFAULT_PORT}; 0: any free one)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to serve on (default 127.0.0.1, this machine only; 0.0.0.0: every interface)")
    parser.add_argument("--fleet", default="*", help="fleet to show (default: every fleet)")
    parser.add_argument("--history", type=int, default=360, help="verdicts kept per machine for its timeline")
    parser.add_argument("--seconds", type=float, default=None, help="stop after this many wall-clock seconds")
    add_bus_arguments(parser)


def _take(live: FleetLive, messages: Sequence[Message]) -> None:
    """Feed ``live`` with verdicts (``health``; a rig's ``cycle_health``), evidence (``kl``), forecasts (``forecast``)
    and followed machines' samples (``sensors``) and expected sensors (``expected``)."""
    for message in messages:
        k = message.key
        if k.topic == "sensors":
            t, channels = arrays_from_sensor_chunk(message.batch)
            live.add_sensors(k.fleet, k.machine, t, channels)
        elif k.topic == "health":
            for row in verdict_rows(message.batch):
                live.add_verdict(k.fleet, k.machine, row, received=message.receive_time_ns / 1e9,
                                 published_ms=message.publish_time_ns / 1e6 or None)
        elif k.topic == "cycle_health":
            live.add_cycle_verdicts(k.fleet, k.machine, cycle_rows(message.batch),
                                    received=message.receive_time_ns / 1e9,
                                    published_ms=message.publish_time_ns / 1e6 or None)
        elif k.topic == "forecast":
            live.add_forecast(k.fleet, k.machine, forecast_parts(message.batch)[1])
        elif k.topic == "expected":
            live.add_expected(k.fleet, k.machine, message.batch.to_pylist())
        else:
            live.add_evidence(k.fleet, k.machine, message.batch.to_pylist())


class _SensorFeeds:
    """A ``…/sensors`` and ``…/expected`` subscriber for each machine whose page is open (declared and undeclared as
    pages come and go); use as a context manager."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._subscribers: dict[str, Subscriber] = {}

    def follow(self, watched: set[str]) -> None:
        """Subscribe to the machines in ``watched`` and to no others."""
        for ident in set(self._subscribers) - watched:
            self._subscribers.pop(ident).close()
        for ident in watched - set(self._subscribers):
            fleet, machine = ident.split("/", 1)
            try:
                self._subscribers[ident] = Subscriber(self.session, [key(fleet, machine, topic)
                                                                     for topic in ("sensors", "expected")])
            except ParameterError:
                continue  # a page asked for an id that is no machine's: it shows no sensors
            event(log, "sensors followed while the machine's page is open", machine=ident)

    def take(self) -> list[Message]:
        """What came on the followed machines' sensor and expected topics since the last call (no waiting)."""
        return [m for s in self._subscribers.values() for m in s.recv_many(timeout=0.0)]

    def __enter__(self) -> _SensorFeeds:
        return self

    def __exit__(self, *exc: object) -> None:
        self.follow(set())


def run(args: argparse.Namespace, stop: threading.Event) -> int:
    """Serve until ``stop`` (or ``--seconds``); returns 0."""
    from services.web.server import WebServer

    live = FleetLive(history=args.history)
    condition = threading.Condition()
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    topics = [key_expr(args.fleet, "*", topic) for topic in TOPICS]
    with open_session(settings_from_args(args)) as session, Subscriber(session, topics) as subscriber, \
            _SensorFeeds(session) as feeds, WebServer(live, condition, args.host, args.port) as server:
        reporter = StatusReporter(session, args.fleet if args.fleet != "*" else "all", NAME, lambda: {
            "messages_in": subscriber.received, "messages_undecodable": subscriber.undecodable_total,
            "pages_open": server.streams})
        try:
            reporter.start()
            reporter.status = "running"
            event(log, "web page ready", url=server.url, fleet=args.fleet)
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                messages = subscriber.recv_many(limit=5000, timeout=0.1)
                feeds.follow(server.watched())
                messages += feeds.take()
                if messages:
                    with condition:
                        _take(live, messages)
                        condition.notify_all()
        finally:
            reporter.stop()
    if subscriber.undecodable_total:
        event(log, "undecodable messages skipped", logging.WARNING, count=subscriber.undecodable_total)
    event(log, "web stopped", machines=len(live), messages=subscriber.received)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.web``."""
    return service_main(NAME, HELP, add_arguments, run, argv)
