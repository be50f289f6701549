"""The throughput fast paths change speed, never bytes or verdicts: fleet encoder, payload layouts,
lazy message batches, the MCAP chunk writer and the plant's simulation thread."""

from __future__ import annotations

import io
import threading

import numpy as np
import pyarrow as pa
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from hydrowatch.bus.fleet_publisher import FleetEncoder
from hydrowatch.bus.keys import parse_key
from hydrowatch.bus.pubsub import Message
from hydrowatch.errors import DataError
from hydrowatch.io.codec import check_payload, decode_batch, encode_batch, sensor_chunk_from_arrays
from hydrowatch.io.mcap_chunks import ChunkedWriter
from hydrowatch.schemas import SENSOR_CHUNK
from services.plant import CHANNELS
from services.plant.stepper import SimulationThread


def fleet_step(step: int, machines: int = 4, n: int = 20) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    rng = np.random.default_rng(step)
    t = np.broadcast_to((step * n + np.arange(n)) / 200.0, (machines, n)).copy()
    return t, {c: rng.normal(size=(machines, n)) for c in CHANNELS}


def reference(t: np.ndarray, values: dict[str, np.ndarray], labels: list[str] | None) -> list[bytes]:
    """encode_batch of each machine's slice of one fleet batch (what the plant sent before the
    fleet encoder; a slice's string data may carry the next machine's bytes as padding)."""
    m, n = t.shape
    columns = {c: values[c].reshape(-1) for c in CHANNELS}
    if labels is not None:
        columns["state"] = [label for label in labels for _ in range(n)]
    fleet = sensor_chunk_from_arrays(t.reshape(-1), columns)
    return [encode_batch(fleet.slice(j * n, n)) for j in range(m)]


@pytest.mark.parametrize("labels", [["healthy", "pump_leak", "healthy", "relief_valve"], None])
def test_fleet_encoder_gives_encode_batch_bytes_and_turns_fast_after_checking(labels):
    encoder = FleetEncoder(CHANNELS, labels)
    for step in range(5):
        t, values = fleet_step(step)
        payloads = encoder.encode(t, values)
        assert payloads == reference(t, values, labels)
        assert encoder.fast == (step >= 1)  # learnt on step 0, checked against encode_batch on step 1
        batch = decode_batch(payloads[3], SENSOR_CHUNK)
        np.testing.assert_array_equal(batch.column("torque").to_numpy(), values["torque"][3])
        assert labels is None or batch.column("state").to_pylist() == [labels[3]] * 20
    # another chunk length: back to encode_batch, then fast again
    t, values = fleet_step(9, n=7)
    assert encoder.encode(t, values) == reference(t, values, labels) and not encoder.fast


def test_the_fleet_publisher_relabels_keeps_history_and_drops_on_purpose():
    """The plant service's and the demo's path: a machine whose state changes gets its new label from that step
    on (the encoder learns again), every chunk goes to the history, every 5th message stays off the bus."""
    from hydrowatch.bus.fleet_publisher import FleetPublisher
    from hydrowatch.bus.history import ChunkHistory

    class Bus:
        messages_out = 0
        sent: list[tuple[str, bytes]] = []

        def put_payload(self, k: str, payload: bytes) -> None:
            self.sent.append((k, payload))
            self.messages_out += 1

    bus, history = Bus(), ChunkHistory(10)
    fleet = FleetPublisher(bus, "f", ["m0", "m1"], CHANNELS, ["healthy"] * 2, history, drop_every=5)  # type: ignore
    labels = [["healthy", "healthy"]] * 3 + [["healthy", "load_warning"]] * 3
    expected = []
    for step, now in enumerate(labels):
        t, values = fleet_step(step, machines=2)
        fleet.publish({"t": t, **values}, now)
        expected += list(zip(["hydro/f/m0/sensors", "hydro/f/m1/sensors"], reference(t, values, now)))
        assert fleet.encoder.fast == (step not in (0, 3))  # learnt again at the change, checked on the next step
    assert fleet.dropped == 2 and bus.sent == [e for i, e in enumerate(expected) if (i + 1) % 5]
    assert decode_batch(bus.sent[-1][1], SENSOR_CHUNK).column("state").to_pylist() == ["load_warning"] * 20
    assert [p for p, _ in history.between("hydro/f/m1/sensors", 0.0, 1.0)] == [p for k, p in expected if "m1" in k]


