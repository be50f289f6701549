"""What the soak (benchmarks/bench_soak.py) hears and what its recorders wrote: the verdicts of every machine and
the dates of one machine's sensor chunks (verdict latency), and the sensor chunks in the recorders' files (samples
dropped or recorded twice). Split from bench_soak.py (one module, one job)."""

from __future__ import annotations

import threading
from collections import Counter
from pathlib import Path

import numpy as np

from hydrowatch.bus import BusSettings, Subscriber, open_session
from hydrowatch.io.codec import check_payload
from hydrowatch.io.mcap_io import expected_schema, iter_records
from hydrowatch.recording import SAMPLE_RATE_HZ

FLEET = "soak"
"""The soak's fleet name (``hydro/soak/<machine>/...``)."""


class Verdicts:
    """Verdicts of every machine and m000's sensor chunks, heard by a client of the router (a thread)."""

    def __init__(self, settings: BusSettings) -> None:
        self.settings = settings
        self.chunk_published: dict[int, int] = {}
        """m000's chunks: end (sample index, exclusive) → publish time, ns since the epoch."""
        self.heard: list[tuple[int, int, int]] = []
        """(received ns, window end as a sample index, 1 when invalid) per verdict."""
        self.windows: Counter[tuple[str, int]] = Counter()
        """(machine, window start sample index) → verdicts (not invalid)."""
        self.bytes: Counter[str] = Counter()
        """Payload bytes and messages heard per topic (``health``, ``kl``, ``sensors``; ``<topic> messages``)."""
        self._ready, self._done = threading.Event(), threading.Event()
        self._thread = threading.Thread(target=self._listen, name="verdicts", daemon=True)

    def _listen(self) -> None:
        with open_session(self.settings) as session, \
                Subscriber(session, [f"hydro/{FLEET}/*/health", f"hydro/{FLEET}/*/kl",
                                     f"hydro/{FLEET}/m000/sensors"]) as sub:
            self._ready.set()
            while not self._done.is_set():
                for message in sub.recv_many(timeout=0.2):
                    self.bytes[message.key.topic] += len(message.payload)
                    self.bytes[f"{message.key.topic} messages"] += 1
                    if message.key.topic == "kl":
                        continue
                    if message.key.topic == "sensors":
                        span = message.time_span()
                        if span is not None:
                            end = round(span[1] * SAMPLE_RATE_HZ) + 1
                            self.chunk_published[end] = message.publish_time_ns
                        continue
                    batch = message.batch
                    starts, ends = batch.column("window_start").to_pylist(), batch.column("window_end").to_pylist()
                    for start, end, state in zip(starts, ends, batch.column("state").to_pylist()):
                        self.heard.append((message.receive_time_ns, round(end * SAMPLE_RATE_HZ), state == "invalid"))
                        if state != "invalid":
                            self.windows[(message.key.machine, round(start * SAMPLE_RATE_HZ))] += 1

    def latencies_ms(self, after_ns: int) -> np.ndarray:
        """Window end → verdict received, ms, for verdicts received after ``after_ns`` whose window end is dated: by
        the chunk that holds the window's last sample (the first chunk ending at or after the window's end; windows
        are staggered, chunks are not)."""
        ends = np.array(sorted(self.chunk_published))
        published = np.array([self.chunk_published[e] for e in ends])
        heard = np.array([(received, end) for received, end, _ in list(self.heard) if received >= after_ns])
        if not heard.size or not ends.size:
            return np.empty(0)
        at = np.searchsorted(ends, heard[:, 1])
        chunk = ends[1] - ends[0] if ends.size > 1 else 0
        dated = (at < ends.size) & (heard[:, 1] > ends[0] - chunk)  # not before m000's first chunk heard
        return (heard[dated, 0] - published[at[dated]]) / 1e6

    def plant_speed(self) -> float:
        """Simulated s per wall-clock s between m000's first and last chunk."""
        ends = sorted(self.chunk_published)
        wall = (self.chunk_published[ends[-1]] - self.chunk_published[ends[0]]) / 1e9
        return (ends[-1] - ends[0]) / SAMPLE_RATE_HZ / wall if wall > 0 else float("nan")

    def __enter__(self) -> Verdicts:
        self._thread.start()
        if not self._ready.wait(60):
            raise RuntimeError("the verdict listener did not join the bus in 60 s")
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._thread.join(timeout=30)


def recorded_chunks(folder: Path) -> tuple[dict[str, Counter[int]], dict[int, int], Counter[str]]:
    """Per machine, how often each chunk start (sample index) is in the files under ``folder`` (every shard's);
    rows per chunk start seen; and the totals ``files``, ``file_bytes``, ``messages``, ``payload_bytes``. Read from
    each record's head and first time, the samples not decoded."""
    starts: dict[str, Counter[int]] = {}
    rows: dict[int, int] = {}
    totals: Counter[str] = Counter()
    for path in sorted(folder.rglob("*.mcap")):
        totals["files"] += 1
        totals["file_bytes"] += path.stat().st_size
        found = starts.setdefault(path.parent.name, Counter())
        for channel, schema, record in iter_records(path):
            expected = expected_schema(channel, schema)
            if expected is None or not channel.topic.endswith("/sensors"):
                continue
            layout = check_payload(record.data, expected, str(path))
            start = round(layout.start_time(record.data) * SAMPLE_RATE_HZ)  # type: ignore[operator]
            found[start] += 1
            rows[start] = layout.rows
            totals["messages"] += 1
            totals["payload_bytes"] += len(record.data)
    return starts, rows, totals
