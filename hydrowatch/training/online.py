"""Online scoring of a fleet, chunk by chunk (river style: ``update`` feeds, nothing is re-read).

Per machine the scorer keeps the reference models' stream states (delay lines or filter states,
:class:`~hydrowatch.training.reference.StreamState`) and a :class:`~hydrowatch.health.streaming.MachineWindow`
of prediction errors; when a window closes its relative entropies go to the classifier and the
open-set rule. All machines' chunks of equal length are predicted in one batched call per sensor,
and all windows that close in one :meth:`OnlineScorer.update` are judged in one call.

A stream breaks, and the window in progress is published as ``invalid`` with its reason instead of
producing a wrong verdict, when a chunk

* leaves a gap (its first sample is later than one sample after the previous chunk's last),
* arrives late or out of order (its first sample is not after the previous chunk's last),
* has NaN in the voltage or a sensor (the NaN samples are skipped),
* is irregular inside (sample spacing off 1/200 s).

After a break the stream restarts: the reference models warm up again (``bundle.warmup`` samples)
and windows are counted from the first sample after the warm-up.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from hydrowatch.health.streaming import MachineWindow, WindowResult
from hydrowatch.health.verdict import INVALID, Verdict, judge
from hydrowatch.recording import INPUT, SAMPLE_RATE_HZ
from hydrowatch.training.bundle import ModelBundle
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
        At least ``voltage`` [V] and the bundle's sensors.
    """

    machine: str
    t: np.ndarray
    channels: Mapping[str, np.ndarray]


@dataclass
class WindowVerdict:
    """The verdict of one window of one machine.

    Attributes
    ----------
    machine : str
    start_s, end_s : float
        Time of the window's first sample and just after its last, s (recording time base).
    verdict : Verdict
    entropies : ndarray, shape (n_sensors, n_states), or None
        Relative entropies, nats (None for a window cut short by a break).
    """

    machine: str
    start_s: float
    end_s: float
    verdict: Verdict
    entropies: np.ndarray | None = None


@dataclass
class _Stream:
    states: list[StreamState]
    window: MachineWindow
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
        Reference models and health model.
    keep : int, default 4
        Closed windows each machine keeps (only the unreported ones are read).
    """

    def __init__(self, bundle: ModelBundle, *, keep: int = 4) -> None:
        self.bundle = bundle
        self.keep = keep
        self._streams: dict[str, _Stream] = {}
        self._columns = [INPUT, *bundle.sensors]
        self.samples = 0
        """Samples fed so far, over every machine."""

    @property
    def machines(self) -> list[str]:
        """Machines seen so far."""
        return list(self._streams)

    def _new_stream(self) -> _Stream:
        refs = self.bundle.references.values()
        return _Stream([r.initial_state() for r in refs], MachineWindow(self.bundle.health.features_, keep=self.keep))

    def _plan(self, stream: _Stream, chunk: Chunk) -> _Plan:
        """Cut a chunk into clean segments and the breaks between them."""
        t = np.asarray(chunk.t, dtype=np.float64)
        x = np.column_stack([np.asarray(chunk.channels[c], dtype=np.float64) for c in self._columns])
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

    def _break(self, machine: str, stream: _Stream, op: _Break) -> tuple[_Stream, WindowVerdict | None]:
        """Restart the stream; the window in progress becomes an invalid verdict."""
        out = None
        if stream.seen:
            begun = stream.window.n_windows * int(self.bundle.health.features_.hop)
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
        refs = list(self.bundle.references.values())
        for group in by_length.values():
            u = np.stack([f.x[:, 0] for _, _, f in group])
            errors = []
            for j, ref in enumerate(refs):
                y = np.stack([f.x[:, 1 + j] for _, _, f in group])
                e, new = ref.step(u, y, [s.states[j] for _, s, _ in group])
                for (_, s, _), state in zip(group, new):
                    s.states[j] = state
                errors.append(e)
            stacked = np.stack(errors, axis=2)  # (M, n, n_sensors)
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
        plans: dict[str, list[_Feed | _Break]] = {}
        for chunk in chunks:
            stream = self._streams.get(chunk.machine)
            if stream is None:
                stream = self._streams[chunk.machine] = self._new_stream()
            plans.setdefault(chunk.machine, []).extend(self._plan(stream, chunk).ops)
        out: list[WindowVerdict] = []
        closed: list[tuple[str, WindowResult, float]] = []
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

    def _collect(self, machine: str, closed: list[tuple[str, WindowResult, float]]) -> None:
        stream = self._streams[machine]
        if stream.window.n_windows > stream.reported and stream.fed_t is not None:
            closed.extend((machine, r, stream.fed_t) for r in stream.window.since(stream.reported))
            stream.reported = stream.window.n_windows

    def _judge(self, closed: list[tuple[str, WindowResult, float]]) -> list[WindowVerdict]:
        if not closed:
            return []
        health = self.bundle.health
        features = np.stack([r.features for _, r, _ in closed])
        verdicts = judge(features, health.classifier_, health.open_set_, [r.reason for _, r, _ in closed])
        return [WindowVerdict(m, t0 + r.start * DT, t0 + r.stop * DT, v, r.entropies)
                for (m, r, t0), v in zip(closed, verdicts)]