def test_same_head_other_values_decode_to_the_new_values_and_start_time_reads_the_body():
    t, values = fleet_step(0, machines=2)
    first, second = reference(t, values, None)
    layout = check_payload(first, SENSOR_CHUNK, "k")
    assert check_payload(second, SENSOR_CHUNK, "k") is layout  # same head and size: one lookup
    batch = decode_batch(second, SENSOR_CHUNK, "k")
    np.testing.assert_array_equal(batch.column("flow").to_numpy(), values["flow"][1])
    assert layout.start_time(second) == t[1, 0] == 0.0
    later, _ = fleet_step(3, machines=1)
    payload = reference(later, fleet_step(3, machines=1)[1], ["healthy"])[0]  # another head
    assert check_payload(payload, SENSOR_CHUNK).start_time(payload) == later[0, 0] == 0.3
    # one byte short, or a null in a required field (another head): the full checks run and fail
    with pytest.raises(DataError):
        check_payload(second[:-9], SENSOR_CHUNK, "k")
    cols = [pa.array([None] + [1.0] * 19, pa.float64()) if f.name == "flow" else c
            for f, c in zip(batch.schema, batch.columns)]
    with pytest.raises(DataError, match="field 'flow' must have no nulls. Got 1."):
        check_payload(encode_batch(pa.RecordBatch.from_arrays(cols, schema=batch.schema)), SENSOR_CHUNK, "k")


def test_message_reads_its_batch_only_when_asked():
    t, values = fleet_step(2, machines=1)
    payload = reference(t, values, None)[0]
    message = Message(parse_key("hydro/f/m1/sensors"), None, payload, 5, 4, check_payload(payload, SENSOR_CHUNK))
    assert message._batch is None and message.start_time() == t[0, 0]
    assert message.schema.names[:2] == ["t", "voltage"] and message._batch is None
    assert message.batch.equals(decode_batch(payload, SENSOR_CHUNK))
    with pytest.raises(ValueError, match="needs its batch or the layout"):
        Message(parse_key("hydro/f/m1/sensors"), None, payload, 5, 4)


def write_file(cls: type[Writer], compression: CompressionType, fast: bool) -> bytes:
    out = io.BytesIO()
    writer = cls(out, chunk_size=300, compression=compression)
    writer.start(profile="hydrowatch", library="test")
    schema = writer.register_schema(name="s", encoding="x", data=b"abc")
    a = writer.register_channel(topic="a", message_encoding="x", schema_id=schema)
    b = writer.register_channel(topic="b", message_encoding="x", schema_id=schema)
    writer.add_metadata("m", {"k": "v"})
    for i in range(50):
        args = (a if i % 3 else b, 1000 + 7 * i - i % 5, bytes([i]) * (i + 3), 5 + i, i)
        writer.add_encoded(*args) if fast else writer.add_message(*args)  # type: ignore[attr-defined]
        if i == 30:
            writer.flush()
    writer.finish()
    return out.getvalue()


def test_chunked_writer_writes_the_bytes_of_mcaps_writer_and_mcap_reads_them_compressed():
    plain = write_file(Writer, CompressionType.NONE, fast=False)
    assert write_file(ChunkedWriter, CompressionType.NONE, fast=True) == plain
    expected = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(io.BytesIO(plain)).iter_messages()]
    for compression in (CompressionType.ZSTD, CompressionType.LZ4):
        reader = make_reader(io.BytesIO(write_file(ChunkedWriter, compression, fast=True)), validate_crcs=True)
        assert [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()] == expected
        assert reader.get_summary().statistics.message_count == 50


class _Counter:
    """Stands in for PlantSimulator: ``step`` returns the sample counter."""

    sample_rate = 200.0

    def __init__(self) -> None:
        self.k = 0

    @property
    def time(self) -> float:
        return self.k / self.sample_rate

    def step(self, voltage: np.ndarray) -> dict[str, np.ndarray]:
        out = {"t": (self.k + np.arange(voltage.shape[1])) / self.sample_rate}
        self.k += voltage.shape[1]
        return out


class _Zeros:
    def next(self, n: int) -> np.ndarray:
        return np.zeros((1, n))


