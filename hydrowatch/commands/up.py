"""``hydrowatch up``: start the services as local processes on one loopback bus; stop them together.

The ``up`` process itself hosts the bus: a zenoh router on ``tcp/127.0.0.1:<port>`` that lives as
long as the services, which join it as clients (the same layout as compose.yaml, on loopback). The
trainer is not on the bus: it trains on the recorder's folder every ``--retrain`` seconds and
registers each model in MLflow; the scorer follows the registry alias, waiting for the first model.
The web service (``hydrowatch web``, started by default) serves the live fleet page; ``up`` prints its
address (port ``--web-port``, else 8050 when free, else any free port).
"""

from __future__ import annotations

import argparse
import threading
from pathlib import Path

from hydrowatch.bus.launch import ServiceSpec, supervise
from hydrowatch.bus.service import command_run
from hydrowatch.bus.session import DEFAULT_PORT, BusSettings, free_port, open_session
from hydrowatch.errors import ParameterError
from hydrowatch.training.options import DEFAULT_CLI_METHOD, GROUPS, METHODS
from hydrowatch.web import DEFAULT_PORT as WEB_PORT
from hydrowatch.web import web_port

NAME = "up"
HELP = "start plant, recorder (and other services) as local processes on one loopback bus; Ctrl-C stops all"
KNOWN = ("plant", "record", "trainer", "scorer", "web", "watch")
MODULES = {"plant": "services.plant", "record": "services.recorder", "web": "services.web"}
"""Services started as ``python -m services.<name>`` (imports only what they need)."""
FOLLOW_S = 5.0
"""How often the scorer looks for a new registered version (and, before the first training, for any), s."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--services", default="plant,record,web",
                        help=f"comma-separated services among {','.join(KNOWN)} (default plant,record,web)")
    parser.add_argument("--fleet", default="fleet1", help="fleet id (default fleet1)")
    parser.add_argument("--machines", type=int, default=10, help="simulated machines (default 10)")
    parser.add_argument("--states", default="healthy", help="health states given to the machines in turn")
    parser.add_argument("--degrade", action="append", default=[], metavar="[MACHINE=]FAULT:FROM:TO:SECONDS[:shape]",
                        help="plant: a machine wearing along a path, as `hydrowatch plant --degrade` (repeatable)")
    parser.add_argument("--speed", default="1", help="plant speed: simulated s per wall-clock s, or inf")
    parser.add_argument("--seed", type=int, default=0, help="plant seed (default 0)")
    parser.add_argument("--out", type=Path, default=Path("recordings"), help="recorder output folder")
    parser.add_argument("--seconds", type=float, default=None, help="stop everything after this many seconds")
    parser.add_argument("--bus-port", type=int, default=DEFAULT_PORT,
                        help=f"loopback rendezvous port of the bus (default {DEFAULT_PORT}; 0: any free port)")
    parser.add_argument("--retrain", type=float, default=60.0,
                        help="trainer: seconds between trainings on the recorder's folder (default 60)")
    parser.add_argument("--models", type=Path, default=Path("models/latest"), help="trainer: bundle folder")
    parser.add_argument("--method", choices=(*METHODS, *GROUPS), default=DEFAULT_CLI_METHOD,
                        help=f"trainer: health method(s), as `hydrowatch train` (default {DEFAULT_CLI_METHOD})")
    parser.add_argument("--tracking-uri", default=None,
                        help="MLflow tracking URI shared by trainer and scorer (default as `hydrowatch train`)")
    parser.add_argument("--web-port", type=int, default=None,
                        help=f"web: HTTP port of the fleet page (default {WEB_PORT} when free, else any free port)")


def service_specs(args: argparse.Namespace, port: int, http_port: int = WEB_PORT) -> list[ServiceSpec]:
    """What ``up`` starts, each a client of the router on loopback ``port`` (the web page on ``http_port``)."""
    names = [s.strip() for s in args.services.split(",") if s.strip()]
    unknown = sorted(set(names) - set(KNOWN))
    if unknown or not names:
        raise ParameterError(f"--services must be among {','.join(KNOWN)}. Got {args.services!r}.")
    bus = ("--connect", f"tcp/127.0.0.1:{port}")
    tracking = () if args.tracking_uri is None else ("--tracking-uri", args.tracking_uri)
    per_service = {
        "plant": ("--fleet", args.fleet, "--machines", str(args.machines), "--states", args.states,
                  "--speed", str(args.speed), "--seed", str(args.seed), "--wait-subscribers", "10",
                  *(a for spec in args.degrade for a in ("--degrade", spec)), *bus),
        # files closed every half retraining period, so that the trainer finds readable ones
        "record": ("--fleet", args.fleet, "--out", str(args.out), *bus,
                   *(("--rotate-s", str(max(args.retrain / 2.0, 10.0))) if "trainer" in names else ())),
        # not on the bus: it reads the recorder's folder and registers in MLflow, which the scorer follows
        "trainer": ("--data", str(args.out), "--out", str(args.models), "--every", str(args.retrain),
                    "--method", args.method, *tracking),
        "scorer": ("--fleet", args.fleet, "--follow-alias", str(FOLLOW_S), *tracking, *bus),
        "web": ("--fleet", args.fleet, "--port", str(http_port), *bus),
        "watch": ("--fleet", args.fleet, *bus),
    }
    verbose = getattr(args, "verbose", 0)
    return [ServiceSpec(name, name, per_service[name], verbose, MODULES.get(name)) for name in names]


def _up(args: argparse.Namespace, stop: threading.Event) -> int:
    port = args.bus_port or free_port()
    http_port = web_port(args.web_port)
    specs = service_specs(args, port, http_port)
    if any(spec.name == "web" for spec in specs):
        print(f"fleet page: http://127.0.0.1:{http_port}/", flush=True)
    with open_session(BusSettings(mode="router", port=port)):
        return supervise(specs, stop, seconds=args.seconds)


run = command_run(_up)
