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
when it moves; an alias that does not exist yet is waited for. SIGINT/SIGTERM drains and exits.
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
from hydrowatch.errors import DataError, ParameterError
from hydrowatch.log import event, get_logger
from hydrowatch.recording import SAMPLE_RATE_HZ
from hydrowatch.rig import BUILTIN
from hydrowatch.rig.plant import PLANT_RIG
from hydrowatch.training.options import default_model_uri

if TYPE_CHECKING:  # the model code (torch) is imported when the service runs, not when the CLI parses
    from hydrowatch.bus import Message
    from hydrowatch.methods.base import HealthMethod
    from hydrowatch.rig import RigDescription
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
                        help="seconds of each machine's windows a forecast rests on (default 7200: 46 kB per machine; "
                             "a forecast reaches at most 10x this ahead)")
    parser.add_argument("--expected", action=argparse.BooleanOptionalAction, default=True,
                        help="methods that predict the sensors (parity, entropy): publish each window's measured and "
                             "expected sensors (…/expected, 50 points per sensor; the web page's chart; default on, "
                             "parity: ~0.3 ms and 3.4 kB per window, 0.06 core and 0.7 MB/s per 1000 machines; "
                             "--no-expected: none)")
    parser.add_argument("--seconds", type=float, default=None, help="stop after this many wall-clock seconds")
    add_bus_arguments(parser)


REGISTRY_ENV = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2", "MLFLOW_HTTP_REQUEST_TIMEOUT": "10"}
"""MLflow client defaults in the scorer (the environment wins): a registry look-up fails within ~20 s when the server is
down instead of retrying for minutes (MLflow's 7 retries with doubling back-off), so that the alias is looked at
again soon after the server returns."""


class _Model:
    """The bundle in use and, for a followed registry alias, a thread that looks at the alias.

    The thread (:meth:`follow`) resolves the alias every ``--follow-alias`` seconds and, when it moved, loads the new
    version; the scoring loop takes it at its next turn (:meth:`moved`). The loop never waits on MLflow: while the
    server cannot be reached (down, restarting) the thread logs it once, keeps the model in use, and tries again.
    Every model must serve ``served`` (None: the first model's rig; :mod:`hydrowatch.training.served`): the first is
    refused with a DataError, a followed version is logged and skipped (:meth:`take`).
    """

    def __init__(self, args: argparse.Namespace, served: RigDescription | None = None) -> None:
        from hydrowatch.training.bundle import load_bundle
        from hydrowatch.training.served import bundle_rig, check_served

        self.args = args
        self.bundle: ModelBundle = load_bundle(args.model, args.tracking_uri)
        self.served: RigDescription = served if served is not None else bundle_rig(self.bundle)
        check_served(self.bundle, self.served, str(args.model))
        self._loaded = self.bundle.version
        self._refused: set[str] = set()
        self._next: ModelBundle | None = None
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    @property
    def following(self) -> bool:
        return self.args.follow_alias > 0 and "@" in str(self.args.model)

    def follow(self, stop: threading.Event) -> None:
        """Start following the alias until ``stop`` (nothing without ``--follow-alias`` or an alias)."""
        if self.following:
            self._thread = threading.Thread(target=self._follow, args=(stop,), name="follow-alias", daemon=True)
            self._thread.start()

    def join(self) -> None:
        if self._thread is not None:
            self._thread.join(timeout=30)

    def moved(self) -> bool:
        """True when the followed alias moved and its new version is now :attr:`bundle`."""
        with self._lock:
            found, self._next = self._next, None
        if found is None:
            return False
        self.bundle = found
        event(log, "model switched", model=self.args.model, version=found.version)
        return True

    def _follow(self, stop: threading.Event) -> None:
        from hydrowatch.training.bundle import load_bundle
        from hydrowatch.training.tracking import parse_model_uri, resolve_version

        a, name, down = self.args, parse_model_uri(self.args.model)[0], False
        while not stop.wait(a.follow_alias):
            try:
                version, _ = resolve_version(a.model, a.tracking_uri)
                current = f"{name}/v{version}"
                found = None if current == self._loaded or current in self._refused else load_bundle(
                    a.model, a.tracking_uri)
            except Exception as exc:  # noqa: BLE001 - any failure to reach or read the registry: keep scoring
                if not down:
                    event(log, "registry unreachable; scoring on with the model in use", logging.WARNING,
                          model=a.model, version=self._loaded, reason=str(exc).split("\n")[0][:300])
                down = True
                continue
            if down:
                event(log, "registry reachable again", model=a.model, version=self._loaded)
                down = False
            if found is not None:
                self.take(found)

    def take(self, found: ModelBundle) -> bool:
        """Hand ``found`` (the followed alias's new version) to the scoring loop, or refuse it when it cannot serve
        the rig (logged once per version; the model in use stays); returns whether it was taken."""
        from hydrowatch.training.served import check_served

        try:
            check_served(found, self.served, str(self.args.model))
        except DataError as exc:
            self._refused.add(found.version)
            event(log, "model refused; scoring on with the model in use", logging.WARNING, model=self.args.model,
                  refused=found.version, version=self._loaded, reason=str(exc))
            return False
        with self._lock:
            self._next, self._loaded = found, found.version
        return True


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


def served_rig(args: argparse.Namespace) -> RigDescription | None:
    """The rig the scorer serves: ``--rig``'s, the plant's when neither ``--rig`` nor ``--model`` is given, else None
    (the first model's rig); fills in ``args.model`` left out with the served rig's registered model
    (:func:`~hydrowatch.training.options.default_model_uri`)."""
    from hydrowatch.rig.plant import any_rig

    served = any_rig(args.rig) if args.rig is not None else any_rig(PLANT_RIG) if args.model is None else None
    if args.model is None:
        args.model = default_model_uri(served.name if served is not None else PLANT_RIG)
    return served


def _first_model(args: argparse.Namespace, stop: threading.Event) -> _Model | None:
    """The model to start with, refused when made for another rig than the one served (:func:`served_rig`). A
    registry alias followed with ``--follow-alias`` that does not exist yet (a trainer
    started beside the scorer has not registered its first model) or cannot be read (the server is not up) is looked
    for again every ``--follow-alias`` seconds, logged once; None when ``stop`` comes first. Anything else that cannot
    be loaded raises."""
    served = served_rig(args)
    waiting = args.follow_alias > 0 and str(args.model).startswith("models:/")
    logged = False
    unreachable: tuple[type[Exception], ...] = (DataError,)
    if waiting:  # a server not up yet: MLflow's own errors, or the network's (requests' are OSErrors)
        from mlflow.exceptions import MlflowException

        unreachable = (DataError, OSError, MlflowException)
    while True:
        try:
            return _Model(args, served)
        except unreachable as exc:
            if not waiting:
                raise
            if not logged:
                event(log, "waiting for the model", logging.WARNING, model=args.model, reason=str(exc))
                logged = True
        if stop.wait(args.follow_alias):
            return None


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
