"""Keys, shards and session configuration of the bus (no network)."""

from __future__ import annotations

import json

import pytest

from hydrowatch.bus import BusSettings, Shard, key, key_expr, machine_hash, parse_key, parse_shard
from hydrowatch.errors import DataError, ParameterError


def test_key_round_trip_and_wildcards() -> None:
    assert key("f1", "m007", "sensors") == "hydro/f1/m007/sensors"
    assert parse_key("hydro/f1/m007/health") == ("f1", "m007", "health")
    assert key_expr() == "hydro/*/*/sensors"
    assert key_expr("f1", topic="*") == "hydro/f1/*/*"
    # zenoh accepts '..', '.' and spaces in a key; ids name the recorder's folders, so they are refused
    for bad in ("hydro/f1/sensors", "other/f1/m1/sensors", "hydro/f1/m1/temperature", "hydro/f1/../sensors",
                "hydro/../m1/sensors", "hydro/f1/./sensors", "hydro/f1/m 1/sensors", "hydro/f1/m@1/sensors"):
        with pytest.raises(DataError):
            parse_key(bad)
    assert parse_key("hydro/f1/m.1/sensors").machine == "m.1"
    for bad in ("m/1", "m*", "", "a b", ".", ".."):
        with pytest.raises(ParameterError):
            key("f1", bad, "sensors")


def test_shards_cover_every_machine_once_and_are_stable() -> None:
    machines = [f"m{i:04d}" for i in range(1000)]
    shards = [parse_shard(f"{i}/3") for i in range(3)]
    owners = [[s.includes(m) for s in shards].count(True) for m in machines]
    assert owners == [1] * 1000
    sizes = [sum(s.includes(m) for m in machines) for s in shards]
    assert all(280 < n < 390 for n in sizes), sizes
    assert machine_hash("m0000") == 0x8A5F5F8F  # CRC-32: the same on every host and Python
    assert Shard().includes("anything")
    for bad in ("2/2", "1", "a/b", "-1/2", "0/0"):
        with pytest.raises(ParameterError):
            parse_shard(bad)


def test_session_settings_peer_client_and_env() -> None:
    peer = BusSettings.from_env({}, port=9000).to_json()
    assert peer["mode"] == "peer" and peer["scouting"]["multicast"]["enabled"] is False
    assert peer["listen"]["endpoints"][:2] == ["tcp/127.0.0.1:9000", "tcp/127.0.0.1:0"]
    assert peer["connect"]["endpoints"] == ["tcp/127.0.0.1:9000"]
    env = {"HYDROWATCH_ZENOH_CONNECT": "tcp/10.0.0.5:7447, tcp/10.0.0.6:7447", "HYDROWATCH_ZENOH_PORT": "7500"}
    client = BusSettings.from_env(env)
    assert client.resolved_mode == "client" and client.port == 7500
    assert client.to_json()["connect"] == {"endpoints": ["tcp/10.0.0.5:7447", "tcp/10.0.0.6:7447"], "timeout_ms": -1}
    assert BusSettings.from_env(env, connect=["tcp/r:1"]).connect == ("tcp/r:1",)  # flags win
    json.loads(str(client.to_config()))  # zenoh accepts it
    with pytest.raises(ParameterError):
        BusSettings(mode="client")
    with pytest.raises(ParameterError):
        BusSettings.from_env({"HYDROWATCH_ZENOH_PORT": "x"})
    assert BusSettings(mode="router", port=7600).to_argv() == ["--bus-port", "7600", "--mode", "router"]
