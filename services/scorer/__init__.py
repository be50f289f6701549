"""Scorer service: sensor chunks in, relative entropies and verdicts out, one window at a time.

Subscribes to ``hydro/<fleet>/*/sensors`` (``--shard i/n``: only that shard's machines), keeps each
machine's window (:class:`hydrowatch.training.online.OnlineScorer`: parity bundles a row of raw
samples and, with ``--smoothing N``, the evidence of its last N windows; entropy bundles the
reference models' delay lines), batched across machines, and publishes
``hydro/<fleet>/<machine>/kl``, ``…/health`` (the pooled verdict) and, for methods that predict the sensors
(parity, entropy), ``…/expected`` (what the model expected each sensor to read, beside what it read, 50 points per
window; ``--no-expected``: none) for every window that closes; for methods with a degradation index (parity),
``…/forecast`` every ``--forecast-every`` windows of a machine, from its last ``--forecast-history`` seconds
of windows (:class:`hydrowatch.training.forecasts.FleetForecasts`). A chunk missing from a machine's stream is
first asked for from the publisher's history (:mod:`hydrowatch.bus.recovery`; the machine's newer chunks wait
meanwhile, at most 2 s); gaps that stay, NaN, late or out-of-order chunks make the window in progress ``invalid``
with its reason.
The model comes from a bundle folder or the MLflow registry (``models:/NAME@ALIAS``; default the served rig's,
``models:/hydrowatch@champion`` for the plant, ``models:/hydrowatch-<rig>@champion`` with ``--rig``). The scorer
serves one rig (``--rig``; the plant when neither ``--rig`` nor ``--model`` is given, else the first model's rig) and
refuses a model made for another rig or reading channels the rig lacks (:mod:`hydrowatch.training.served`): at start
with the error, on a followed alias by keeping the model in use and logging the refusal. With
``--follow-alias S`` the alias is checked every S seconds and the scorer switches (fresh windows)
when it moves; an alias that does not exist yet is waited for (the model, the alias and the served rig:
:mod:`services.scorer.model`). SIGINT/SIGTERM drains and exits.
A cycles bundle (``train --rig``) judges a rig's whole cycles instead: ``hydro/<fleet>/*/cycles`` in,
``…/cycle_health`` out (:mod:`services.scorer.cycles`).
"""

from __future__ import annotations

import argparse
import logging
import os
import threading
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from hydrowatch.bus import (
    Publisher,
    Shard,
    StatusReporter,
    Subscriber,
    add_bus_arguments,
    key,
    key_expr,
    open_session,
    parse_shard,
)
from hydrowatch.bus.recovery import GapRecovery
from hydrowatch.bus.service import freeze_heap, service_main
from hydrowatch.bus.session import settings_from_args
from hydrowatch.bus.takeover import release, sharded
from hydrowatch.errors import ParameterError
from hydrowatch.log import event, get_logger
from hydrowatch.recording import SAMPLE_RATE_HZ
from hydrowatch.rig import BUILTIN
from hydrowatch.rig.plant import PLANT_RIG
from hydrowatch.training.options import default_model_uri
from services.scorer.model import REGISTRY_ENV, _first_model, _Model
from services.scorer.model import served_rig as served_rig  # where tests and scripts have found it

if TYPE_CHECKING:  # the model code (torch) is imported when the service runs, not when the CLI parses
    from hydrowatch.bus import Message
    from hydrowatch.methods.base import HealthMethod
    from hydrowatch.training.bundle import ModelBundle
    from hydrowatch.training.forecasts import FleetForecasts
    from hydrowatch.training.online import ChunkBatch, OnlineScorer, WindowVerdict

NAME = "scorer"
HELP = ("score sensor chunks online: publish relative entropies (…/kl), verdicts (…/health) and the sensors the model "
        "expected (…/expected) per window, and each machine's forecast (…/forecast) every few windows")
