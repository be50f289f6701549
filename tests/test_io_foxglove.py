"""``hydrowatch export --foxglove``: the same samples, verdicts, relative entropies, forecasts, expected sensors and
cycle verdicts as JSON with JSON Schema, read back with the mcap library as Foxglove would read them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from mcap.reader import make_reader

from hydrowatch.cli import main
from hydrowatch.io import McapWriter
from hydrowatch.io.codec import sensor_chunk_from_arrays
from hydrowatch.io.foxglove import FoxgloveWriter, export_foxglove
from hydrowatch.schemas import (
    CYCLE_VERDICT,
    EXPECTED_WINDOW,
    FORECAST,
    HEALTH_VERDICT,
    KL_WINDOW,
    RIG_CYCLES,
    STATUS,
    wire_schema,
)

KEY = "hydro/f1/m1"
RECEIVED_NS = 1_764_000_000_000_000_000
"""A recorder's log time (receive time, Unix ns): the export moves it to publish time."""
STATES = ["healthy", "load_alert"]


def _chunk(i: int, n: int = 100) -> pa.RecordBatch:
    t = i * n / 200.0 + np.arange(n) / 200.0
    rng = np.random.default_rng(i)
    columns = {c: rng.normal(size=n) for c in ("voltage", "flow", "speed", "torque")}
    if i == 3:
        columns["flow"][5] = np.nan  # a lost sample: left out of its JSON message, not written as NaN
    return sensor_chunk_from_arrays(t, columns)


def _verdict(start: float, state: str, p: float) -> pa.RecordBatch:
    row = {"window_start": [start], "window_end": [start + 2.0], "state": [state], "probability": [p],
           "probabilities": [[{"state": s, "probability": p if s == state else 1 - p} for s in STATES]],
           "reason": [None], "model_version": ["sha256:abc"],
           "degradation": [None if state == "healthy" else [{"fault": "load", "index": 0.5, "low": 0.45,
                                                              "high": 0.55}]]}
    return pa.RecordBatch.from_pydict(row, schema=wire_schema(HEALTH_VERDICT))


def _kl(start: float) -> pa.RecordBatch:
    sensors = ["flow", "speed", "torque"]
    row = {"window_start": [start] * 6, "window_end": [start + 2.0] * 6,
           "sensor": [s for s in sensors for _ in STATES], "state": [k for _ in sensors for k in STATES],
           "relative_entropy": [start + 0.1 * j for j in range(6)], "model_version": ["sha256:abc"] * 6}
    return pa.RecordBatch.from_pydict(row, schema=wire_schema(KL_WINDOW))


def _forecast(start: float, alert_in_s: float) -> pa.RecordBatch:
    """A scorer's forecast after the window at ``start``: load wearing, valve_coil too flat (its nulls)."""
    rows = [{"window_start": start, "fault": "load", "alert_in_s": alert_in_s, "low_s": 0.8 * alert_in_s,
             "high_s": 1.3 * alert_in_s, "rate_per_h": 0.61, "level": 0.52, "model": "exp", "points": 340,
             "reset_at": None, "reason": None, "history_windows": 352, "model_version": "sha256:abc"},
            {"window_start": start, "fault": "valve_coil", "alert_in_s": None, "low_s": None, "high_s": None,
             "rate_per_h": 0.003, "level": 0.01, "model": "linear", "points": 340, "reset_at": None,
             "reason": "too flat: the index rose 0.001 < 0.1 over the history", "history_windows": 352,
             "model_version": "sha256:abc"}]
    return pa.RecordBatch.from_pylist(rows, schema=wire_schema(FORECAST))


