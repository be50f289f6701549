"""The scorer with a cycles bundle (``train --rig``): ``hydro/<fleet>/*/cycles`` in, ``…/cycle_health`` out.

Each ``rig_cycles`` message is judged as it comes (:class:`hydrowatch.training.cycle_stream.CycleJudge`: one verdict
per cycle and component); a message the bundle cannot judge (another rig, grid or channels, a label outside the
description) is counted, logged once per key, and skipped. ``--shard``, ``--follow-alias``, the status heartbeat
and SIGINT/SIGTERM behave as for sensor chunks; there are no windows to gather, recover or forecast.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections import Counter
from typing import TYPE_CHECKING

from hydrowatch.bus import Publisher, StatusReporter, Subscriber, key, key_expr, open_session
from hydrowatch.bus.session import settings_from_args
from hydrowatch.bus.takeover import release, sharded
from hydrowatch.errors import DataError
from hydrowatch.log import event, get_logger

if TYPE_CHECKING:
    from hydrowatch.bus import Message
    from hydrowatch.training.cycle_stream import CycleJudge
    from services.scorer.model import _Model

log = get_logger("services.scorer")


class _Cycles:
    """Judge and publish; counts what was judged and what was refused."""

    def __init__(self, publisher: Publisher, judge: CycleJudge) -> None:
        self.publisher, self.judge = publisher, judge
        self.cycles = 0
        self.refused: Counter[str] = Counter()

    def handle(self, message: Message) -> None:
        where = str(message.key)
        try:
            verdicts = self.judge.judge(message.batch, where)
        except DataError as exc:
            if not self.refused[where]:
                event(log, "rig cycles refused", logging.WARNING, key=where, reason=str(exc))
            self.refused[where] += 1
            return
        self.publisher.put(key(message.key.fleet, message.key.machine, "cycle_health"), verdicts)
        self.cycles += message.batch.num_rows


def run_cycles(model: _Model, args: argparse.Namespace, stop: threading.Event, name: str) -> int:
    """Score rig cycles until ``stop`` (or ``--seconds``) with ``model`` (the scorer's ``_Model``); returns 0."""
    from hydrowatch.training.cycle_stream import CycleJudge

    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    with open_session(settings_from_args(args)) as session:
        shard = sharded(session, args.fleet, name, args.shard)
        subscriber = Subscriber(session, key_expr(args.fleet, "*", "cycles"), shard=shard)
        publisher = Publisher(session)
        scored = _Cycles(publisher, CycleJudge(model.bundle))
        reporter = StatusReporter(session, args.fleet if args.fleet != "*" else "all", name, lambda: {
            "messages_in": subscriber.received, "messages_out": publisher.messages_out,
            "messages_undecodable": subscriber.undecodable_total + sum(scored.refused.values())})
        try:
            reporter.start()
            reporter.status = "running"
            event(log, "scorer started", model=model.bundle.version, shard=str(args.shard),
                  fleet=args.fleet, topic="cycles")
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                if model.moved():
                    scored.judge = CycleJudge(model.bundle)
                message = subscriber.recv(timeout=0.1)
                if message is not None:
                    scored.handle(message)
            reporter.status = "draining"
            subscriber.close()
            for message in subscriber.drain():
                scored.handle(message)
        finally:
            subscriber.close()
            release(shard)
            reporter.stop()
            publisher.close()
            stop.set()
            model.join()
    event(log, "scorer stopped", cycles=scored.cycles, refused=sum(scored.refused.values()))
    return 0
