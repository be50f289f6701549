"""Schemas and the Arrow message codec: round trip, and the three kinds of bad message."""

import json

import numpy as np
import pyarrow as pa
import pytest

from hydrowatch.errors import DataError
from hydrowatch.io.codec import (
    SchemaMismatchError,
    SchemaVersionError,
    UndecodableMessageError,
    arrays_from_sensor_chunk,
    decode_batch,
    encode_batch,
    sensor_chunk_from_arrays,
)
from hydrowatch.recording import UNITS
from hydrowatch.schemas import (
    HEALTH_VERDICT,
    KL_WINDOW,
    SCHEMA_VERSION,
    SENSOR_CHUNK,
    STATUS,
    current_version,
    describe,
    schema_by_name,
    schemas_dir,
    units,
    validate,
    wire_schema,
)


@pytest.fixture
def chunk():
    rng = np.random.default_rng(1)
    t = 12.0 + np.arange(100) / 200.0
    channels = {c: rng.normal(size=100) for c in ("voltage", "flow", "speed", "torque", "temperature")}
    return t, channels


def test_schemas_carry_name_version_units_and_descriptions():
    for schema, name in (
        (SENSOR_CHUNK, "sensor_chunk"),
        (KL_WINDOW, "kl_window"),
        (HEALTH_VERDICT, "health_verdict"),
        (STATUS, "status"),
    ):
        assert schema.metadata[b"hydrowatch.schema"] == name.encode()
        assert schema.metadata[b"hydrowatch.schema_version"] == str(current_version(name)).encode()
        assert all(f.metadata[b"description"] for f in schema)
        assert schema_by_name(name) is schema
    assert units(SENSOR_CHUNK) == UNITS  # the contract's units, one source of truth
    assert units(KL_WINDOW)["relative_entropy"] == "nats"
    assert HEALTH_VERDICT.field("probabilities").type == pa.list_(
        pa.struct(
            [pa.field("state", pa.string(), nullable=False), pa.field("probability", pa.float64(), nullable=False)]
        )
    )
    assert "flow double [L/min]" in describe(SENSOR_CHUNK)


def test_schema_files_are_plain_json_with_every_field_documented():
    files = sorted(p.name for p in schemas_dir().glob("*.json"))
    assert files == ["cycle_verdict.v1.json", "cycle_verdict.v2.json", "expected_window.v1.json", "forecast.v1.json",
                     "forecast.v2.json", "health_verdict.v1.json", "health_verdict.v2.json", "kl_window.v1.json",
                     "rig_cycles.v1.json", "sensor_chunk.v1.json", "sensor_chunk.v2.json", "status.v1.json"]
    assert [current_version(n) for n in ("sensor_chunk", "kl_window", "health_verdict", "status", "forecast",
                                         "expected_window", "rig_cycles", "cycle_verdict")] == [2, 1, 2, 1, 2, 1, 1, 2]
    assert SCHEMA_VERSION == current_version("sensor_chunk")  # what recording metadata says it holds
    readme = (schemas_dir() / "README.md").read_text()
    for name in files:
        spec = json.loads((schemas_dir() / name).read_text())
        for field in spec["fields"]:
            assert f"`{field['name']}`" in readme, (name, field["name"])


def test_unknown_schema_is_a_clear_error():
    with pytest.raises(DataError, match=r"Got sensor_chunk.v9"):
        schema_by_name("sensor_chunk", 9)


def test_sensor_chunk_round_trip_keeps_values_units_and_version(chunk):
    t, channels = chunk
    batch = sensor_chunk_from_arrays(t, channels)
    data = encode_batch(batch)
    back = decode_batch(data, SENSOR_CHUNK, "test")
    assert back.equals(batch)
    assert back.schema.field("torque").metadata[b"unit"] == "N·m".encode()
    assert back.schema.metadata[b"hydrowatch.schema_version"] == b"2"
    t2, ch2 = arrays_from_sensor_chunk(back)
    np.testing.assert_array_equal(t2, t)
    assert sorted(ch2) == sorted(channels)
    np.testing.assert_array_equal(ch2["flow"], channels["flow"])
    # descriptions stay out of messages: 100 samples x 6 columns fit in under 6 kB
    assert len(data) < 6000


