"""Streaming MCAP writer, recovery of unfinished files, and bad messages inside a file."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pyarrow as pa
import pytest

from hydrowatch.errors import DataError
from hydrowatch.io import McapWriter, Recovery, encode_batch, iter_messages, read_recording, summarize
from hydrowatch.io.codec import sensor_chunk_from_arrays
from hydrowatch.schemas import SCHEMA_VERSION, STATUS, wire_schema

TOPIC = "hydro/f1/m1/sensors"


def chunk(i, n=100):
    t = i * n / 200.0 + np.arange(n) / 200.0
    rng = np.random.default_rng(i)
    return sensor_chunk_from_arrays(t, {c: rng.normal(size=n) for c in ("voltage", "flow", "speed", "torque")})


def test_writer_streams_several_topics_and_iter_messages_reads_them_back(tmp_path):
    path = tmp_path / "bus.mcap"
    status = pa.RecordBatch.from_pylist(
        [
            {
                "service": "plant",
                "machine": "m1",
                "time": 1.0,
                "status": "running",
                "messages_in": 0,
                "messages_out": 3,
                "messages_dropped": 0,
                "messages_undecodable": 0,
            }
        ],
        schema=wire_schema(STATUS),
    )
    with McapWriter(path, chunk_size=4096, metadata={"fleet": "f1", "n": 3}) as writer:
        for i in range(30):
            writer.write(TOPIC, chunk(i), i * 500_000_000)
        writer.write("hydro/f1/m1/status", status, 15_000_000_000)
        with pytest.raises(DataError, match="must all be sensor_chunk v2. Got status v1"):
            writer.write(TOPIC, status, 15_000_000_001)
    got = list(iter_messages(path))
    assert [g[0] for g in got] == [TOPIC] * 30 + ["hydro/f1/m1/status"]
    assert got[7][1].equals(chunk(7)) and got[7][2] == 3_500_000_000
    info = summarize(path)
    assert info["finished"] and info["messages"] == 31
    assert info["metadata"]["hydrowatch"] == {"fleet": "f1", "n": "3"}
    assert {c["topic"]: c["messages"] for c in info["channels"]} == {TOPIC: 30, "hydro/f1/m1/status": 1}


def test_writer_rejects_invalid_messages(tmp_path):
    with McapWriter(tmp_path / "x.mcap") as writer:
        with pytest.raises(DataError, match="must carry hydrowatch schema metadata"):
            writer.write(TOPIC, pa.record_batch([pa.array([1.0])], names=["t"]), 0)


def write_with_bad_message(path, payload):
    with McapWriter(path) as writer:
        for i in range(5):
            writer.write(TOPIC, chunk(i), i * 500_000_000)
        writer.write_encoded(TOPIC, payload, 2_500_000_000, "sensor_chunk", SCHEMA_VERSION)


def test_malformed_payload_in_file_is_named_and_complete_messages_come_first(tmp_path):
    path = tmp_path / "bad.mcap"
    write_with_bad_message(path, b"\x01\x02garbage")
    got = []
    with pytest.raises(
        DataError,
        match=r"bad.mcap: message 5 on hydro/f1/m1/sensors \(log time 2.500 s\): message "
        "must be an Arrow IPC stream",
    ):
        for message in iter_messages(path):
            got.append(message)
    assert len(got) == 5
    info = summarize(path)
    assert info["channels"][0]["undecodable"] == 1 and info["channels"][0]["samples"] == 500
    with pytest.raises(DataError, match="message 5"):
        read_recording(path)


def test_wrong_schema_version_in_file(tmp_path):
    path = tmp_path / "v3.mcap"
    batch = chunk(5)
    v2 = batch.replace_schema_metadata({**batch.schema.metadata, b"hydrowatch.schema_version": b"3"})
    write_with_bad_message(path, encode_batch(v2))
    with pytest.raises(DataError, match="message 5 .*sensor_chunk schema version must be 2 or an older"):
        read_recording(path)


def test_truncated_file_recovers_complete_chunks(tmp_path):
    path = tmp_path / "full.mcap"
    with McapWriter(path, chunk_size=8 * 1024) as writer:
        for i in range(40):
            writer.write(TOPIC, chunk(i), i * 500_000_000)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    recovery = Recovery(str(cut))
    got = list(iter_messages(cut, recovery=recovery))
    assert not recovery.finished and 0 < recovery.messages < 40
    for i, (_, batch, _) in enumerate(got):  # every recovered message is exactly what was written
        assert batch.equals(chunk(i))
    assert "unfinished file" in recovery.describe() and recovery.bytes_lost > 0
    with pytest.raises(DataError, match=r"cut.mcap: file must be a finished MCAP. Got unfinished .*--recover"):
        read_recording(cut)


CRASH_SCRIPT = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from hydrowatch.io import McapWriter
    from hydrowatch.io.codec import sensor_chunk_from_arrays
    with McapWriter(sys.argv[1], chunk_size=4096, metadata={"fleet": "f1", "machine": "m1"}) as w:
        for i in range(100000):
            t = i * 0.5 + np.arange(100) / 200.0
            w.write("hydro/f1/m1/sensors", sensor_chunk_from_arrays(t, {c: t * k for k, c in
                    enumerate(("voltage", "flow", "speed", "torque"))}), i * 500_000_000)
            if i == 40:
                print("ready", flush=True)
            time.sleep(0.002)
    """
)


def test_sigkilled_writer_loses_only_the_open_chunk(tmp_path):
    path = tmp_path / "crash.mcap"
    proc = subprocess.Popen([sys.executable, "-c", CRASH_SCRIPT, str(path)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.2)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    recovery = Recovery(str(path))
    messages = list(iter_messages(path, recovery=recovery))
    assert not recovery.finished and len(messages) >= 40
    # consecutive, complete and exact: message i holds t = i*0.5 + k/200 and flow = t
    for i, (_, batch, log_time) in enumerate(messages):
        assert log_time == i * 500_000_000
        t = batch.column("t").to_numpy()
        np.testing.assert_array_equal(t, i * 0.5 + np.arange(100) / 200.0)
        np.testing.assert_array_equal(batch.column("flow").to_numpy(), t)
    # at most one 4 kB chunk (a few messages) was lost
    assert recovery.bytes_lost < 8 * 1024
    info = summarize(path)
    assert not info["finished"] and info["messages"] == len(messages)
    assert "recovered" in info["recovery"] and info["metadata"]["hydrowatch"]["machine"] == "m1"
    rec = read_recording(path, recover=True)
    assert len(rec) == 100 * len(messages) and "recovered" in rec.meta["recovered"]


def test_several_machines_need_a_choice(tmp_path):
    path = tmp_path / "fleet.mcap"
    with McapWriter(path) as writer:
        for i in range(4):
            writer.write("hydro/f1/m1/sensors", chunk(i), i)
            writer.write("hydro/f1/m2/sensors", chunk(i), i)
    with pytest.raises(DataError, match="one machine's sensors, or pass machine="):
        read_recording(path)
    assert len(read_recording(path, machine="m2")) == 400
