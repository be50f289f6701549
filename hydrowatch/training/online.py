"""Online scoring of a fleet, chunk by chunk (river style: ``update`` feeds, nothing is re-read).

:class:`OnlineScorer` is the one fleet driver of every health method: it asks the bundle's method
for its streaming part (:meth:`HealthMethod.online <hydrowatch.methods.base.HealthMethod.online>`) and
applies chunk hygiene, breaks, staggering, batching and the verdicts' times the same way for all:

* a method that reads raw windows (parity, stats) gives a
  :class:`~hydrowatch.methods.base.WindowJudge`, run by
  :class:`~hydrowatch.training.window_fleet.WindowFleet`: every machine's window is a row of one
  fleet-wide array, clean chunks are written with one vectorised scatter per update, and closed
  windows are judged as they close in batches of at most ``batch`` (the parity judge optionally
  pools each verdict over the machine's last ``smoothing`` windows);
* a method whose values need a state per machine (the study's entropy method: the reference
  models' delay lines or filter states, :class:`~hydrowatch.methods.entropy.reference.StreamState`)
  gives a :class:`~hydrowatch.methods.base.StreamEngine`, run here machine by machine: all
  machines' segments of equal length are processed in one batched call, and all windows that close
  in one :meth:`OnlineScorer.update` are judged in one call.

A stream breaks, and the window in progress is published as ``invalid`` with its reason instead of
producing a wrong verdict, when a chunk

* leaves a gap (its first sample is later than one sample after the previous chunk's last),
* arrives late or out of order (its first sample is not after the previous chunk's last),
* has NaN in the voltage or a sensor the method reads (the NaN samples are skipped),
* is irregular inside (sample spacing off 1/200 s).

After a break the stream restarts: the reference models warm up again (``bundle.warmup`` samples,
none for the raw-window methods) and windows are counted from the first sample after the warm-up.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrowatch.methods.base import HealthMethod, StreamEngine, refuse_smoothing
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.chunks import (
    DT,
    TOLERANCE,
    Break,
    Chunk,
    ChunkBatch,
    Segment,
    WindowVerdict,
    chunk_matrix,
    chunks_from_batches,
    clean_chunks,
    cut_short,
    plan_chunk,
)
from hydrowatch.training.window_fleet import WindowFleet

__all__ = ["DT", "TOLERANCE", "Chunk", "ChunkBatch", "OnlineScorer", "WindowVerdict", "chunks_from_batches"]


@dataclass
class _Stream:
    states: Any
    """The engine's per-machine state (:meth:`StreamEngine.new_states`)."""
    window: Any
    """The machine's window of values (:meth:`StreamEngine.new_window`)."""
    next_t: float | None = None
    start_t: float | None = None
    """Time of the first sample of the stream (warm-up included)."""
    fed_t: float | None = None
    """Time of the first sample fed to the window (after warm-up)."""
    reported: int = 0
    """Windows already turned into verdicts."""
    seen: int = 0
    """Samples received since the stream (re)started."""
    fed: int = 0
    """Samples fed to the window."""