def test_labels_travel_as_strings(chunk):
    t, channels = chunk
    labels = np.array(["healthy"] * 50 + ["load_alert"] * 50, dtype=object)
    batch = sensor_chunk_from_arrays(t, {**channels, "state": labels})
    _, back = arrays_from_sensor_chunk(decode_batch(encode_batch(batch), SENSOR_CHUNK))
    assert list(back["state"][48:52]) == ["healthy", "healthy", "load_alert", "load_alert"]


def test_missing_required_channel_and_unknown_channel_are_rejected(chunk):
    t, channels = chunk
    del channels["voltage"]
    with pytest.raises(DataError, match="'voltage' must be given"):
        sensor_chunk_from_arrays(t, channels)
    with pytest.raises(DataError, match=r"unknown \['pressure'\]"):
        sensor_chunk_from_arrays(t, {**chunk[1], "pressure": t})
    with pytest.raises(DataError, match=r"at least one of the sensors \['flow', 'speed', 'torque'\]"):
        sensor_chunk_from_arrays(t, {"voltage": t, "temperature": t})


@pytest.mark.parametrize("sensors", [("flow",), ("speed",), ("torque",), ("flow", "torque"), ("speed", "torque")])
def test_a_chunk_of_any_sensor_subset_round_trips_and_one_of_none_is_refused(chunk, sensors):
    t, channels = chunk
    kept = {c: v for c, v in channels.items() if c in ("voltage", *sensors, "temperature")}
    back = decode_batch(encode_batch(sensor_chunk_from_arrays(t, kept)), SENSOR_CHUNK, "k")
    assert back.schema.names == ["t", "voltage", *sensors, "temperature"]
    np.testing.assert_array_equal(arrays_from_sensor_chunk(back)[1][sensors[0]], channels[sensors[0]])
    # a sensor, when present, holds no nulls (optional, not nullable)
    cols = [pa.array([None] * 100, pa.float64()) if n == sensors[0] else c for n, c in zip(back.schema.names,
                                                                                         back.columns)]
    with pytest.raises(DataError, match=f"field '{sensors[0]}' must have no nulls. Got 100."):
        decode_batch(encode_batch(pa.RecordBatch.from_arrays(cols, schema=back.schema)), SENSOR_CHUNK, "k")
    # no sensor at all: the schema's one_or_more_of rule, whatever wrote the message
    wire = wire_schema(SENSOR_CHUNK)
    bare_schema = pa.schema([wire.field("t"), wire.field("voltage")], metadata=wire.metadata)
    bare = pa.RecordBatch.from_arrays([pa.array(t), pa.array(channels["voltage"])], schema=bare_schema)
    with pytest.raises(DataError, match=r"k: sensor_chunk must have at least one of the fields \['flow', 'speed'"):
        decode_batch(encode_batch(bare), SENSOR_CHUNK, "k")


def test_a_sensor_chunk_v1_is_still_read_and_must_have_every_sensor(chunk):
    t, channels = chunk
    v1 = wire_schema(schema_by_name("sensor_chunk", 1))  # what a hydrowatch of before 2026-11-26 sends
    batch = sensor_chunk_from_arrays(t, channels)
    old = pa.RecordBatch.from_arrays(batch.columns, schema=pa.schema([v1.field(n) for n in batch.schema.names],
                                                                     metadata=v1.metadata))
    back = decode_batch(encode_batch(old), SENSOR_CHUNK, "k")
    assert back.schema.metadata[b"hydrowatch.schema_version"] == b"1"
    np.testing.assert_array_equal(arrays_from_sensor_chunk(back)[1]["torque"], channels["torque"])
    lacking = pa.RecordBatch.from_arrays(old.columns[:4], schema=pa.schema(list(old.schema)[:4], metadata=v1.metadata))
    with pytest.raises(DataError, match="sensor_chunk field 'torque' must be present"):
        decode_batch(encode_batch(lacking), SENSOR_CHUNK, "k")


