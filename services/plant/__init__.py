"""Plant service: publishes a simulated fleet on ``hydro/<fleet>/<machine>/sensors``.

Each machine runs the streaming plant simulator (:class:`hydrowatch.plant.PlantSimulator`, all
machines batched) under its own filtered-noise command; every ``--chunk`` seconds of simulated
time one ``sensor_chunk`` per machine goes out, in real time (``--speed 1``), accelerated
(``--speed 10``) or as fast as possible (``--speed inf``). Machines get the health states of
``--states`` in turn, each with a severity drawn inside its level's band. ``--shard i/n``
simulates only the machines of that shard, so a large fleet spreads over processes. ``--degrade
[MACHINE=]FAULT:FROM:TO:SECONDS[:linear|exp]`` makes a machine wear along a path (as ``simulate --degrade``;
:class:`hydrowatch.plant.wear.Wear`), its label following the level it has reached.
"""

from __future__ import annotations

import argparse
import logging
import math
import threading
import time
from collections.abc import Sequence
from contextlib import nullcontext

import numpy as np

from hydrowatch.bus import Publisher, Shard, StatusReporter, add_bus_arguments, key_expr, open_session, parse_shard
from hydrowatch.bus.fleet_publisher import FleetPublisher
from hydrowatch.bus.history import ChunkHistory, HistoryServer
from hydrowatch.bus.service import LINGER_S, service_main
from hydrowatch.bus.session import settings_from_args
from hydrowatch.channels import PLANT
from hydrowatch.errors import ParameterError
from hydrowatch.log import event, get_logger
from hydrowatch.plant import PlantSimulator
from hydrowatch.plant.excitation import FilteredNoiseCommand, parse_volts
from hydrowatch.plant.faults import parse_state, random_state_parameters
from hydrowatch.plant.paths import FORM, parse_degradation
from hydrowatch.plant.wear import DegradationPath, Wear
from hydrowatch.recording import SAMPLE_RATE_HZ
from services.plant.stepper import SimulationThread

NAME = "plant"
HELP = "publish a simulated fleet on hydro/<fleet>/<machine>/sensors in real time or faster"
CHANNELS = PLANT.names
"""Channels of every published chunk by default: all the plant's, in ``sensor_chunk`` order (``--channels``: fewer)."""
log = get_logger("services.plant")


