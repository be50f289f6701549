"""Codec speed: Arrow encode + decode of sensor chunks, samples per second per core.

Compares the chosen message encoding (IPC stream: schema + batch, carries name, version and
units) with the bare batch (``batch.serialize()`` / ``pa.ipc.read_record_batch``: no schema, so
no version check possible) and reports the MCAP write/read rate of whole recordings. The codec
caches each schema's serialised schema message (encode) and the verdict of its full validation
(decode); the "cold" row clears those caches before every call, i.e. what every message cost
before the caches (and what the first message of a schema still costs). The "fleet encoder,
check" row is the bus's hot path: the plant's one-pass encoder (per message, 100 machines, no
labels) and the recorder's validation without building the batch (``codec.check_payload``).

Reference: 200 Hz × 8 columns per machine; the target is to encode + decode a 1000-machine fleet
in real time on one core, i.e. ≥ 200,000 samples/s per core (stack-notes: publishers reach
15-20k msgs/s). Run: ``python benchmarks/bench_io_codec.py [--repeat N]``. Timings on a shared
2-core machine are pessimistic.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import pyarrow as pa

from hydrowatch.bus.fleet_publisher import FleetEncoder
from hydrowatch.channels import PLANT
from hydrowatch.io import codec, decode_batch, encode_batch, read_recording, sensor_chunk_from_arrays, write_recording
from hydrowatch.recording import Recording
from hydrowatch.schemas import SENSOR_CHUNK

REFERENCE_SAMPLES_PER_S = 200_000.0
CHANNELS = PLANT.names


def best_of(func: Callable[[], object], number: int, repeat: int) -> float:
    """Best mean time of one call, s, over ``repeat`` runs of ``number`` calls."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        for _ in range(number):
            func()
        best = min(best, (time.perf_counter() - start) / number)
    return best


def cold(func: Callable[[], object]) -> Callable[[], object]:
    """``func`` with the codec's schema caches emptied before each call."""

    def call() -> object:
        codec._ENCODE_CACHE.clear()
        codec._DECODE_CACHE.clear()
        codec._LAYOUTS.clear()
        return func()

    return call


def main(repeat: int = 5) -> None:
    rng = np.random.default_rng(0)
    print(
        f"{'chunk':>6} {'encoding':<22} {'bytes':>6} {'build µs':>9} {'enc µs':>7} {'dec µs':>7} "
        f"{'samples/s/core':>15} {'× ref':>6}"
    )
    for n in (20, 100, 1000):
        t = np.arange(n) / 200.0
        channels = {c: rng.normal(size=n) for c in CHANNELS}
        build = best_of(partial(sensor_chunk_from_arrays, t, channels), 2000 // max(1, n // 100), repeat)
        batch = sensor_chunk_from_arrays(t, channels)
        number = 2000
        stream = encode_batch(batch)
        enc = best_of(partial(encode_batch, batch), number, repeat)
        dec = best_of(partial(decode_batch, stream, SENSOR_CHUNK), number, repeat)
        enc_cold = best_of(cold(partial(encode_batch, batch)), number // 4, repeat)
        dec_cold = best_of(cold(partial(decode_batch, stream, SENSOR_CHUNK)), number // 4, repeat)
        check = best_of(partial(codec.check_payload, stream, SENSOR_CHUNK), number, repeat)
        fleet = FleetEncoder(CHANNELS, ["healthy"] * 100)
        block = {c: np.tile(channels[c], (100, 1)) for c in CHANNELS}
        times = np.tile(t, (100, 1))
        fleet.encode(times, block), fleet.encode(times, block)  # learn the layout, check it
        enc_fleet = best_of(partial(fleet.encode, times, block), max(1, number // 100), repeat) / 100
        bare = batch.serialize()
        enc_bare = best_of(batch.serialize, number, repeat)
        dec_bare = best_of(partial(pa.ipc.read_record_batch, bare, batch.schema), number, repeat)
        for name, size, b, e, d in (
            ("ipc-stream (chosen)", len(stream), build, enc, dec),
            ("ipc-stream, cold cache", len(stream), build, enc_cold, dec_cold),
            ("fleet encoder, check", len(stream), 0.0, enc_fleet, check),  # it encodes from the arrays
            ("bare batch, no schema", bare.size, build, enc_bare, dec_bare),
        ):
            rate = n / (b + e + d)
            print(
                f"{n:>6} {name:<22} {size:>6} {b * 1e6:>9.1f} {e * 1e6:>7.1f} {d * 1e6:>7.1f} "
                f"{rate:>15,.0f} {rate / REFERENCE_SAMPLES_PER_S:>6.1f}"
            )
    n = 200 * 600  # ten minutes of one machine
    t = np.arange(n) / 200.0
    rec = Recording(t, {c: rng.normal(size=n) for c in CHANNELS}, {"fleet": "f", "machine": "m", "state": "healthy"})
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in (".mcap", ".parquet", ".csv"):
            path = Path(tmp) / f"rec{suffix}"
            w = best_of(partial(write_recording, rec, path), 1, max(1, repeat // 2))
            r = best_of(partial(read_recording, path), 1, max(1, repeat // 2))
            print(
                f"recording {suffix:<8} 10 min × 8 columns: write {n / w:>12,.0f} samples/s, read+check "
                f"{n / r:>12,.0f} samples/s, {path.stat().st_size / n:.1f} bytes/sample"
            )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    main(parser.parse_args().repeat)