DEFAULT_MODEL = default_model_uri()
"""The plant's registered model, loaded unless ``--model`` or ``--rig`` is given."""
log = get_logger("services.scorer")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", default=None,
                        help=f"bundle folder or registry URI (default {DEFAULT_MODEL}; with --rig "
                             f"{default_model_uri('<rig>')})")
    parser.add_argument("--rig", default=None, metavar="NAME|FILE",
                        help=f"the rig served: {PLANT_RIG!r}, {', '.join(BUILTIN)} or a .toml description; a model "
                             "made for another rig, or reading a channel this one lacks, is refused (default: the "
                             "plant without --model, else the rig of the first model loaded)")
    parser.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for models:/ (default as train)")
    parser.add_argument("--follow-alias", type=float, default=0.0, metavar="SECONDS",
                        help="re-check a models:/NAME@ALIAS this often and switch when it moves (0: never)")
    parser.add_argument("--fleet", default="*", help="fleet to score (default: every fleet)")
    parser.add_argument("--shard", type=parse_shard, default=Shard(), help="score only shard i/n of the machines")
    parser.add_argument("--tick", type=float, default=0.05, help="seconds of chunks gathered per batch (default 0.05)")
    parser.add_argument("--smoothing", type=int, default=None, metavar="N",
                        help="methods that pool (parity): each verdict pools the machine's last N valid windows "
                             "(default 12: what spread severities and the open set need on working commands; 1: each "
                             "window alone; a new state is named after ~N/2 windows). Other methods: 1 only")
    parser.add_argument("--stagger", action=argparse.BooleanOptionalAction, default=True,
                        help="raw-window methods (parity, stats): start each machine's windows at a phase of its own "
                             "(from its name), so a "
                             "fleet started together, or every machine after a restart or a model switch, does not "
                             "close every window at once (default on; costs up to one window of samples after each "
                             "(re)start; --no-stagger: windows from each machine's first sample)")
    parser.add_argument("--no-recovery", action="store_true",
                        help="do not ask publishers' history for chunks missing from a machine's stream (a missed "
                             "chunk then invalidates its window)")
    parser.add_argument("--commissioning", default=None, metavar="FOLDER|URI",
                        help="parity bundles: per-machine bundles, a folder written by `hydrowatch commission --out "
                             "FOLDER/ID` or a registry template such as models:/hydrowatch-{machine}@champion "
                             "(`commission --register`); a machine without one (or commissioned from another fleet "
                             "model version) is judged by the fleet model, with a logged warning")
    parser.add_argument("--forecast-every", type=int, default=60, metavar="N",
                        help="methods with a degradation index (parity): publish a machine's forecast (…/forecast) "
                             "after every N of its windows, at a phase of its own (default 60: 5 min of 5 s windows; "
                             "12-22 ms per machine and forecast, 0.04-0.07 core per 1000 machines; 0: no forecasts)")
    parser.add_argument("--forecast-history", type=float, default=7200.0, metavar="SECONDS",
                        help="seconds of each machine's windows a forecast rests on (default 7200: 81 kB per machine; "
                             "a forecast reaches at most 10x this ahead)")
    parser.add_argument("--expected", action=argparse.BooleanOptionalAction, default=True,
                        help="methods that predict the sensors (parity, entropy): publish each window's measured and "
                             "expected sensors (…/expected, 50 points per sensor; the web page's chart; default on, "
                             "parity: ~0.3 ms and 3.4 kB per window, 0.06 core and 0.7 MB/s per 1000 machines; "
                             "--no-expected: none)")
    parser.add_argument("--seconds", type=float, default=None, help="stop after this many wall-clock seconds")
    add_bus_arguments(parser)


class _Units:
    """The machines' commissionings (``--commissioning``) for the fleet bundle in use, or none."""

    def __init__(self, args: argparse.Namespace, fleet: ModelBundle) -> None:
        from hydrowatch.training.commissioning import Commissionings

        source = args.commissioning
        self.found = None if source is None or not fleet.health_method.commissionable else Commissionings(
            source, fleet, args.tracking_uri)
        self.fleet = fleet

    def bundle(self, stream: str) -> ModelBundle:
        """The bundle judging ``fleet/machine``: its commissioning, else the fleet's."""
        found = None if self.found is None else self.found.for_machine(stream.split("/", 1)[1])
        return found or self.fleet

    def unit_method(self) -> Callable[[str], HealthMethod | None] | None:
        """What ``OnlineScorer(unit_method=...)`` takes (None without commissionings)."""
        if self.found is None:
            return None
        return lambda stream: self.bundle(stream).health_method


def _publish(publisher: Publisher, units: _Units, verdicts: list[WindowVerdict],
             forecasts: FleetForecasts | None) -> None:
    from hydrowatch.training.messages import expected_batch, forecast_batch, kl_batch, verdict_batch

    for item in verdicts:
        fleet, machine = item.machine.split("/", 1)
        bundle = units.bundle(item.machine)
        kl = kl_batch(item, bundle.kl_rows, bundle.states, bundle.version)
        if kl is not None:
            publisher.put(key(fleet, machine, "kl"), kl)
        publisher.put(key(fleet, machine, "health"), verdict_batch(item, bundle.version))
        expected = expected_batch(item, bundle.version)
        if expected is not None:
            publisher.put(key(fleet, machine, "expected"), expected)
    for due in forecasts.update(verdicts) if forecasts is not None else ():
        fleet, machine = due.machine.split("/", 1)
        publisher.put(key(fleet, machine, "forecast"), forecast_batch(due, units.bundle(due.machine).version))


def _forecasts(model: _Model, args: argparse.Namespace) -> FleetForecasts | None:
    """Each machine's history and forecast schedule (none with ``--forecast-every 0``); a new model starts them
    again, as its index starts again (the index is relative to the model's unit)."""
    from hydrowatch.training.forecasts import FleetForecasts

    if args.forecast_every < 0 or args.forecast_history <= 0:
        raise ParameterError(f"--forecast-every must be >= 0 (0: no forecasts) and --forecast-history > 0 s. Got "
                             f"{args.forecast_every} and {args.forecast_history}; the defaults are 60 and 7200.")
    if args.forecast_every == 0:
        return None
    hop_s = model.bundle.hop / SAMPLE_RATE_HZ
    return FleetForecasts(every=args.forecast_every, capacity=max(1, round(args.forecast_history / hop_s)),
                          stagger=args.stagger)