def test_simulation_thread_yields_every_step_in_order_and_stops():
    stop = threading.Event()
    steps = SimulationThread(_Counter(), _Zeros(), 20, 1.0, stop)  # type: ignore[arg-type]
    steps.start()
    got = list(steps)
    steps.close()
    assert [end for _, end in got] == pytest.approx([0.1 * (i + 1) for i in range(10)])
    np.testing.assert_allclose(np.concatenate([out["t"] for out, _ in got]), np.arange(200) / 200.0)
    endless = SimulationThread(_Counter(), _Zeros(), 20, float("inf"), stop)  # type: ignore[arg-type]
    endless.start()
    for i, _ in enumerate(endless):
        if i == 3:
            stop.set()
    endless.close()
    assert 4 <= i <= 7  # what was queued (at most 2 ahead) when stopped


def test_recording_files_open_files_in_the_background_and_keep_every_message_in_order(tmp_path):
    from hydrowatch.io.mcap_io import iter_messages
    from services.recorder.files import RecordingFiles

    machines, steps = 12, 6
    files = RecordingFiles(tmp_path, flush_s=0.01)
    encoder = FleetEncoder(CHANNELS, ["healthy"] * machines)
    keys = [parse_key(f"hydro/f1/m{j:02d}/sensors") for j in range(machines)]
    for step in range(steps):
        t, values = fleet_step(step, machines)
        burst = [Message(k, None, p, 10 + step, 0, check_payload(p, SENSOR_CHUNK))
                 for k, p in zip(keys, encoder.encode(t, values))]
        files.write_many(burst[: machines // 2])  # files still opening: these wait in memory
        files.write_many(burst[machines // 2:])
        if step == 2:
            files.tick()
    files.close()
    assert files.messages == machines * steps and len(files.files_written) == machines
    for j in range(machines):
        (path,) = (tmp_path / "f1" / f"m{j:02d}").glob("*.mcap")
        starts = [batch.column("t")[0].as_py() for _, batch, _ in iter_messages(path)]
        assert starts == pytest.approx([0.1 * step for step in range(steps)])


def test_a_stream_in_arrow_s_legacy_format_still_checks_and_reads():
    t, values = fleet_step(1, machines=1)
    batch = sensor_chunk_from_arrays(t[0], {c: values[c][0] for c in CHANNELS})
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, batch.schema, options=pa.ipc.IpcWriteOptions(use_legacy_format=True)) as writer:
        writer.write_batch(batch)
    legacy = sink.getvalue().to_pybytes()
    layout = check_payload(legacy, SENSOR_CHUNK)
    assert layout.read(legacy).equals(batch) and layout.start_time(legacy) is None
    assert decode_batch(legacy, SENSOR_CHUNK).equals(batch)


def test_chunked_writer_holds_about_a_hundred_bytes_per_chunk_until_the_file_is_finished(tmp_path):
    # a recorder closes a chunk per machine every second and keeps every chunk's index until the file is finished:
    # mcap's ChunkIndex objects held ~680 B each (1.2 GB per hour of a file's life per 500 machines)
    import tracemalloc

    with (tmp_path / "a.mcap").open("wb") as out:
        writer = ChunkedWriter(out, chunk_size=1_000_000, compression=CompressionType.ZSTD)
        writer.start(profile="hydrowatch", library="test")
        channel = writer.register_channel(topic="a", message_encoding="x",
                                          schema_id=writer.register_schema(name="s", encoding="x", data=b"abc"))
        payload = bytes(range(256)) * 12

        def chunks(first: int, count: int) -> None:
            for i in range(first, first + count):
                writer.add_encoded(channel, 10**18 + i * 10**9, payload, 10**18 + i * 10**9, i)
                writer.flush()  # one message per chunk: what --flush does to a quiet machine

        chunks(0, 500)  # buffers and caches reach their size
        tracemalloc.start()
        before = tracemalloc.get_traced_memory()[0]
        chunks(500, 4000)
        per_chunk = (tracemalloc.get_traced_memory()[0] - before) / 4000
        tracemalloc.stop()
        writer.finish()
    assert per_chunk < 150, per_chunk
    summary = make_reader((tmp_path / "a.mcap").open("rb")).get_summary()
    assert len(summary.chunk_indexes) == 4500 and summary.statistics.chunk_count == 4500
    assert [i.message_start_time for i in summary.chunk_indexes[:2]] == [10**18, 10**18 + 10**9]
