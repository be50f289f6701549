"""Rig descriptions: the shipped UCI rig and the plant load; bad descriptions are refused by file and key."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest

from hydrowatch.channels import PLANT
from hydrowatch.errors import DataError, ParameterError
from hydrowatch.health.plan import DataPlan
from hydrowatch.plant.faults import EXTENDED_STATES
from hydrowatch.recording import SAMPLE_RATE_HZ
from hydrowatch.rig import BUILTIN, builtin_rig, data_root, load_rig, parse_rig
from hydrowatch.rig.plant import plant_rig

UCI_TOML = Path(__file__).resolve().parents[1] / "hydrowatch" / "rig" / "uci-hydraulic.toml"


def _uci() -> dict[str, Any]:
    with UCI_TOML.open("rb") as f:
        return tomllib.load(f)


def test_the_uci_rig_declares_its_17_channels_window_and_four_components() -> None:
    rig = builtin_rig("uci-hydraulic")
    assert len(rig.channels) == 17 and not rig.channels.has_command
    assert rig.channels["PS1"].unit == "bar" and rig.sampling["PS1"].source == "PS1_1hz_mean.txt"
    assert rig.channels.with_role("condition") == ("TS1", "TS2", "TS3", "TS4")
    assert (rig.window.kind, rig.window.length_s, rig.window.grid_hz, rig.window.samples) == ("cycle", 60.0, 1.0, 60)
    assert rig.components == ("cooler", "valve", "pump", "accumulator")
    accumulator = rig.label("accumulator")
    assert accumulator.values == (130.0, 115.0, 100.0, 90.0) and accumulator.healthy == 130.0
    assert accumulator.column == 3 and accumulator.names[90.0] == "close to total failure"
    assert rig.label("stable").component is False and rig.label_source == "profile.txt"
    assert rig.sampling["PS1"].original_hz == 100.0 and rig.sampling["FS1"].original_hz == 10.0
    assert rig.sampling["TS1"].recorded_hz is None and rig.sampling["TS1"].original_hz == 1.0
    assert rig.recorded_at_least(10.0) == ("PS1", "PS2", "PS3", "PS4", "PS5", "PS6", "EPS1", "FS1", "FS2")
    assert BUILTIN == ("uci-hydraulic",)


def test_the_plant_description_is_built_from_the_channel_registry() -> None:
    rig = plant_rig()
    assert rig.channels is PLANT and rig.channels.command == "voltage" and rig.layout == "long"
    assert all(s.rate_hz == SAMPLE_RATE_HZ and s.source == name for name, s in rig.sampling.items())
    assert rig.window.samples == DataPlan().window and rig.window.hop_s * SAMPLE_RATE_HZ == DataPlan().hop
    assert rig.label("state").values == EXTENDED_STATES and rig.label("state").healthy == "healthy"
    assert rig.components == ("state",)


def test_data_root_follows_the_environment_variable(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("HYDROWATCH_DATA", raising=False)
    assert data_root() == Path(__file__).resolve().parents[1].parent / "shared" / "data"
    monkeypatch.setenv("HYDROWATCH_DATA", str(tmp_path))
    assert data_root() == tmp_path


def _set(data: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    *path, last = key.split(".")
    table = data
    for part in path:
        table = table[part]
    if value is None:
        del table[last]
    else:
        table[last] = value
    return data


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("window.kind", "sliding", r"'window.kind' must be one of \['cycle', 'fixed'\]"),
        ("window.length_s", -60, "'window.length_s' must be a positive number"),
        ("window.grid_hz", None, "'window.grid_hz' must be given"),
        ("window.grid_hz", float("inf"), "'window.grid_hz' must be a positive number. Got inf"),
        ("channels.PS1.offset", float("nan"), "'channels.PS1.offset' must be a finite number. Got nan"),
        ("channels.PS1.scale", True, "'channels.PS1.scale' must be a finite number. Got True"),
        ("window.hop_s", 30.0, "'window.hop_s' must be the cycle length"),
        ("channels.PS1.rate_hz", 0.5, "'channels.PS1.rate_hz' must be a whole multiple of window.grid_hz"),
        ("channels.PS1.role", "label", "'channels.PS1.role' must be one of"),
        ("channels.PS1.unit", 3, "'channels.PS1.unit' must be a string"),
        ("channels.PS1.scale", 0, "'channels.PS1.scale' must be non-zero"),
        ("channels.PS1.recorded_hz", 0.5, "'channels.PS1.recorded_hz' must be at least rate_hz = 1.0"),
        ("channels.PS1.rate", 100, "'channels.PS1.rate' is not a known key"),
        ("labels.cooler.healthy", 50, r"'labels.cooler.healthy' must be one of the values \[3, 20, 100\]"),
        ("labels.cooler.values", [3, 3], "'labels.cooler.values' must be a non-empty list of distinct values"),
        ("labels.cooler.column", None, "'labels.cooler.column' must be a column index"),
        ("labels.valve.column", 0, "each label its own column"),
        ("labels.pump.names", {"7": "broken"}, "'labels.pump.names.7' must be a string naming one of the values"),
        ("layout.kind", "tall", "'layout.kind' must be one of"),
        ("channels", {}, "'channels' must declare at least one channel"),
        ("name", None, "'name' must be given"),
    ],
)
def test_a_bad_description_is_refused_naming_file_and_key(key: str, value: Any, match: str) -> None:
    with pytest.raises(DataError, match=match) as caught:
        parse_rig(_set(_uci(), key, value), "rigs/bad.toml")
    assert str(caught.value).startswith("rigs/bad.toml: ")


def test_channel_set_rules_reach_the_description_as_data_errors() -> None:
    data = _set(_uci(), "channels.PS1.role", "command")
    data = _set(data, "channels.PS2.role", "command")
    with pytest.raises(DataError, match="table 'channels': a channel set must have at most one command"):
        parse_rig(data, "x.toml")
    only_conditions = {name: {**table, "role": "condition"} for name, table in _uci()["channels"].items()}
    with pytest.raises(DataError, match="at least one sensor"):
        parse_rig(_set(_uci(), "channels", only_conditions), "x.toml")


def test_load_rig_refuses_a_missing_file_and_invalid_toml(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="must exist"):
        load_rig(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n", encoding="utf-8")
    with pytest.raises(DataError, match=r"bad.toml: rig description must be valid TOML"):
        load_rig(bad)
    with pytest.raises(ParameterError, match="rig must be one of"):
        builtin_rig("zema")


def test_a_fixed_window_rig_with_scaling_and_string_labels_loads(tmp_path: Path) -> None:
    path = tmp_path / "press.toml"
    path.write_text(
        'name = "press"\n[window]\nkind = "fixed"\nlength_s = 2.0\nhop_s = 1.0\ngrid_hz = 50.0\n'
        '[layout]\nkind = "long"\ntime_column = "time"\n'
        '[channels.u]\nunit = "V"\nrole = "command"\nrate_hz = 100.0\n'
        '[channels.p]\nunit = "bar"\nrole = "sensor"\nrate_hz = 50.0\nsource = "P_psi"\nscale = 0.0689476\n'
        '[labels.state]\nvalues = ["ok", "worn"]\nhealthy = "ok"\n',
        encoding="utf-8",
    )
    rig = load_rig(path)
    assert rig.channels.command == "u" and rig.window.samples == 100 and rig.window.hop_s == 1.0
    assert rig.sampling["p"].source == "P_psi" and rig.sampling["p"].scale == pytest.approx(0.0689476)
    assert rig.label("state").column is None and rig.time_column == "time" and rig.label_source is None
    with pytest.raises(ParameterError, match="label must be one of"):
        rig.label("cooler")
    path.write_text(path.read_text(encoding="utf-8").replace("hop_s = 1.0", "hop_s = 0.01"), encoding="utf-8")
    with pytest.raises(DataError, match=r"'window.grid_hz' must be such that hop_s \* grid_hz is a whole number"):
        load_rig(path)