def _expected(start: float) -> pa.RecordBatch:
    """A scorer's expected sensors of the 2 s window at ``start``: flow and torque, 20 points of 0.1 s each; the
    torque's point 4 of the first window is NaN (a chart leaves it out)."""
    points = np.arange(20, dtype=np.float32)
    torque = 10.0 + points
    if start == 0.0:
        torque[4] = np.nan
    rows = [{"window_start": start, "window_end": start + 2.0, "sensor": "flow", "unit": "L/min", "step": 0.1,
             "measured": (start + 0.5 * points).tolist(), "expected": (start + 0.25 * points).tolist(),
             "source": "valve relation", "model_version": "sha256:abc"},
            {"window_start": start, "window_end": start + 2.0, "sensor": "torque", "unit": "N·m", "step": 0.1,
             "measured": torque.tolist(), "expected": (torque - 1.0).tolist(), "source": "load relation",
             "model_version": "sha256:abc"}]
    return pa.RecordBatch.from_pylist(rows, schema=wire_schema(EXPECTED_WINDOW))


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    """A recorder-like file: 10 sensor chunks (1000 samples), 2 verdicts, 2 kl windows, 2 forecasts, 2 windows of
    expected sensors (40 points), 1 heartbeat."""
    path = tmp_path / "m1.mcap"
    status = pa.RecordBatch.from_pylist([{"service": "plant", "machine": "m1", "time": 1.7e9, "status": "running",
                                          "messages_in": 0, "messages_out": 3, "messages_dropped": 0,
                                          "messages_undecodable": 0}], schema=wire_schema(STATUS))
    with McapWriter(path, chunk_size=4096, metadata={"fleet": "f1", "machine": "m1", "state": None}) as writer:
        for i in range(10):
            writer.write(f"{KEY}/sensors", _chunk(i), RECEIVED_NS + i * 500_000_000)
        for j, (state, p) in enumerate((("healthy", 0.9), ("load_alert", 0.75))):
            writer.write(f"{KEY}/kl", _kl(2.0 * j), RECEIVED_NS + 10**9 * (j + 2))
            writer.write(f"{KEY}/health", _verdict(2.0 * j, state, p), RECEIVED_NS + 10**9 * (j + 2))
            writer.write(f"{KEY}/forecast", _forecast(2.0 * j, 1820.0 - 2.0 * j), RECEIVED_NS + 10**9 * (j + 2))
            writer.write(f"{KEY}/expected", _expected(2.0 * j), RECEIVED_NS + 10**9 * (j + 2))
        writer.write(f"{KEY}/status", status, RECEIVED_NS)
        writer.add_metadata("rig", {"name": "test bench"})
    return path


def _read(path: Path) -> tuple[dict, dict]:
    """Foxglove topic → [(log ns, publish ns, message)], and the file's metadata records; every message is
    checked against its channel's JSON Schema (properties, required, types)."""
    types = {"number": (int, float), "string": str, "object": dict}

    def conforms(body: dict, spec: dict) -> bool:  # a map of objects (forecast parts, degradation) value by value
        for k, v in body.items():
            inner = spec["properties"][k]
            if not isinstance(v, types[inner["type"]]):
                return False
            each = inner.get("additionalProperties")
            if isinstance(each, dict) and "properties" in each and not all(
                    conforms(sub, inner.get("properties", {}).get(name, each)) for name, sub in v.items()):
                return False
        return True

    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert (schema.encoding, channel.message_encoding) == ("jsonschema", "json")
            spec = json.loads(schema.data)
            body = json.loads(message.data)
            assert set(spec["required"]) <= set(body) <= set(spec["properties"]), (channel.topic, body)
            assert conforms(body, spec), (channel.topic, body)
            out.setdefault(channel.topic, []).append((message.log_time, message.publish_time, body))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return out, metadata