def test_garbage_other_schema_and_other_version_are_three_distinct_errors(chunk):
    data = encode_batch(sensor_chunk_from_arrays(*chunk))
    with pytest.raises(UndecodableMessageError, match="key/x: message must be an Arrow IPC stream"):
        decode_batch(b"\x00garbage" * 10, SENSOR_CHUNK, "key/x")
    with pytest.raises(UndecodableMessageError):
        decode_batch(data[: len(data) // 2], SENSOR_CHUNK, "key/x")  # truncated payload
    with pytest.raises(SchemaMismatchError, match="must be 'kl_window'. Got 'sensor_chunk'"):
        decode_batch(data, KL_WINDOW, "key/x")
    foreign = encode_batch(pa.record_batch([pa.array([1.0])], names=["t"]))
    with pytest.raises(SchemaMismatchError, match="must carry schema metadata"):
        decode_batch(foreign, SENSOR_CHUNK, "key/x")
    batch = sensor_chunk_from_arrays(*chunk)
    v2 = batch.replace_schema_metadata({**batch.schema.metadata, b"hydrowatch.schema_version": b"3"})
    with pytest.raises(SchemaVersionError, match="sensor_chunk schema version must be 2 or an older declared one"):
        decode_batch(encode_batch(v2), SENSOR_CHUNK, "key/x")
    assert not issubclass(SchemaVersionError, SchemaMismatchError)


def test_a_health_verdict_of_an_older_version_is_read_and_a_newer_one_refused():
    from hydrowatch.report.fleet_table import verdict_rows
    from hydrowatch.training.chunks import WindowVerdict
    from hydrowatch.training.messages import verdict_batch
    from hydrowatch.verdict import Verdict

    verdict = Verdict("pump_leak_warning", 0.9, {"healthy": 0.1, "pump_leak_warning": 0.9})
    index = {"pump_leak": {"value": 0.41, "ci95": [0.38, 0.44]}}
    v2 = verdict_batch(WindowVerdict("m", 0.0, 5.0, verdict, None, index), "sha256:x")
    row = verdict_rows(decode_batch(encode_batch(v2), HEALTH_VERDICT, "key/h"))[0]
    assert row["degradation"] == index and row["state"] == "pump_leak_warning"
    v1_schema = wire_schema(schema_by_name("health_verdict", 1))  # what a hydrowatch of before 2026-11-25 sends
    v1 = pa.RecordBatch.from_pylist([{k: v for k, v in v2.to_pylist()[0].items() if k != "degradation"}],
                                    schema=v1_schema)
    old = verdict_rows(decode_batch(encode_batch(v1), HEALTH_VERDICT, "key/h"))[0]
    assert old["degradation"] is None and old["probabilities"] == {"healthy": 0.1, "pump_leak_warning": 0.9}
    newer = v2.replace_schema_metadata({**v2.schema.metadata, b"hydrowatch.schema_version": b"3"})
    with pytest.raises(SchemaVersionError, match="health_verdict schema version must be 2 or an older"):
        decode_batch(encode_batch(newer), HEALTH_VERDICT, "key/h")
    with_field = v1.replace_schema_metadata(v1.schema.metadata)
    extra = pa.RecordBatch.from_arrays([*with_field.columns, pa.array([1.0])],
                                       schema=with_field.schema.append(pa.field("degradation", pa.float64())))
    with pytest.raises(DataError, match="fields must be among"):  # v1 does not declare it
        decode_batch(encode_batch(extra), HEALTH_VERDICT, "key/h")


def test_a_forecast_names_the_part_it_may_be_and_an_older_version_is_read():
    from hydrowatch.condition.forecast import Forecast
    from hydrowatch.report.fleet_table import forecast_parts, wear_parts, wear_text
    from hydrowatch.schemas import FORECAST
    from hydrowatch.training.forecasts import MachineForecast
    from hydrowatch.training.messages import forecast_batch

    parts = {"relief_spring": Forecast(600.0, (480.0, 720.0), 1.2, "linear", 0.5, 80, None, None, "valve_coil"),
             "load": Forecast(None, (None, None), 0.0, "linear", 0.01, 80, None, "too flat: no rise")}
    v2 = forecast_batch(MachineForecast("f/m", 100.0, parts, 80), "sha256:x")
    start, got = forecast_parts(decode_batch(encode_batch(v2), FORECAST, "f/m/forecast"))
    assert start == 100.0 and got["relief_spring"]["untold_from"] == "valve_coil" and "untold_from" not in got["load"]
    text = wear_text("relief_spring", wear_parts(None, got)["relief_spring"])
    assert text.endswith("alert in 10 min (95 %: 8 min–12 min) (or valve_coil: not yet told apart)")
    v1_schema = wire_schema(schema_by_name("forecast", 1))  # what a hydrowatch of before 2026-12-03 sends
    v1 = pa.RecordBatch.from_pylist([{k: v for k, v in r.items() if k != "untold_from"} for r in v2.to_pylist()],
                                    schema=v1_schema)
    _, old = forecast_parts(decode_batch(encode_batch(v1), FORECAST, "f/m/forecast"))
    assert old["relief_spring"]["alert_in_s"] == 600.0 and "untold_from" not in old["relief_spring"]


def test_malformed_payload_names_the_field(chunk):
    t, channels = chunk
    batch = sensor_chunk_from_arrays(t, channels)
    # right schema name and version, but 'flow' sent as strings
    cols = [
        pa.array(channels["flow"].astype(str)) if n == "flow" else c for n, c in zip(batch.schema.names, batch.columns)
    ]
    fields = [pa.field("flow", pa.string()) if f.name == "flow" else f for f in batch.schema]
    bad = pa.RecordBatch.from_arrays(cols, schema=pa.schema(fields, metadata=batch.schema.metadata))
    with pytest.raises(DataError, match="field 'flow' must have type double. Got string"):
        decode_batch(encode_batch(bad), SENSOR_CHUNK, "key/x")
    # nulls in a required field: Arrow does not enforce non-null, validate does
    nullable = pa.schema([f.with_nullable(True) for f in batch.schema], metadata=batch.schema.metadata)
    cols = [
        pa.array([None] * 100, pa.float64()) if n == "speed" else c for n, c in zip(batch.schema.names, batch.columns)
    ]
    with pytest.raises(DataError, match="field 'speed' must have no nulls. Got 100"):
        decode_batch(encode_batch(pa.RecordBatch.from_arrays(cols, schema=nullable)), SENSOR_CHUNK)


def test_other_messages_validate_and_round_trip():
    verdict = pa.RecordBatch.from_pylist(
        [
            {
                "window_start": 10.0,
                "window_end": 20.0,
                "state": "pump_leak_alert",
                "probability": 0.9,
                "probabilities": [
                    {"state": "healthy", "probability": 0.1},
                    {"state": "pump_leak_alert", "probability": 0.9},
                ],
                "reason": None,
                "model_version": "3",
            }
        ],
        schema=wire_schema(HEALTH_VERDICT),
    )
    back = decode_batch(encode_batch(verdict), HEALTH_VERDICT)
    assert back.to_pylist()[0]["probabilities"][1]["probability"] == 0.9
    status = pa.RecordBatch.from_pylist(
        [
            {
                "service": "scorer",
                "machine": None,
                "time": 1.7e9,
                "status": "running",
                "messages_in": 5,
                "messages_out": 4,
                "messages_dropped": 0,
                "messages_undecodable": 1,
            }
        ],
        schema=STATUS,
    )
    validate(status, STATUS)
    kl = pa.RecordBatch.from_pylist(
        [
            {
                "window_start": 0.0,
                "window_end": 10.0,
                "sensor": "flow",
                "state": "healthy",
                "relative_entropy": 0.02,
                "model_version": "3",
            }
        ],
        schema=KL_WINDOW,
    )
    with pytest.raises(DataError, match="must be 'status'"):
        validate(kl, STATUS)


def test_a_forecast_message_round_trips_with_nulls_where_there_is_no_forecast():
    from hydrowatch.condition.forecast import forecast_alert
    from hydrowatch.report.fleet_table import forecast_parts
    from hydrowatch.schemas import FORECAST
    from hydrowatch.training.forecasts import MachineForecast
    from hydrowatch.training.messages import forecast_batch

    t = np.arange(0.0, 1800.0, 5.0)
    wearing = forecast_alert(t, 0.6 * t / t[-1] + 0.01 * np.sin(t))  # 0.6 after 30 min: the alert ~20 min later
    parts = {"load": wearing, "motor_leak": forecast_alert(t[:4], np.zeros(4))}
    batch = forecast_batch(MachineForecast("f/m", float(t[-1]), parts, t.size), "sha256:x")
    validate(batch, FORECAST, require_metadata=True)
    start, back = forecast_parts(decode_batch(encode_batch(batch), FORECAST))
    assert start == t[-1] and back == {fault: f.to_dict() for fault, f in parts.items()}
    assert back["load"]["alert_in_s"] == pytest.approx(1200.0, rel=0.05) and back["load"]["model"] == "linear"
    assert back["motor_leak"]["alert_in_s"] is None and back["motor_leak"]["rate_per_h"] is None
    assert back["motor_leak"]["reason"].startswith("too short")
    assert batch.column("history_windows").to_pylist() == [t.size, t.size]