def _scorer(model: _Model, units: _Units, args: argparse.Namespace) -> OnlineScorer:
    from hydrowatch.training.online import OnlineScorer
    from hydrowatch.training.scoring import smoothing_for

    # a method that does not pool (entropy) judges each window alone, whatever --smoothing says
    pools = model.bundle.health_method.pools
    return OnlineScorer(model.bundle, smoothing=smoothing_for(model.bundle, args.smoothing) if pools else 1,
                        stagger=args.stagger, unit_method=units.unit_method(), expected=args.expected)


def run(args: argparse.Namespace, stop: threading.Event) -> int:
    """Score until ``stop`` (or ``--seconds``); returns 0."""
    for name, value in REGISTRY_ENV.items():
        os.environ.setdefault(name, value)
    model = _first_model(args, stop)
    if model is None:
        return 0
    model.follow(stop)
    if model.bundle.health_method.streams == "cycles":  # a rig's whole cycles, not sensor samples (docs/rigs.md)
        from services.scorer.cycles import run_cycles

        return run_cycles(model, args, stop, NAME)
    units = _Units(args, model.bundle)
    scorer = _scorer(model, units, args)
    forecasts = _forecasts(model, args)
    freeze_heap()
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    counters = {"verdicts": 0}
    with open_session(settings_from_args(args)) as session:
        shard = sharded(session, args.fleet, NAME, args.shard)
        subscriber = Subscriber(session, key_expr(args.fleet, "*", "sensors"), shard=shard)
        recovery = None if args.no_recovery else GapRecovery(session, shard=shard)
        publisher = Publisher(session)
        reporter = StatusReporter(session, args.fleet if args.fleet != "*" else "all", NAME, lambda: {
            "messages_in": subscriber.received, "messages_out": publisher.messages_out,
            "messages_undecodable": subscriber.undecodable_total})
        try:
            reporter.start()
            reporter.status = "running"
            event(log, "scorer started", model=model.bundle.version, shard=str(args.shard), fleet=args.fleet)
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                before = scorer
                units, scorer, verdicts = _step(model, units, scorer, args,
                                                lambda columns: _gather(subscriber, args.tick, columns, recovery))
                if scorer is not before:  # a new model: its index starts again, and so do the histories
                    forecasts = _forecasts(model, args)
                _publish(publisher, units, verdicts, forecasts)
                counters["verdicts"] += len(verdicts)
            reporter.status = "draining"
            subscriber.close()
            last = list(subscriber.drain())
            rest = _chunks(recovery.observe(last) + recovery.wait() if recovery else last, scorer.columns)
            _publish(publisher, units, scorer.update(rest), forecasts)
        finally:
            subscriber.close()
            release(shard)
            reporter.stop()
            publisher.close()
            stop.set()  # ends the alias follower (a --seconds run ends without a signal)
            model.join()
    if subscriber.undecodable_total:
        event(log, "undecodable messages skipped", logging.WARNING, count=subscriber.undecodable_total)
    event(log, "scorer stopped", verdicts=counters["verdicts"], machines=len(scorer.machines), samples=scorer.samples)
    return 0


def _step(model: _Model, units: _Units, scorer: OnlineScorer, args: argparse.Namespace,
          gather: Callable[[Sequence[str]], ChunkBatch | None]) -> tuple[_Units, OnlineScorer, list[WindowVerdict]]:
    """One turn of the loop: switch model if the alias moved, *then* gather chunks of the channels the scorer in
    use reads (a new bundle may read another channel, e.g. temperature) and score them."""
    if model.moved():
        units = _Units(args, model.bundle)
        scorer = _scorer(model, units, args)
        freeze_heap()
    chunks = gather(scorer.columns)
    return units, scorer, scorer.update(chunks) if chunks else []


def _chunks(messages: list[Message], columns: Sequence[str]) -> ChunkBatch:
    from hydrowatch.training.online import chunks_from_batches

    return chunks_from_batches([f"{m.key.fleet}/{m.key.machine}" for m in messages], [m.batch for m in messages],
                               columns)


def _gather(subscriber: Subscriber, tick: float, columns: Sequence[str],
            recovery: GapRecovery | None) -> ChunkBatch | None:
    """Chunks received within ``tick`` seconds of the first one (at most 0.1 s waiting for it), with what
    ``recovery`` fetched or held back meanwhile (each machine's chunks in order)."""
    messages: list[Message] = []
    first = subscriber.recv(timeout=0.1)
    if first is not None:
        messages.append(first)
        end = time.monotonic() + tick
        while (left := end - time.monotonic()) > 0:
            message = subscriber.recv(timeout=left)
            if message is None:
                break
            messages.append(message)
    if recovery is not None:
        messages = recovery.observe(messages) + recovery.collect()
    return _chunks(messages, columns) if messages else None


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.scorer``."""
    return service_main(NAME, HELP, add_arguments, run, argv)
