"""One rotating MCAP file per machine (a recording is one machine over one stretch of time).

Files are ``<out>/<fleet>/<machine>/<UTC start>-<seq>.mcap``; a file is opened on a machine's
first message (on a worker thread: the machine's messages wait in memory for the few ms that
takes), so its ``hydrowatch`` metadata (fleet, machine, state, schema_version, units) is complete
from the start and survives a crash. It rotates when it grows past ``rotate_bytes`` or spans
``rotate_s`` of wall-clock time. Chunks close every ``chunk_size`` bytes or ``flush_s`` seconds,
whichever comes first: that bounds what a ``kill -9`` can lose. With ``foxglove`` the files are
``<UTC start>-<seq>.foxglove.mcap`` and hold JSON for Foxglove instead of the Arrow payloads
(:class:`hydrowatch.io.foxglove.FoxgloveWriter`; log time = sample time, publish time = receive time).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from hydrowatch.bus.keys import Key
from hydrowatch.bus.pubsub import Message
from hydrowatch.errors import DataError
from hydrowatch.io.foxglove import FoxgloveWriter
from hydrowatch.io.mcap_io import McapWriter
from hydrowatch.log import event, get_logger
from hydrowatch.schemas import SCHEMA_VERSION, schema_name, schema_version, units

log = get_logger(__name__)

OPENERS = 4
"""Threads that create folders and files: creating one took 0.1-3 ms of wall time (disk), during
which the recorder would otherwise stop taking messages (~3 s at the first chunk of 1000 machines)."""
MAX_TIME_NS = 2**63 - 1
"""Latest time an MCAP record takes, ns (a chunk that says it starts later is stored at this time)."""


@dataclass
class _Open:
    writer: McapWriter
    opened: float
    messages: int = 0


@dataclass
class RecordingFiles:
    """Writes received messages into per-machine MCAP files.

    Parameters
    ----------
    out : Path
        Folder of the recordings.
    chunk_size : int
        Bytes per MCAP chunk before compression.
    compression : str
        ``zstd``, ``lz4`` or ``none``.
    flush_s : float
        Close a chunk once it spans this many seconds of receive time.
    rotate_bytes : int
        Start a new file past this size, bytes.
    rotate_s : float
        Start a new file after this many seconds.
    extra_metadata : dict
        Added to every file's ``hydrowatch`` metadata (e.g. recorder id, shard).
    foxglove : bool
        Write JSON that Foxglove plots (samples, verdicts, relative entropies, forecasts, expected sensors, cycle
        verdicts; heartbeats and a rig's raw cycles left out)
        instead of the payloads as received. Costs ~5 µs per sample: for a few machines on a bench.
    """

    out: Path
    chunk_size: int = 64 * 1024
    compression: str = "zstd"
    flush_s: float = 1.0
    rotate_bytes: int = 256 * 1024 * 1024
    rotate_s: float = 3600.0
    extra_metadata: dict = field(default_factory=dict)
    foxglove: bool = False
    files_written: list[Path] = field(default_factory=list)
    messages: int = 0
    unwritable: dict[str, int] = field(default_factory=dict)
    """Per key, messages a Foxglove recording could not carry (a NaN or negative sample time), left out."""
    _open: dict[tuple[str, str], _Open] = field(default_factory=dict)
    _opening: dict[tuple[str, str], tuple[Future[_Open], list[Message]]] = field(default_factory=dict)
    _sequence: int = 0
    _channels: dict[Key, tuple[str, str, int, bool]] = field(default_factory=dict)
    _pool: ThreadPoolExecutor = field(
        default_factory=lambda: ThreadPoolExecutor(OPENERS, thread_name_prefix="recorder-open"))

    def _new_file(self, message: Message, sequence: int) -> _Open:
        fleet, machine = message.key.fleet, message.key.machine
        folder = self.out / fleet / machine
        folder.mkdir(parents=True, exist_ok=True)
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        path = folder / f"{stamp}-{sequence:04d}{'.foxglove' if self.foxglove else ''}.mcap"
        batch = message.batch
        state = None
        if "state" in batch.schema.names and batch.num_rows:
            state = batch.column("state")[0].as_py()
        metadata = {
            "fleet": fleet,
            "machine": machine,
            "state": state,
            "schema_version": str(schema_version(batch.schema) or SCHEMA_VERSION),
            "units": units(batch.schema),
            **self.extra_metadata,
        }
        kind = FoxgloveWriter if self.foxglove else McapWriter
        writer = kind(path, chunk_size=self.chunk_size, compression=self.compression, metadata=metadata,
                      flush_every_s=self.flush_s)
        return _Open(writer, time.monotonic())

    def _start_file(self, machine: tuple[str, str], message: Message) -> None:
        """Open the machine's next file on a worker thread; its messages wait in memory meanwhile."""
        self._sequence += 1
        self._opening[machine] = (self._pool.submit(self._new_file, message, self._sequence), [message])

    def _adopt(self, wait: bool = False) -> None:
        """Start writing to the files that are open by now (all of them with ``wait``), oldest
        waiting messages first."""
        for machine, (future, waiting) in list(self._opening.items()):
            if wait or future.done():
                del self._opening[machine]
                current = self._open[machine] = future.result()
                self.files_written.append(current.writer.path)
                for message in waiting:
                    self._append(current, message)

    def write(self, message: Message) -> None:
        """Append one message: log time = receive time, publish time = sample time of the chunk start."""
        self.write_many([message])

    def write_many(self, messages: Iterable[Message]) -> None:
        """Append messages in order (what one :meth:`Subscriber.recv_many` returned): the clock is read
        once for the whole burst, channel facts (topic, schema name and version) once per key."""
        if self._opening:
            self._adopt()
        now = time.monotonic()
        for message in messages:
            machine = message.key[:2]
            current = self._open.get(machine)
            if current is not None and self._due(current, now):
                current.writer.close()
                del self._open[machine]
                current = None
            if current is not None:
                self._append(current, message)
            elif machine in self._opening:
                self._opening[machine][1].append(message)
            else:
                self._start_file(machine, message)

    def _append(self, current: _Open, message: Message) -> None:
        """Write one message: log time = receive time, publish time = sample time of the chunk start."""
        channel = self._channels.get(message.key)
        if channel is None:
            schema = message.schema
            channel = self._channels[message.key] = (
                str(message.key), schema_name(schema) or "", schema_version(schema) or SCHEMA_VERSION,
                message.key.topic == "sensors",
            )
        topic, name, version, sensors = channel
        if isinstance(current.writer, FoxgloveWriter):
            try:
                current.writer.write_message(topic, message.batch, message.receive_time_ns)
            except DataError as exc:  # a sample time JSON cannot carry as a log time (NaN, negative): left out
                self.unwritable[topic] = self.unwritable.get(topic, 0) + 1
                if self.unwritable[topic] == 1:
                    event(log, "message left out of the Foxglove recording", logging.WARNING, key=topic, reason=exc)
                return
        else:
            publish = message.publish_time_ns
            if sensors and (start := message.start_time()) is not None and math.isfinite(start):
                publish = min(max(0, int(round(start * 1e9))), MAX_TIME_NS)  # else (NaN t) the publish time as sent
            current.writer.write_encoded(topic, message.payload, message.receive_time_ns, name, version, publish)
        current.messages += 1
        self.messages += 1

    def _due(self, current: _Open, now: float) -> bool:
        if now - current.opened >= self.rotate_s:
            return True
        # stat every 64 messages: the file size is what rotation bounds, and stat is not free
        return current.messages % 64 == 0 and current.writer.path.stat().st_size >= self.rotate_bytes

    def tick(self) -> None:
        """Close chunks of machines that went quiet (what has arrived survives a crash) and rotate old files."""
        self._adopt()
        for machine, current in list(self._open.items()):
            if time.monotonic() - current.opened >= self.rotate_s:
                current.writer.close()
                del self._open[machine]
            else:
                current.writer.flush()

    def close(self) -> None:
        """Write what waits for a file, finish every open file (chunk, index, summary)."""
        try:
            self._adopt(wait=True)
        finally:
            for current in self._open.values():
                current.writer.close()
            self._open.clear()
            self._pool.shutdown()