def test_export_foxglove_writes_json_that_reads_back_with_the_same_values(
        recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "m1.foxglove.mcap"
    assert main(["export", str(recording), "--foxglove", "--out", str(out)]) == 0
    line = capsys.readouterr().out
    assert "1000 samples, 2 verdicts, 2 relative-entropy windows, 2 forecasts, 40 expected points on 5 channels" in line
    assert "left out 1 messages Foxglove is not given (status)" in line
    got, metadata = _read(out)
    assert {t: len(m) for t, m in got.items()} == {f"/{KEY}/sensors": 1000, f"/{KEY}/health": 2, f"/{KEY}/kl": 2,
                                                   f"/{KEY}/forecast": 2, f"/{KEY}/expected": 40}
    assert metadata["hydrowatch"]["fleet"] == "f1" and metadata["rig"] == {"name": "test bench"}

    samples = got[f"/{KEY}/sensors"]
    source = _chunk(7)
    log_ns, publish_ns, sample = samples[742]  # chunk 7, row 42: log time = sample time, publish = receive time
    assert sample["t"] == pytest.approx(3.71) and log_ns == 3_710_000_000
    assert publish_ns == RECEIVED_NS + 7 * 500_000_000
    assert sample["flow"] == source.column("flow")[42].as_py()
    assert sample["torque"] == source.column("torque")[42].as_py()
    assert "flow" not in samples[305][2] and samples[305][2]["speed"] == _chunk(3).column("speed")[5].as_py()

    (log0, _, first), (log1, _, second) = got[f"/{KEY}/health"]
    assert (log0, log1) == (2_000_000_000, 4_000_000_000)  # window end, on the samples' time base
    assert second["state"] == "load_alert" and second["probability"] == 0.75
    assert second["probabilities"] == {"healthy": 0.25, "load_alert": 0.75} and "reason" not in second
    assert (second["window_start"], second["window_end"], second["model_version"]) == (2.0, 4.0, "sha256:abc")
    kl = got[f"/{KEY}/kl"][1][2]
    assert kl["relative_entropy"]["speed"] == {"healthy": pytest.approx(2.2), "load_alert": pytest.approx(2.3)}
    assert set(kl["relative_entropy"]) == {"flow", "speed", "torque"}

    (log0, publish0, _), (log1, _, forecast) = got[f"/{KEY}/forecast"]
    assert (log0, log1, publish0) == (0, 2_000_000_000, RECEIVED_NS + 2 * 10**9)  # window_start: what it counts from
    assert (forecast["window_start"], forecast["history_windows"]) == (2.0, 352)
    assert forecast["model_version"] == "sha256:abc"
    assert forecast["parts"]["load"] == {"alert_in_s": 1818.0, "low_s": pytest.approx(1454.4),
                                         "high_s": pytest.approx(2363.4), "rate_per_h": 0.61, "level": 0.52,
                                         "model": "exp", "points": 340}  # null reset_at and reason left out
    coil = forecast["parts"]["valve_coil"]
    assert "alert_in_s" not in coil and "low_s" not in coil and coil["reason"].startswith("too flat")

    points = got[f"/{KEY}/expected"]  # one message per 0.1 s point, at its middle, every sensor of the window
    assert [log for log, _, _ in points] == [50_000_000 + 100_000_000 * i for i in range(40)]
    log_ns, publish_ns, point = points[27]  # window 2-4 s, point 7
    assert (log_ns, publish_ns) == (2_750_000_000, RECEIVED_NS + 3 * 10**9)
    assert point["t"] == pytest.approx(2.75) and (point["window_start"], point["window_end"]) == (2.0, 4.0)
    assert point["step"] == pytest.approx(0.1) and point["model_version"] == "sha256:abc"
    assert point["sensors"] == {
        "flow": {"measured": pytest.approx(5.5), "expected": pytest.approx(3.75), "source": "valve relation",
                 "unit": "L/min"},
        "torque": {"measured": 17.0, "expected": 16.0, "source": "load relation", "unit": "N·m"}}
    assert points[4][2]["sensors"]["torque"] == {"source": "load relation", "unit": "N·m"}  # NaN left out
    assert points[4][2]["sensors"]["flow"]["measured"] == pytest.approx(2.0)


def test_schemas_name_units_and_list_the_states_for_path_completion(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "fox.mcap"
    assert main(["export", str(recording), "--foxglove", "--out", str(out)]) == 0
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    schemas = {s.name: json.loads(s.data) for s in summary.schemas.values()}
    sensors = schemas["hydrowatch.sensor_sample"]["properties"]
    assert sensors["flow"]["description"].endswith("[L/min]") and sensors["speed"]["type"] == "number"
    assert set(schemas["hydrowatch.health_verdict"]["properties"]["probabilities"]["properties"]) == set(STATES)
    assert set(schemas["hydrowatch.kl_window"]["properties"]["relative_entropy"]["properties"]["torque"][
        "properties"]) == set(STATES)
    assert {c.topic: c.metadata["hydrowatch.key"] for c in summary.channels.values()}[f"/{KEY}/health"] == (
        f"{KEY}/health")
    parts = schemas["hydrowatch.forecast"]["properties"]["parts"]
    assert set(parts["properties"]) == {"load", "valve_coil"} and "parts" in schemas["hydrowatch.forecast"]["required"]
    part = parts["additionalProperties"]["properties"]
    assert part["alert_in_s"]["description"].endswith("[s]") and part["rate_per_h"]["description"].endswith("[1/h]")
    assert (part["model"]["type"], part["points"]["type"]) == ("string", "number")
    expected = schemas["hydrowatch.expected_point"]
    assert set(expected["properties"]["sensors"]["properties"]) == {"flow", "torque"}
    assert {"t", "sensors", "window_start", "model_version"} <= set(expected["required"])
    point = expected["properties"]["sensors"]["additionalProperties"]["properties"]
    assert (point["measured"]["type"], point["expected"]["type"], point["source"]["type"]) == (
        "number", "number", "string")
    assert expected["properties"]["t"]["description"].endswith("[s]")


def test_export_foxglove_refuses_what_is_not_a_hydrowatch_recording(
        recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = tmp_path / "notes.mcap"
    text.write_text("not an mcap file\n")
    assert main(["export", str(text), "--foxglove", "--out", str(tmp_path / "a.mcap")]) == 2
    assert "notes.mcap: file must be an MCAP file" in capsys.readouterr().err
    fox = tmp_path / "fox.mcap"
    assert main(["export", str(recording), "--foxglove", "--out", str(fox)]) == 0
    capsys.readouterr()
    again = tmp_path / "again.mcap"
    assert main(["export", str(fox), "--foxglove", "--out", str(again)]) == 2
    err = capsys.readouterr().err
    assert "must be a hydrowatch MCAP recording" in err and "/hydro/f1/m1/sensors (json)" in err
    assert "Foxglove export already" in err and not again.exists() and not list(tmp_path.glob("*.part"))
    assert main(["export", str(recording), "--foxglove", "--out", str(tmp_path / "x.parquet")]) == 2
    assert "--out must end in .mcap with --foxglove" in capsys.readouterr().err


def test_a_negative_sample_time_cannot_be_a_log_time(tmp_path: Path) -> None:
    chunk = sensor_chunk_from_arrays(np.array([-0.01, -0.005]), {c: np.zeros(2) for c in
                                                                 ("voltage", "flow", "speed", "torque")})
    with FoxgloveWriter(tmp_path / "neg.mcap") as writer, pytest.raises(ValueError, match="t must be a finite time"):
        writer.write_message(f"{KEY}/sensors", chunk)


def test_recorder_option_writes_the_same_json_as_the_export(tmp_path: Path) -> None:
    """``hydrowatch record --foxglove``: the files the recorder writes hold what ``export --foxglove`` writes."""
    from hydrowatch.bus.keys import parse_key
    from hydrowatch.bus.pubsub import Message
    from hydrowatch.io import encode_batch
    from services.recorder.files import RecordingFiles

    sent = [(f"{KEY}/sensors", _chunk(i)) for i in range(4)] + [(f"{KEY}/health", _verdict(0.0, "healthy", 0.9)),
                                                                 (f"{KEY}/kl", _kl(0.0)),
                                                                 (f"{KEY}/forecast", _forecast(0.0, 600.0))]
    files = RecordingFiles(tmp_path / "rec", flush_s=0.01, foxglove=True)
    files.write_many([Message(parse_key(k), b, encode_batch(b), RECEIVED_NS + i, 0) for i, (k, b) in enumerate(sent)])
    files.close()
    (path,) = (tmp_path / "rec" / "f1" / "m1").glob("*.foxglove.mcap")
    got, metadata = _read(path)
    assert {t: len(m) for t, m in got.items()} == {f"/{KEY}/sensors": 400, f"/{KEY}/health": 1, f"/{KEY}/kl": 1,
                                                   f"/{KEY}/forecast": 1}
    assert got[f"/{KEY}/forecast"][0][2]["parts"]["load"]["alert_in_s"] == 600.0
    assert metadata["hydrowatch"]["machine"] == "m1" and files.messages == len(sent)
    log_ns, publish_ns, sample = got[f"/{KEY}/sensors"][250]
    assert (log_ns, publish_ns) == (1_250_000_000, RECEIVED_NS + 2)
    assert sample["speed"] == _chunk(2).column("speed")[50].as_py()


def test_an_unfinished_recording_needs_recover(recording: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.mcap"
    data = recording.read_bytes()
    cut.write_bytes(data[: len(data) // 2])  # the recorder was killed: no summary, a half-written chunk
    out = tmp_path / "cut.foxglove.mcap"
    assert main(["export", str(cut), "--foxglove", "--out", str(out)]) == 2
    assert "must be a finished MCAP" in capsys.readouterr().err and not out.exists()
    assert main(["export", str(cut), "--foxglove", "--out", str(out), "--recover"]) == 0
    assert "unfinished file" in capsys.readouterr().out
    got, metadata = _read(out)
    assert 0 < len(got[f"/{KEY}/sensors"]) < 1000 and len(got[f"/{KEY}/sensors"]) % 100 == 0
    assert metadata["hydrowatch"]["machine"] == "m1"


def test_non_finite_scores_are_left_out_because_json_has_no_nan() -> None:
    from hydrowatch.io.foxglove import kl_windows

    batch = _kl(4.0)
    values = batch.column("relative_entropy").to_pylist()
    values[3] = float("inf")  # speed × load_alert
    batch = batch.set_column(4, "relative_entropy", pa.array(values))
    ((log_ns, window),) = list(kl_windows(batch, "test"))
    assert log_ns == 6_000_000_000 and window["relative_entropy"]["speed"] == {"healthy": pytest.approx(4.2)}
    json.dumps(window, allow_nan=False)


def test_recorder_option_leaves_out_a_chunk_whose_times_json_cannot_carry(tmp_path: Path) -> None:
    # a publisher sent a chunk with NaN sample times: the Foxglove recording leaves it out, counted, and goes on
    from hydrowatch.bus.keys import parse_key
    from hydrowatch.bus.pubsub import Message
    from hydrowatch.io import encode_batch
    from services.recorder.files import RecordingFiles

    good, bad = _chunk(0), _chunk(1)
    bad = bad.set_column(bad.schema.get_field_index("t"), bad.schema.field("t"),
                         pa.array([float("nan")] * bad.num_rows))
    files = RecordingFiles(tmp_path / "rec", flush_s=0.01, foxglove=True)
    files.write_many([Message(parse_key(f"{KEY}/sensors"), b, encode_batch(b), RECEIVED_NS + i, 0)
                      for i, b in enumerate((good, bad, _chunk(2)))])
    files.close()
    (path,) = (tmp_path / "rec" / "f1" / "m1").glob("*.foxglove.mcap")
    got, _ = _read(path)
    assert len(got[f"/{KEY}/sensors"]) == 200 and files.unwritable == {f"{KEY}/sensors": 1}


COMPONENTS = {"cooler": ("3", "20", "100"), "valve": ("73", "80", "90", "100")}


def _cycle_verdicts(first: int, n: int) -> pa.RecordBatch:
    """A scorer's verdicts on cycles ``first`` … ``first + n - 1`` of 60 s: cooler at 100 %, the valve unknown
    from cycle 2 on (novelty 1.8, NaN on cycle 1: left out)."""
    rows = []
    for cycle in range(first, first + n):
        for component, states in COMPONENTS.items():
            unknown = component == "valve" and cycle >= 2
            p = 0.9 - 0.1 * cycle if component == "valve" else 0.97
            rest = (1.0 - p) / (len(states) - 1)
            rows.append({"cycle": cycle, "window_start": 60.0 * cycle, "window_end": 60.0 * cycle + 60.0,
                         "component": component, "state": "unknown" if unknown else "100", "probability": p,
                         "probabilities": [{"state": s, "probability": p if s == "100" else rest} for s in states],
                         "novelty": float("nan") if cycle == 1 else (1.8 if unknown else 0.4),
                         "reason": "no trained state explains the cycle" if unknown else None,
                         "truth": "100" if component == "cooler" else None, "healthy": "100",
                         "model_version": "uci/v1"})
    return pa.RecordBatch.from_pylist(rows, schema=wire_schema(CYCLE_VERDICT))


def test_cycle_verdicts_are_one_message_per_cycle_with_each_components_verdict(tmp_path: Path) -> None:
    key = "hydro/uci/rig1"
    cycles = pa.RecordBatch.from_pylist(
        [{"cycle": c, "start_s": 60.0 * c, "rig": "uci", "grid_hz": 1.0, "channels": ["PS1"],
          "values": [float(c)] * 60, "labels": None} for c in range(4)], schema=wire_schema(RIG_CYCLES))
    source = tmp_path / "rig.mcap"
    with McapWriter(source, metadata={"fleet": "uci", "machine": "rig1"}) as writer:
        writer.write(f"{key}/cycles", cycles, 0)
        writer.write(f"{key}/cycle_health", _cycle_verdicts(0, 2), RECEIVED_NS)
        writer.write(f"{key}/cycle_health", _cycle_verdicts(2, 2), RECEIVED_NS + 1)
    out = tmp_path / "rig.foxglove.mcap"
    summary = export_foxglove(source, out).describe()
    assert "4 cycle verdicts on 1 channels" in summary and "left out 1 messages Foxglove is not given (cycles)" in (
        summary)
    got, _ = _read(out)
    assert list(got) == [f"/{key}/cycle_health"]
    verdicts = got[f"/{key}/cycle_health"]
    assert [log for log, _, _ in verdicts] == [60_000_000_000 * (c + 1) for c in range(4)]  # window_end
    log_ns, publish_ns, third = verdicts[2]
    assert (third["cycle"], third["window_start"], third["window_end"]) == (2, 120.0, 180.0)
    assert publish_ns == RECEIVED_NS + 1 and third["model_version"] == "uci/v1"
    valve = third["components"]["valve"]
    assert valve == {"state": "unknown", "probability": pytest.approx(0.7), "novelty": 1.8, "healthy": "100",
                     "reason": "no trained state explains the cycle",
                     "probabilities": {"73": pytest.approx(0.1), "80": pytest.approx(0.1), "90": pytest.approx(0.1),
                                       "100": pytest.approx(0.7)}}  # null truth left out
    assert third["components"]["cooler"]["truth"] == "100" and third["components"]["cooler"]["state"] == "100"
    assert "novelty" not in verdicts[1][2]["components"]["valve"]  # NaN: JSON has none
    with open(out, "rb") as f:
        summary_record = make_reader(f).get_summary()
    assert summary_record is not None
    (schema,) = [json.loads(s.data) for s in summary_record.schemas.values()]
    components = schema["properties"]["components"]
    assert schema["title"] == "hydrowatch.cycle_verdicts" and set(components["properties"]) == set(COMPONENTS)
    assert set(components["properties"]["valve"]["properties"]["probabilities"]["properties"]) == set(
        COMPONENTS["valve"])
    assert components["additionalProperties"]["properties"]["probability"]["type"] == "number"


def test_expected_points_refuse_lists_of_different_lengths() -> None:
    from hydrowatch.io.foxglove import expected_points

    batch = _expected(0.0)
    rows = batch.to_pylist()
    rows[1]["expected"] = rows[1]["expected"][:-1]
    bad = pa.RecordBatch.from_pylist(rows, schema=batch.schema)
    with pytest.raises(ValueError, match="expected must have as many points as measured. Got 19 and 20 for sensor "
                                         "'torque'"):
        list(expected_points(bad, "m1.mcap: message 3"))
