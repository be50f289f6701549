"""Online scoring of a fleet, chunk by chunk (river style: ``update`` feeds, nothing is re-read).

Per machine the scorer keeps what the bundle's method needs (:mod:`hydrowatch.training.engines`):
for the entropy method the reference models' stream states (delay lines or filter states,
:class:`~hydrowatch.training.reference.StreamState`) and a :class:`~hydrowatch.health.streaming.MachineWindow`
of prediction errors, whose closed windows' relative entropies go to the classifier and the
open-set rule; for the parity method a window of raw samples judged by the condition model. All
machines' segments of equal length are processed in one batched call, and all windows that close
in one :meth:`OnlineScorer.update` are judged in one call.

A stream breaks, and the window in progress is published as ``invalid`` with its reason instead of
producing a wrong verdict, when a chunk

* leaves a gap (its first sample is later than one sample after the previous chunk's last),
* arrives late or out of order (its first sample is not after the previous chunk's last),
* has NaN in the voltage or a sensor the method reads (the NaN samples are skipped),
* is irregular inside (sample spacing off 1/200 s).

After a break the stream restarts: the reference models warm up again (``bundle.warmup`` samples,
none for the parity method) and windows are counted from the first sample after the warm-up.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import pyarrow as pa

from hydrowatch.health.streaming import MachineWindow
from hydrowatch.health.verdict import INVALID, Verdict
from hydrowatch.recording import SAMPLE_RATE_HZ
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.engines import RawWindow, engine_for
from hydrowatch.training.reference import StreamState

DT = 1.0 / SAMPLE_RATE_HZ
TOLERANCE = 0.5 * DT
"""Largest deviation of a sample time from where it is expected, s."""


@dataclass
class Chunk:
    """One received ``sensor_chunk`` of one machine.

    Attributes
    ----------
    machine : str
        ``<fleet>/<machine>`` or any id unique within the scorer.
    t : ndarray, shape (n,)
        Sample times, s.
    channels : mapping of str to ndarray, shape (n,)
        At least ``voltage`` [V] and the bundle's sensors (and ``temperature`` [°C] when a parity
        bundle uses it; 40 °C is assumed when missing).
    """

    machine: str
    t: np.ndarray
    channels: Mapping[str, np.ndarray]


def chunks_from_batches(machines: Sequence[str], batches: Sequence[pa.RecordBatch],
                        columns: Sequence[str]) -> list[Chunk]:
    """:class:`Chunk` s of ``sensor_chunk`` batches with only ``columns`` read (float64; nulls become NaN).

    Batches with the same schema are converted together, one Arrow → NumPy conversion per column
    for all of them (the chunks are views into it): the per-chunk conversion cost is what limits
    the fleet one scorer keeps up with. Columns a batch lacks are left out (the scorer then uses
    its default or breaks the stream); the label column is never read.
    """
    groups: dict[pa.Schema, list[int]] = {}
    for i, batch in enumerate(batches):
        groups.setdefault(batch.schema, []).append(i)
    out: list[Chunk | None] = [None] * len(batches)
    for schema, members in groups.items():
        names = ["t", *[c for c in columns if c in schema.names]]
        arrays = {c: pa.concat_arrays([batches[i].column(c) for i in members]).to_numpy(zero_copy_only=False)
                  for c in names}
        stops = np.cumsum([batches[i].num_rows for i in members]).tolist()
        start = 0
        for i, stop in zip(members, stops):
            out[i] = Chunk(machines[i], arrays["t"][start:stop], {c: arrays[c][start:stop] for c in names[1:]})
            start = stop
    return [c for c in out if c is not None]


@dataclass
class WindowVerdict:
    """The verdict of one window of one machine.

    Attributes
    ----------
    machine : str
    start_s, end_s : float
        Time of the window's first sample and just after its last, s (recording time base).
    verdict : Verdict
    scores : ndarray, shape (n_rows, n_states), or None
        The window's ``kl`` scores (None for a window cut short by a break): relative entropies
        per sensor, nats (entropy method), or relation scores per relation (parity method).
    """

    machine: str
    start_s: float
    end_s: float
    verdict: Verdict
    scores: np.ndarray | None = None


@dataclass
class _Stream:
    states: list[StreamState]
    window: MachineWindow | RawWindow
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


@dataclass
class _Feed:
    t: np.ndarray
    x: np.ndarray  # (n, 1 + n_sensors): voltage then sensors


@dataclass
class _Break:
    reason: str
    t: float


@dataclass
class _Plan:
    ops: list[_Feed | _Break] = field(default_factory=list)


class OnlineScorer:
    """Streaming verdicts for many machines from one model bundle.

    Parameters
    ----------
    bundle : ModelBundle
        Either method's bundle.
    keep : int, default 4
        Closed windows each machine keeps (entropy method; only the unreported ones are read).
    """

    def __init__(self, bundle: ModelBundle, *, keep: int = 4) -> None:
        self.bundle = bundle
        self.keep = keep
        self._streams: dict[str, _Stream] = {}
        self._engine = engine_for(bundle, keep=keep)
        self._columns = self._engine.columns
        self.samples = 0
        """Samples fed so far, over every machine."""

    @property
    def columns(self) -> list[str]:
        """Channels the bundle's method reads from every chunk."""
        return list(self._columns)

    @property
    def machines(self) -> list[str]:
        """Machines seen so far."""
        return list(self._streams)

    def _new_stream(self) -> _Stream:
        return _Stream(self._engine.new_states(), self._engine.new_window())

    def _plan(self, stream: _Stream, chunk: Chunk) -> _Plan:
        """Cut a chunk into clean segments and the breaks between them."""
        t = np.asarray(chunk.t, dtype=np.float64)
        x = np.empty((t.size, len(self._columns)))
        for j, c in enumerate(self._columns):
            column = chunk.channels.get(c)
            x[:, j] = self._engine.defaults[c] if column is None and c in self._engine.defaults else column
        plan = _Plan()
        if t.size == 0:
            return plan
        if stream.next_t is not None:
            lag = t[0] - stream.next_t
            if lag < -TOLERANCE:
                plan.ops.append(_Break(f"late or out-of-order chunk: t={t[0]:.3f} s arrived after "
                                       f"t={stream.next_t - DT:.3f} s", float(stream.next_t)))
                return plan  # the chunk is dropped: its samples belong to the past
            if lag > TOLERANCE:
                plan.ops.append(_Break(f"gap of {lag:.3f} s before t={t[0]:.3f} s", float(stream.next_t)))
        bad = ~np.all(np.isfinite(x), axis=1) | ~np.isfinite(t)
        jumps = np.flatnonzero(np.abs(np.diff(t) - DT) > TOLERANCE) + 1
        start = 0
        for i in sorted({*np.flatnonzero(bad).tolist(), *jumps.tolist()}):
            if i > start:
                plan.ops.append(_Feed(t[start:i], x[start:i]))
            if bad[i]:
                names = [c for c, v in zip(self._columns, x[i]) if not np.isfinite(v)] or ["t"]
                plan.ops.append(_Break(f"NaN in {', '.join(names)} at t={t[i]:.3f} s", float(t[i])))
                start = i + 1
            elif i >= start:
                plan.ops.append(_Break(f"irregular sample spacing before t={t[i]:.3f} s", float(t[i])))
                start = i
        if start < t.size:
            plan.ops.append(_Feed(t[start:], x[start:]))
        stream.next_t = float(t[-1] + DT) if np.isfinite(t[-1]) else stream.next_t
        return plan

    def _plans(self, chunks: Sequence[Chunk]) -> dict[str, list[_Feed | _Break]]:
        """Every machine's segments and breaks; clean chunks are checked together (one array per length).

        A chunk is clean when it is its machine's only chunk in the update, has every column,
        only finite values, regular spacing and follows the previous chunk: it becomes one segment
        without going through :meth:`_plan` (the per-chunk Python cost is what limits the fleet size).
        """
        plans: dict[str, list[_Feed | _Break]] = {}
        count: dict[str, int] = {}
        for chunk in chunks:
            count[chunk.machine] = count.get(chunk.machine, 0) + 1
            if chunk.machine not in self._streams:
                self._streams[chunk.machine] = self._new_stream()
        groups: dict[int, list[Chunk]] = {}
        for chunk in chunks:
            if count[chunk.machine] == 1 and all(c in chunk.channels for c in self._columns):
                groups.setdefault(len(chunk.t), []).append(chunk)
        fast: dict[str, _Feed] = {}
        for n, group in groups.items():
            if n < 2:
                continue
            t = np.asarray(np.stack([c.t for c in group]), dtype=np.float64)  # (M, n)
            x = np.stack([np.stack([c.channels[k] for c in group]) for k in self._columns], axis=2)  # (M, n, width)
            expected = np.array([np.nan if (nt := self._streams[c.machine].next_t) is None else nt for c in group])
            clean = (np.isfinite(x).all(axis=(1, 2)) & np.isfinite(t).all(axis=1)
                     & (np.abs(np.diff(t, axis=1) - DT) <= TOLERANCE).all(axis=1)
                     & (np.isnan(expected) | (np.abs(t[:, 0] - expected) <= TOLERANCE)))
            for i in np.flatnonzero(clean).tolist():
                fast[group[i].machine] = _Feed(t[i], x[i])
                self._streams[group[i].machine].next_t = float(t[i, -1] + DT)
        for chunk in chunks:
            feed = fast.get(chunk.machine)
            if feed is not None:
                plans[chunk.machine] = [feed]
            else:
                plans.setdefault(chunk.machine, []).extend(self._plan(self._streams[chunk.machine], chunk).ops)
        return plans

    def _break(self, machine: str, stream: _Stream, op: _Break) -> tuple[_Stream, WindowVerdict | None]:
        """Restart the stream; the window in progress becomes an invalid verdict."""
        out = None
        if stream.seen:
            begun = stream.window.n_windows * self._engine.hop
            if stream.fed_t is not None and stream.fed > begun:
                start = stream.fed_t + begun * DT
            elif stream.fed_t is None and stream.start_t is not None:
                start = stream.start_t
            else:
                start = None
            if start is not None:
                out = WindowVerdict(machine, float(start), float(op.t), Verdict(INVALID, None, {}, op.reason))
        fresh = self._new_stream()
        fresh.next_t = stream.next_t
        return fresh, out

    def _feed(self, jobs: list[tuple[str, _Stream, _Feed]]) -> None:
        """Predict one segment per machine, batched by segment length, and feed the windows."""
        by_length: dict[int, list[tuple[str, _Stream, _Feed]]] = {}
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
                self.samples += e.shape[0]

    def update(self, chunks: Sequence[Chunk]) -> list[WindowVerdict]:
        """Feed chunks of any machines (in arrival order); returns the verdicts of the windows they close."""
        plans = self._plans(chunks)
        out: list[WindowVerdict] = []
        closed: list[tuple[str, Any, float]] = []
        while plans:
            jobs = []
            for machine in list(plans):
                ops = plans[machine]
                while ops and isinstance(ops[0], _Break):
                    self._collect(machine, closed)
                    brk = ops.pop(0)
                    assert isinstance(brk, _Break)
                    self._streams[machine], invalid = self._break(machine, self._streams[machine], brk)
                    if invalid is not None:
                        out.append(invalid)
                if ops:
                    feed = ops.pop(0)
                    assert isinstance(feed, _Feed)
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
            closed.extend((machine, r, stream.fed_t) for r in self._engine.collect(cast(Any, stream.window),
                                                                                  stream.reported))
            stream.reported = stream.window.n_windows

    def _judge(self, closed: list[tuple[str, Any, float]]) -> list[WindowVerdict]:
        if not closed:
            return []
        judged = self._engine.judge([r for _, r, _ in closed])
        return [WindowVerdict(m, t0 + r.start * DT, t0 + r.stop * DT, v, scores)
                for (m, r, t0), (v, scores) in zip(closed, judged)]
