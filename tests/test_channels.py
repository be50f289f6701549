"""The channel registry: one declaration that the schema, the simulator and the io agree with."""

import numpy as np
import pytest

from hydrowatch import recording
from hydrowatch.channels import LABEL, PLANT, TIME, Channel, ChannelSet
from hydrowatch.condition import layout
from hydrowatch.errors import ParameterError
from hydrowatch.plant import PlantParameters, PlantSimulator, simulate
from hydrowatch.plant.effects import SENSOR_NAMES
from hydrowatch.plant.kernel import CHANNELS_OUT
from hydrowatch.plant.parameters import PARAMETER_INDEX
from hydrowatch.plant.population import NOISE_CHANNELS
from hydrowatch.plant.steady import steady_curve
from hydrowatch.schemas import SENSOR_CHUNK, may_be_absent, one_or_more_of, units


def test_sensor_chunk_schema_and_registry_agree_on_names_order_units_and_optionality() -> None:
    assert SENSOR_CHUNK.names == [TIME, *PLANT.names, LABEL]
    assert units(SENSOR_CHUNK) == PLANT.units
    for c in PLANT:
        assert may_be_absent(SENSOR_CHUNK.field(c.name)) == c.optional, c.name
        # a sensor may be left out but holds no nulls when present; a condition channel may hold nulls
        assert SENSOR_CHUNK.field(c.name).nullable == (c.role == "condition"), c.name
    assert one_or_more_of(SENSOR_CHUNK) == PLANT.sensors  # a chunk has at least one sensor, as a recording
    assert not SENSOR_CHUNK.field(TIME).nullable and SENSOR_CHUNK.field(LABEL).nullable


def test_a_recording_needs_the_command_and_one_sensor_whichever() -> None:
    assert PLANT.missing(["voltage", "torque"]) == [] and PLANT.missing(["voltage", "flow", "temperature"]) == []
    assert PLANT.missing(["voltage", "temperature"]) == ["one of flow, speed, torque"]
    assert PLANT.missing(["speed"]) == ["voltage"]


def test_plant_set_roles_and_the_recording_views() -> None:
    assert PLANT.command == recording.INPUT == "voltage"
    assert PLANT.sensors == recording.SENSORS == ("flow", "speed", "torque")
    assert PLANT.with_role("condition") == ("supply_pressure", "load_pressure", "temperature")
    assert recording.REQUIRED_CHANNELS == ("voltage",)  # and one sensor at least: PLANT.missing
    assert recording.OPTIONAL_CHANNELS == (*PLANT.sensors, *PLANT.with_role("condition"))
    assert recording.UNITS == {"t": "s", "voltage": "V", "flow": "L/min", "speed": "rad/s", "torque": "N·m",
                               "supply_pressure": "bar", "load_pressure": "bar", "temperature": "°C"}
    assert layout.CHANNELS == (PLANT.command, *PLANT.sensors) and layout.WIDTH == 4


def test_kernel_columns_follow_the_measured_channels() -> None:
    assert CHANNELS_OUT == len(PLANT.measured) == 6
    assert [PLANT.column(c) for c in PLANT.measured] == list(range(6))
    # the noise parameters and sensor_lowpass's sensor index address the first columns
    assert SENSOR_NAMES == PLANT.sensors
    assert NOISE_CHANNELS == ("noise_flow", "noise_speed", "noise_torque")
    assert [PARAMETER_INDEX[n] for n in NOISE_CHANNELS] == list(range(PARAMETER_INDEX["noise_flow"],
                                                                      PARAMETER_INDEX["noise_flow"] + 3))


def test_simulator_outputs_are_the_registry_channels_with_their_physical_values() -> None:
    out = PlantSimulator(PlantParameters(), noise=False).step(np.full(400, 3.0))
    assert set(out) == {TIME, *PLANT.names}
    rec = simulate(np.full(400, 3.0), noise=False, seed=0)
    assert tuple(rec.channels) == PLANT.names
    steady = steady_curve([3.0])
    # at rest under 3 V the kernel's columns read what the algebraic steady state says they should
    for name in ("flow", "speed", "torque", "supply_pressure", "load_pressure"):
        assert rec[name][-1] == pytest.approx(steady[name][0], rel=2e-3, abs=1e-3), name
    assert rec["temperature"][-1] == 40.0


def test_column_and_lookup_errors_name_the_channel() -> None:
    with pytest.raises(KeyError, match="'pressure'"):
        PLANT["pressure"]
    with pytest.raises(KeyError, match="measured"):
        PLANT.column("voltage")
    with pytest.raises(ParameterError, match="role"):
        PLANT.with_role("actuator")
    assert "flow" in PLANT and "t" not in PLANT and len(PLANT) == 7


@pytest.mark.parametrize(("channels", "match"), [
    ((Channel("u", "V", "command"), Channel("y", "m", "sensor"), Channel("y", "m", "sensor")), "unique"),
    ((Channel("u", "V", "command"), Channel("v", "V", "command"), Channel("y", "m", "sensor")), "at most one command"),
    ((Channel("u", "V", "command", optional=True), Channel("y", "m", "sensor")), "a required one"),
    ((Channel("u", "V", "command"), Channel("T", "°C", "condition")), "at least one sensor"),
])
def test_a_channel_set_refuses_an_inconsistent_declaration(channels: tuple[Channel, ...], match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        ChannelSet(channels)


def test_a_rig_declares_its_own_channels() -> None:
    rig = ChannelSet((Channel("current", "A", "command"), Channel("position", "mm", "sensor"),
                      Channel("temperature", "°C", "condition", optional=True)))
    assert rig.command == "current" and rig.sensors == ("position",) and rig.optional == ("temperature",)
    assert rig.units == {"t": "s", "current": "A", "position": "mm", "temperature": "°C"}
    for bad in ("", "a/b", "t", "state"):
        with pytest.raises(ParameterError, match="channel name"):
            Channel(bad, "V", "command")
    with pytest.raises(ParameterError, match="role"):
        Channel("x", "V", "input")


def test_a_rig_without_a_command_says_so_when_one_is_asked_for() -> None:
    rig = ChannelSet((Channel("PS1", "bar", "sensor"), Channel("TS1", "°C", "condition")))
    assert not rig.has_command and PLANT.has_command and rig.sensors == ("PS1",)
    with pytest.raises(ParameterError, match="command channel must be declared"):
        _ = rig.command
