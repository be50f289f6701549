"""compose.yaml parses and every command in it is a valid hydrowatch invocation."""

from __future__ import annotations

from pathlib import Path

import yaml

from hydrowatch.cli import build_parser

COMPOSE = Path(__file__).resolve().parent.parent / "compose.yaml"


def test_compose_services_are_valid_hydrowatch_invocations() -> None:
    spec = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))
    services = spec["services"]
    assert services["zenoh"]["image"].startswith("eclipse/zenoh")
    mlflow = " ".join(services["mlflow"]["command"].split())
    assert "--backend-store-uri postgresql://" in mlflow and "postgres" in services
    parser = build_parser()
    commands = {}
    for name, service in services.items():
        command = service.get("command")
        if isinstance(command, list) and command[0] == "hydrowatch":
            args = parser.parse_args(command[1:])  # exits (fails the test) on an invalid invocation
            commands[name] = args.subcommand
            assert service["environment"]["HYDROWATCH_ZENOH_CONNECT"] == "tcp/zenoh:7447"
    assert commands == {"plant": "plant", "record-0": "record", "record-1": "record", "trainer": "trainer",
                        "score-0": "scorer", "score-1": "scorer"}
    for pair in (("record-0", "record-1"), ("score-0", "score-1")):
        shards = sorted(str(parser.parse_args(services[n]["command"][1:]).shard) for n in pair)
        assert shards == ["0/2", "1/2"], pair
