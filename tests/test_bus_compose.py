"""compose.yaml stays equivalent to the topology that ``hydrowatch up`` and the tests start (issue 18, item 6):
``up`` on loopback and :class:`hydrowatch.testbed.topology.Topology`, the router topology of
tests/test_bus_topology.py.

The same services (plant, recorder shards, trainer, scorer shards), each command's flags parsed by that service's
own parser (what ``python -m services.<name>`` accepts, not only the ``hydrowatch`` CLI), the router endpoint the
services connect to being the one the router listens on, the trainer reading the recorders' folder and the
scorers following the model the trainer registers.
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path
from types import ModuleType
from urllib.parse import urlsplit

import pytest
import yaml

from hydrowatch.bus import BusSettings
from hydrowatch.bus.service import service_parser
from hydrowatch.bus.session import ENV_CONNECT, settings_from_args
from hydrowatch.cli import build_parser
from hydrowatch.commands import up
from hydrowatch.training.options import tracking_names

COMPOSE = Path(__file__).resolve().parent.parent / "compose.yaml"
SERVICES = {"plant": "services.plant", "record": "services.recorder", "trainer": "services.trainer",
            "scorer": "services.scorer", "web": "services.web"}
"""Services deployed (``hydrowatch up --services`` names → their package); ``watch`` is an operator's view."""


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))["services"]


def service_module(command: str) -> ModuleType:
    return importlib.import_module(SERVICES[command])


def parse_as_service(command: str, argv: list[str]) -> argparse.Namespace:
    """``argv`` parsed by the service's own parser; a flag it does not take fails the test by name."""
    module = service_module(command)
    try:
        return service_parser(module.NAME, module.HELP, module.add_arguments).parse_args(argv)
    except SystemExit:
        pytest.fail(f"{command} does not take {argv}")


def hydrowatch_services(compose: dict) -> dict[str, tuple[str, argparse.Namespace, dict]]:
    """Compose service → (subcommand, its arguments parsed by the service's own parser, environment)."""
    parser, found = build_parser(), {}
    for name, service in compose.items():
        command = service.get("command")
        if isinstance(command, list) and command[0] == "hydrowatch":
            args = parser.parse_args(command[1:])  # exits (fails the test) on an invalid invocation
            at = command.index(args.subcommand)
            found[name] = (args.subcommand, parse_as_service(args.subcommand, command[at + 1:]),
                           service["environment"])
    return found


def test_compose_services_are_valid_hydrowatch_invocations(compose: dict) -> None:
    assert compose["zenoh"]["image"].startswith("eclipse/zenoh")
    mlflow = " ".join(compose["mlflow"]["command"].split())
    assert "--backend-store-uri postgresql+psycopg2://" in mlflow and "postgres" in compose
    commands = {name: command for name, (command, _, _) in hydrowatch_services(compose).items()}
    assert commands == {"plant": "plant", "record-0": "record", "record-1": "record", "trainer": "trainer",
                        "score-0": "scorer", "score-1": "scorer", "web": "web"}
    assert set(commands.values()) == set(up.KNOWN) - {"watch"} == set(SERVICES)


def test_compose_shards_cover_the_fleet(compose: dict) -> None:
    shards: dict[str, list[str]] = {}
    for command, args, _ in hydrowatch_services(compose).values():
        if command in ("record", "scorer"):
            shards.setdefault(command, []).append(str(args.shard))
    n = len(shards["record"])
    assert n > 1 and sorted(shards["record"]) == sorted(shards["scorer"]) == [f"{i}/{n}" for i in range(n)]


def test_up_hands_each_service_only_flags_it_takes(tmp_path: Path) -> None:
    # `up --services plant,record,trainer,scorer` once gave the trainer bus flags it does not take (issue 18)
    parser = argparse.ArgumentParser()
    up.add_arguments(parser)
    args = parser.parse_args(["--services", ",".join(SERVICES), "--out", str(tmp_path), "--tracking-uri", "sqlite://",
                              "--degrade", "m001=load:0:1.2:600", "--degrade", "pump_leak:0:1:900:exp"])
    for spec in up.service_specs(args, 7555):
        parsed = parse_as_service(spec.name, list(spec.argv))
        if spec.name == "plant":  # the fleet's wearing machines go to the plant
            assert parsed.degrade == ["m001=load:0:1.2:600", "pump_leak:0:1:900:exp"]
        if hasattr(parsed, "connect"):  # on the bus: a client of up's router
            router = BusSettings(mode="router", port=7555).to_json()["listen"]["endpoints"]
            assert settings_from_args(parsed).resolved_mode == "client" and list(parsed.connect) == router