def machine_ids(n_machines: int) -> list[str]:
    """Ids ``m000``, ``m001``, … (zero-padded to at least 3 digits)."""
    width = max(3, len(str(n_machines - 1)))
    return [f"m{i:0{width}d}" for i in range(n_machines)]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--fleet", default="fleet1", help="fleet id in the keys (default fleet1)")
    parser.add_argument("--machines", type=int, default=10, help="machines in the fleet (default 10)")
    parser.add_argument("--states", default="healthy",
                        help="comma-separated health states, given to the machines in turn (default healthy)")
    parser.add_argument("--chunk", type=float, default=0.1, help="seconds of samples per message (default 0.1)")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="simulated seconds per wall-clock second; inf: as fast as possible (default 1)")
    parser.add_argument("--seconds", type=float, default=math.inf,
                        help="stop after this much simulated time, s (default: run until stopped)")
    parser.add_argument("--volts", type=parse_volts, default=(0.0, 4.0), help="command range LO:HI, V (default 0:4)")
    parser.add_argument("--seed", type=int, default=0, help="seed of commands, severities and noise (default 0)")
    parser.add_argument("--shard", type=parse_shard, default=Shard(), help="simulate only shard i/n of the fleet")
    parser.add_argument("--wait-subscribers", type=float, default=0.0, metavar="SECONDS",
                        help="before publishing, wait up to this long for a subscriber on every key (default 0)")
    parser.add_argument("--linger", type=float, default=LINGER_S, metavar="SECONDS",
                        help=f"after the last message, wait this long before leaving the bus (default {LINGER_S:g})")
    parser.add_argument("--express", action="store_true",
                        help="send every message at once instead of batching (lower latency, lower throughput)")
    parser.add_argument("--machine-tokens", action="store_true",
                        help="also declare a liveliness token per machine (hydro/<fleet>/<machine>/status); "
                             "costs every subscriber of the fleet ~0.1 µs per machine per message (docs/bus.md)")
    parser.add_argument("--history", type=float, default=5.0, metavar="SECONDS",
                        help="keep each machine's last chunks this long and serve them to subscribers that missed "
                             "some (hydrowatch.bus.history; 0: off; default 5)")
    parser.add_argument("--drop-every", type=int, default=0, metavar="N",
                        help="fault injection: leave every N-th message off the bus (it stays in the history), "
                             "to exercise recorders' recovery (default 0: none)")
    parser.add_argument("--degrade", action="append", default=[], metavar=f"[MACHINE=]{FORM}",
                        help="a machine wearing from index FROM to TO (0 new, 0.5 warning, 1 alert) over SECONDS of "
                             "simulated time from the start, e.g. m003=load:0:1.3:3600:exp; repeatable; without "
                             "MACHINE the paths go to m000, m001, … in order; the machine's --states entry is "
                             "replaced by the path")
    parser.add_argument("--no-noise", action="store_true", help="switch sensor noise off")
    parser.add_argument("--no-label", action="store_true", help="leave the per-sample 'state' column out")
    parser.add_argument("--channels", default=",".join(CHANNELS), metavar="C1,C2,...",
                        help="channels to publish: the command and at least one sensor, e.g. voltage,speed,torque "
                             "for machines without a flow meter (default: all of " + ",".join(CHANNELS) + ")")
    add_bus_arguments(parser)


def _check(args: argparse.Namespace) -> int:
    if args.machines < 1:
        raise ParameterError(f"--machines must be >= 1. Got {args.machines}.")
    n = int(round(args.chunk * SAMPLE_RATE_HZ))
    if n < 1 or not math.isfinite(args.chunk):
        raise ParameterError(f"--chunk must be at least one sample (1/{SAMPLE_RATE_HZ:g} s). Got {args.chunk}.")
    if not args.speed > 0:
        raise ParameterError(f"--speed must be > 0 (or inf). Got {args.speed}.")
    if not args.history >= 0 or args.drop_every < 0:
        raise ParameterError(f"--history and --drop-every must be >= 0. Got {args.history} and {args.drop_every}.")
    return n


def degradation_paths(specs: Sequence[str], machines: Sequence[str]) -> dict[str, DegradationPath]:
    """Machine id → path of ``--degrade [MACHINE=]FAULT:FROM:TO:SECONDS[:shape]`` texts (those without MACHINE go to
    the first machines not named, in order).

    Raises
    ------
    ParameterError
        A machine that is not in the fleet, one given two paths, more paths than machines, or a bad path.
    """
    named: dict[str, DegradationPath] = {}
    unnamed = []
    for spec in specs:
        machine, _, path = spec.rpartition("=")
        if machine and machine not in machines:
            raise ParameterError(f"--degrade MACHINE must be one of the fleet's machines ({machines[0]}…"
                                 f"{machines[-1]}). Got {machine!r} in {spec!r}.")
        if machine in named:
            raise ParameterError(f"--degrade must give each machine one path. Got two for {machine!r}.")
        if machine:
            named[machine] = parse_degradation(path)
        else:
            unnamed.append(parse_degradation(path))
    free = [m for m in machines if m not in named]
    if len(unnamed) > len(free):
        raise ParameterError(f"--degrade must give at most one path per machine. Got {len(specs)} paths for "
                             f"{len(machines)} machines.")
    return {**named, **dict(zip(free, unnamed))}