class OnlineScorer:
    """Streaming verdicts for many machines from one model bundle (module docstring).

    Parameters
    ----------
    bundle : ModelBundle
        Any method's bundle.
    keep : int, default 4
        Closed windows each machine keeps (stream engines; only the unreported ones are read).
    smoothing : int, default 1
        Valid windows of a machine whose evidence each verdict pools, for a method that pools (parity,
        :class:`~hydrowatch.condition.stream.ConditionStream`; 1: each window alone). Other methods take only 1.
    batch : int, default 64
        Raw-window methods: most windows judged in one call (bounds the work between verdicts).
    stagger : bool, default False
        Raw-window methods: each machine's windows start at a phase of its own (:class:`WindowFleet`), so
        machines started together do not close their windows in the same update.
    unit_method : callable, optional
        Machine → its commissioned method (:attr:`ModelBundle.health_method` of its commissioning) or None.
    """

    def __init__(self, bundle: ModelBundle, *, keep: int = 4, smoothing: int = 1, batch: int = 64,
                 stagger: bool = False, unit_method: Callable[[str], HealthMethod | None] | None = None) -> None:
        self.bundle = bundle
        self.keep = keep
        self.smoothing = smoothing
        self._streams: dict[str, _Stream] = {}
        self._samples = 0
        method = bundle.health_method
        if smoothing != 1 and not method.pools:
            refuse_smoothing(method.name, smoothing)
        engine = method.online(keep=keep, smoothing=smoothing, unit_method=unit_method)
        self._columns = list(engine.columns)
        self._fleet: WindowFleet | None = None
        if not isinstance(engine, StreamEngine):
            self._fleet = WindowFleet(engine, batch=batch, stagger=stagger)
            return
        self._engine: StreamEngine = engine  # the per-machine path below

    @property
    def samples(self) -> int:
        """Samples fed so far, over every machine."""
        return int(self._fleet.samples) if self._fleet is not None else self._samples

    @property
    def columns(self) -> list[str]:
        """Channels the bundle's method reads from every chunk."""
        return list(self._columns)

    @property
    def machines(self) -> list[str]:
        """Machines seen so far."""
        return self._fleet.machines if self._fleet is not None else list(self._streams)

    def _new_stream(self) -> _Stream:
        return _Stream(self._engine.new_states(), self._engine.new_window())

    def _plans(self, chunks: Sequence[Chunk]) -> dict[str, list[Segment | Break]]:
        """Every machine's segments and breaks; clean chunks are found for the whole update at once.

        A clean chunk (:func:`~hydrowatch.training.chunks.clean_chunks`) becomes one segment
        without going through :func:`plan_chunk` (the per-chunk Python cost limits the fleet size).
        """
        batch = ChunkBatch.from_chunks(chunks, self._columns)
        if not len(batch):
            return {}
        count: dict[str, int] = {}
        for machine in batch.machines:
            count[machine] = count.get(machine, 0) + 1
            if machine not in self._streams:
                self._streams[machine] = self._new_stream()
        streams = [self._streams[m] for m in batch.machines]
        expected = np.array([np.nan if s.next_t is None else s.next_t for s in streams])
        once = np.array([count[m] == 1 for m in batch.machines], dtype=bool)
        clean = clean_chunks(batch, self._columns, expected, once, self._engine.defaults)
        plans: dict[str, list[Segment | Break]] = {}
        for i, machine in enumerate(batch.machines):
            stream = streams[i]
            a, b = int(batch.offsets[i]), int(batch.offsets[i + 1])
            if clean[i]:
                t = batch.t[a:b]
                plans[machine] = [Segment(t, np.stack([batch.channels[c][a:b] for c in self._columns], axis=1))]
                stream.next_t = float(t[-1] + DT)
            else:
                ops, stream.next_t = plan_chunk(batch.t[a:b], chunk_matrix(batch[i], self._columns,
                                                                           self._engine.defaults),
                                                self._columns, stream.next_t)
                plans.setdefault(machine, []).extend(ops)
        return plans

    def _break(self, machine: str, stream: _Stream, op: Break) -> tuple[_Stream, WindowVerdict | None]:
        """Restart the stream; the window in progress (or the warm-up) becomes an invalid verdict."""
        out = None
        if stream.seen:
            if stream.fed_t is not None:
                out = cut_short(machine, stream.window.n_windows * self._engine.hop, stream.fed, stream.fed_t, op)
            elif stream.start_t is not None:  # still warming up: the window would have begun with the stream
                out = cut_short(machine, 0, stream.seen, stream.start_t, op)
        fresh = self._new_stream()
        fresh.next_t = stream.next_t
        return fresh, out

    def _feed(self, jobs: list[tuple[str, _Stream, Segment]]) -> None:
        """Predict one segment per machine, batched by segment length, and feed the windows."""
        by_length: dict[int, list[tuple[str, _Stream, Segment]]] = {}
        for job in jobs:
            by_length.setdefault(job[2].t.size, []).append(job)
        for group in by_length.values():
            x = np.stack([f.x for _, _, f in group])
            stacked = self._engine.values(x, [s.states for _, s, _ in group])  # (M, n, width)
            for i, (_, stream, feed) in enumerate(group):
                if stream.start_t is None:
                    stream.start_t = float(feed.t[0])
                e = stacked[i]
                stream.seen += feed.t.size
                if stream.fed_t is None:  # still warming up: the errors start where every sensor has one
                    ready = np.flatnonzero(np.all(np.isfinite(e), axis=1))
                    if ready.size == 0:
                        continue
                    stream.fed_t = float(feed.t[ready[0]])
                    e = e[ready[0] :]
                stream.window.update(e)
                stream.fed += e.shape[0]
                self._samples += e.shape[0]

    def update(self, chunks: Sequence[Chunk]) -> list[WindowVerdict]:
        """Feed chunks of any machines (in arrival order); returns the verdicts of the windows they close.

        ``chunks`` may be a :class:`ChunkBatch` (:func:`chunks_from_batches`), which the raw-window
        methods read without per-chunk Python work.
        """
        if self._fleet is not None:
            return self._fleet.update(chunks)
        plans = self._plans(chunks)
        out: list[WindowVerdict] = []
        closed: list[tuple[str, Any, float]] = []
        while plans:
            jobs = []
            for machine in list(plans):
                ops = plans[machine]
                while ops and isinstance(ops[0], Break):
                    self._collect(machine, closed)
                    brk = ops.pop(0)
                    assert isinstance(brk, Break)
                    self._streams[machine], invalid = self._break(machine, self._streams[machine], brk)
                    if invalid is not None:
                        out.append(invalid)
                if ops:
                    feed = ops.pop(0)
                    assert isinstance(feed, Segment)
                    jobs.append((machine, self._streams[machine], feed))
                if not ops:
                    del plans[machine]
            self._feed(jobs)
            for machine, _, _ in jobs:
                self._collect(machine, closed)
        return out + self._judge(closed)

    def _collect(self, machine: str, closed: list[tuple[str, Any, float]]) -> None:
        stream = self._streams[machine]
        if stream.window.n_windows > stream.reported and stream.fed_t is not None:
            closed.extend((machine, r, stream.fed_t) for r in self._engine.collect(stream.window,
                                                                                  stream.reported))
            stream.reported = stream.window.n_windows

    def _judge(self, closed: list[tuple[str, Any, float]]) -> list[WindowVerdict]:
        if not closed:
            return []
        judged = self._engine.judge([r for _, r, _ in closed])
        return [WindowVerdict(m, t0 + r.start * DT, t0 + r.stop * DT, v, scores)
                for (m, r, t0), (v, scores) in zip(closed, judged)]
