"""The codec's hot path on the bus: cached schema messages must change speed, never behaviour."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from hydrowatch.errors import DataError
from hydrowatch.io.codec import (
    SchemaMismatchError,
    SchemaVersionError,
    UndecodableMessageError,
    decode_batch,
    encode_batch,
    sensor_chunk_from_arrays,
)
from hydrowatch.schemas import KL_WINDOW, SENSOR_CHUNK

CHANNELS = ("voltage", "flow", "speed", "torque", "temperature")


def fleet_chunk(machines: int = 5, n: int = 20) -> pa.RecordBatch:
    """One batch holding ``machines`` chunks of ``n`` samples, machine-major (as the plant builds it)."""
    rng = np.random.default_rng(3)
    t = np.tile(np.arange(n) / 200.0, machines)
    labels = ["healthy"] * (machines * n)
    return sensor_chunk_from_arrays(t, {**{c: rng.normal(size=t.size) for c in CHANNELS}, "state": labels})


def stream_writer_bytes(batch: pa.RecordBatch) -> bytes:
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, batch.schema) as writer:
        writer.write_batch(batch)
    return sink.getvalue().to_pybytes()


def test_encoded_slices_are_byte_identical_to_a_stream_writer():
    fleet = fleet_chunk()
    for j in range(5):
        piece = fleet.slice(j * 20, 20)
        assert encode_batch(piece) == stream_writer_bytes(piece)
    # a schema whose stream needs more than schema + batch (a dictionary) takes the writer's path
    coded = pa.record_batch([pa.array(["a", "b", "a"]).dictionary_encode()], names=["s"])
    data = encode_batch(coded)
    assert data == stream_writer_bytes(coded)
    assert pa.ipc.open_stream(data).read_all().column("s").to_pylist() == ["a", "b", "a"]


def test_decoding_the_same_schema_again_returns_the_same_batches():
    fleet = fleet_chunk()
    payloads = [encode_batch(fleet.slice(j * 20, 20)) for j in range(5)]
    for form in (bytes, memoryview, pa.py_buffer):
        for j, data in enumerate(payloads):
            batch = decode_batch(form(data), SENSOR_CHUNK, "k")
            assert batch.equals(fleet.slice(j * 20, 20))
            assert batch.schema.equals(fleet.schema, check_metadata=True)
            assert batch.column("state").to_pylist() == ["healthy"] * 20


def test_bad_messages_after_a_good_one_are_still_rejected():
    fleet = fleet_chunk()
    good = encode_batch(fleet.slice(0, 20))
    decode_batch(good, SENSOR_CHUNK, "k")  # its schema message is now known
    # truncated anywhere between the schema message and the batch's end
    for cut in (1100, len(good) // 2, len(good) - 40):
        with pytest.raises(UndecodableMessageError, match="k: message must be an Arrow IPC stream"):
            decode_batch(good[:cut], SENSOR_CHUNK, "k")
    # the same schema bytes, but nulls in a required field (Arrow does not enforce non-null); the
    # counts come from the message's field nodes: each field and count must be the right one
    for k, field in enumerate(("t", "voltage", "flow", "speed", "torque"), start=1):
        cols = [pa.array([None if i % k == 0 else 1.0 for i in range(20)], pa.float64()) if n == field else c
                for n, c in zip(fleet.schema.names, fleet.slice(0, 20).columns)]
        nulls = pa.RecordBatch.from_arrays(cols, schema=fleet.schema)
        with pytest.raises(DataError, match=f"field '{field}' must have no nulls. Got {len(range(0, 20, k))}."):
            decode_batch(encode_batch(nulls), SENSOR_CHUNK, "k")
    # nulls in an optional field are fine
    cols = [pa.array([None] * 20, pa.float64()) if n == "temperature" else c
            for n, c in zip(fleet.schema.names, fleet.slice(0, 20).columns)]
    optional = decode_batch(encode_batch(pa.RecordBatch.from_arrays(cols, schema=fleet.schema)), SENSOR_CHUNK)
    assert optional.column("temperature").null_count == 20
    # a known schema message checked against another expected schema
    with pytest.raises(SchemaMismatchError, match="must be 'kl_window'"):
        decode_batch(good, KL_WINDOW, "k")
    v2 = fleet.replace_schema_metadata({**fleet.schema.metadata, b"hydrowatch.schema_version": b"3"})
    for _ in range(2):
        with pytest.raises(SchemaVersionError):
            decode_batch(encode_batch(v2.slice(0, 20)), SENSOR_CHUNK, "k")
    # and the good one still decodes
    assert decode_batch(good, SENSOR_CHUNK).num_rows == 20