def run(args: argparse.Namespace, stop: threading.Event) -> int:
    """Simulate and publish until ``--seconds`` of simulated time or ``stop``; returns 0."""
    n = _check(args)
    channels = PLANT.select(args.channels)  # a bad --channels fails before the bus is opened
    states = [s.strip() for s in args.states.split(",") if s.strip()]
    for state in states:
        parse_state(state)
    everyone = machine_ids(args.machines)
    mine = [(i, m) for i, m in enumerate(everyone) if args.shard.includes(m)]
    if not mine:
        event(log, "no machine in this shard", shard=str(args.shard))
        return 0
    paths = degradation_paths(args.degrade, everyone)
    rng = np.random.default_rng(args.seed)
    labels = [states[i % len(states)] for i, _ in mine]
    parameters = [random_state_parameters(label, rng)[0] for label in labels]
    worn = {j: paths[m] for j, (_, m) in enumerate(mine) if m in paths}
    wear = Wear(worn, {j: random_state_parameters("healthy", rng)[0] for j in worn}) if worn else None
    for j, p in wear.due(0.0) if wear is not None else ():
        parameters[j] = p
    labels = wear.states(0.0, labels) if wear is not None else labels
    sim = PlantSimulator(parameters, noise=not args.no_noise, seed=args.seed)
    # load the compiled kernel now: the first step would otherwise come ~1 s late and the plant
    # would catch up in one burst (a latency spike at start-up)
    PlantSimulator(parameters[:1], noise=not args.no_noise, seed=args.seed).step(np.zeros(1))
    command = FilteredNoiseCommand(len(mine), args.volts, seed=args.seed + 1)
    samples = 0
    depth = int(math.ceil(args.history / args.chunk))
    history = ChunkHistory(depth) if depth else None
    with open_session(settings_from_args(args)) as session, \
            (HistoryServer(session, key_expr(args.fleet), history) if history else nullcontext()):
        publisher = Publisher(session, express=args.express)
        fleet = FleetPublisher(publisher, args.fleet, [m for _, m in mine], channels,
                               None if args.no_label else labels, history, args.drop_every)
        reporter = StatusReporter(session, args.fleet, NAME, lambda: {"messages_out": publisher.messages_out},
                                  machines=[m for _, m in mine] if args.machine_tokens else ())
        steps = SimulationThread(sim, command, n, args.seconds, stop, wear=wear)
        publish_cpu_s = 0.0
        try:
            reporter.start()
            if (args.wait_subscribers > 0 and not publisher.wait_for_subscribers(fleet.keys, args.wait_subscribers,
                                                                                  stop=stop) and not stop.is_set()):
                event(log, "no subscriber on some keys; publishing anyway", logging.WARNING,
                      waited_s=args.wait_subscribers)
            reporter.status = "running"
            event(log, "plant started", fleet=args.fleet, machines=len(mine), shard=str(args.shard), speed=args.speed)
            wall0, cpu0 = time.monotonic(), time.thread_time()
            steps.start()
            for out, end_time in steps:
                if wear is not None and not args.no_label:  # a wearing machine's label follows its path's level
                    fleet.publish(out, wear.states(float(out["t"][0, 0]), labels))
                else:
                    fleet.publish(out)
                samples += n * len(fleet.keys)
                if math.isfinite(args.speed):
                    ahead = wall0 + end_time / args.speed - time.monotonic()
                    if ahead > 0:
                        stop.wait(ahead)
            publish_cpu_s = time.thread_time() - cpu0
            reporter.status = "draining"
            # what is still in the sockets is lost if this session closes before subscribers read it
            time.sleep(args.linger)
        finally:
            steps.close()
            reporter.stop()
            publisher.close()
    event(log, "plant stopped", messages=publisher.messages_out, dropped_on_purpose=fleet.dropped, samples=samples,
          served_from_history=history.served if history else 0, simulated_s=round(sim.time, 3),
          cpu_simulation_s=round(steps.cpu_s, 2), cpu_publish_s=round(publish_cpu_s, 2))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.plant``."""
    return service_main(NAME, HELP, add_arguments, run, argv)