def test_compose_services_connect_to_the_router_compose_starts(compose: dict) -> None:
    router = compose["zenoh"]["command"]
    listen = urlsplit("//" + router[router.index("--listen") + 1].split("/", 1)[1])
    assert "--no-multicast-scouting" in router and f"{listen.port}:{listen.port}" in compose["zenoh"]["ports"]
    mlflow = compose["mlflow"]["command"].split()
    for name, (command, args, env) in hydrowatch_services(compose).items():
        assert "zenoh" in compose[name]["depends_on"], name
        if command != "trainer":  # the trainer is not on the bus
            settings = BusSettings.from_env(env, mode=args.mode, connect=args.connect, listen=args.listen,
                                            port=args.bus_port, config_file=args.zenoh_config)
            assert settings.resolved_mode == "client" and settings.connect == (f"tcp/zenoh:{listen.port}",), name
            assert env[ENV_CONNECT] == f"tcp/zenoh:{listen.port}"
        tracking = urlsplit(env["MLFLOW_TRACKING_URI"])
        assert tracking.hostname in compose and str(tracking.port) == mlflow[mlflow.index("--port") + 1], name


def test_compose_topology_is_the_one_up_starts(compose: dict) -> None:
    services = hydrowatch_services(compose)
    by_command: dict[str, list[tuple[str, argparse.Namespace]]] = {}
    for name, (command, args, _) in services.items():
        by_command.setdefault(command, []).append((name, args))
    (plant,), (trainer_name, trainer) = by_command["plant"], by_command["trainer"][0]
    fleets = {args.fleet for command in ("plant", "record", "scorer", "web") for _, args in by_command[command]}
    assert fleets == {plant[1].fleet}, "plant, recorders, scorers and the web page on one fleet"
    for name, recorder in by_command["record"]:
        # the trainer reads the recorders' folder (same volume, same path) ...
        mounted = {v.split(":")[0]: v.split(":")[1] for v in compose[name]["volumes"]}
        trained = {v.split(":")[0]: v.split(":")[1] for v in compose[trainer_name]["volumes"]}
        volume = next(v for v, path in mounted.items() if Path(path) == recorder.out)
        assert Path(trained[volume]) == trainer.data == recorder.out, name
        # ... and finds finished files: as `up` does, the recorders close theirs every half training period
        assert recorder.rotate_s <= max(trainer.every / 2, 10.0), name
    for name, scorer in by_command["scorer"]:  # the scorers follow what the trainer registers
        registered = tracking_names(trainer)[1]  # --model-name, else the plant's (options.mlflow_name)
        assert scorer.model == f"models:/{registered}@{trainer.alias}" and scorer.follow_alias > 0, name


def test_compose_runs_the_router_topology_the_tests_start(compose: dict, tmp_path: Path) -> None:
    from hydrowatch.testbed.topology import MODULES, Topology, TopologySettings

    tested = Topology(tmp_path, TopologySettings(namespaces=False, postgres=False)).commands()
    deployed = hydrowatch_services(compose)
    # the same services on the same hosts (compose's router is zenohd, the test's the same router from zenoh's
    # Python package; compose's MLflow server runs on PostgreSQL, as the test's where PostgreSQL is installed)
    assert tested.pop("router")[0] == "router" and "zenoh" in compose and "postgres" in compose
    assert {host: command for host, (command, _) in tested.items()} == {
        name: command for name, (command, _, _) in deployed.items()}
    parsed = {}
    for host, (command, argv) in tested.items():
        module = importlib.import_module(MODULES[command])
        parsed[host] = service_parser(module.NAME, module.HELP, module.add_arguments).parse_args(argv)
    for host, args in parsed.items():
        _, theirs, env = deployed[host]
        for name in ("shard", "method", "alias", "history"):
            assert getattr(args, name, None) == getattr(theirs, name, None), (host, name)
        if host == "trainer":  # the same experiment and registered model, given or left to the plant's default
            assert tracking_names(args) == tracking_names(theirs)
        if host.startswith("score"):
            registered = tracking_names(parsed["trainer"])[1]
            assert args.model == theirs.model == f"models:/{registered}@{parsed['trainer'].alias}"
            assert args.follow_alias > 0 and theirs.follow_alias > 0
        if host.startswith("record"):  # the trainer reads what the recorders write, in both
            assert args.out == parsed["trainer"].data and args.rotate_s <= max(parsed["trainer"].every / 2, 10.0)
        if host != "trainer":  # clients of the router, in both
            assert settings_from_args(args).resolved_mode == "client" and len(args.connect) == 1, host
            assert env[ENV_CONNECT].rsplit(":", 1)[1] == args.connect[0].rsplit(":", 1)[1], host
