"""The online fleet driver of every health method: one array row per machine, windows judged as they close.

:class:`WindowFleet` is what :class:`~hydrowatch.training.online.OnlineScorer` runs for the bundle's
method, whose streaming part is a :class:`~hydrowatch.methods.base.WindowJudge` (parity, stats: raw
windows) or a :class:`~hydrowatch.methods.base.StreamEngine` (entropy: every clean segment is first
turned into values, the reference models' prediction errors, batched over machines with each
machine's state; the windows start where the values are finite, after the warm-up). Per machine it
keeps a row of one fleet-wide array (the window in progress, ``window × width`` floats) and a few
counters in fleet-wide vectors, so an update of 1000 machines' clean chunks is a handful of NumPy
operations, not 1000 Python objects:

1. the chunks (a :class:`~hydrowatch.training.chunks.ChunkBatch`) are checked all at once: a
   machine's only chunk in the update, every column present (or defaulted), finite, regular and
   following its previous chunk is *clean* (:func:`~hydrowatch.training.chunks.clean_chunks`, the
   rule every method's stream uses) and written with one scatter per chunk length;
2. anything else (a gap, NaN, a late chunk, several chunks of one machine) goes through
   :func:`~hydrowatch.training.chunks.plan_chunk` machine by machine, as before: a break makes the
   window in progress ``invalid`` with its reason and restarts the machine's window; a chunk without
   a channel the method reads (a machine without a sensor the model was trained on) is such a break,
   its reason naming the channel;
3. windows that close are copied out and handed to the method's judge in batches of at most
   ``batch`` windows (the parity judge pools a machine's recent windows when asked,
   :mod:`hydrowatch.methods.parity.online`).

With ``stagger`` each machine's windows start at a phase of its own after its stream (re)starts,
so a fleet started in one instant does not close every window in the same update (not for a
stream engine whose ``staggers`` is False: the entropy method's windows start after its warm-up).
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.methods.base import ExpectsSensors, StreamEngine, WindowJudge
from hydrowatch.training.chunks import (
    DT,
    Break,
    Chunk,
    ChunkBatch,
    WindowVerdict,
    clean_chunks,
    cut_short,
    optional_columns,
    plan_chunk,
)
from hydrowatch.verdict import INVALID, Verdict


@dataclass
class _Closed:
    slot: int
    start: int
    """First sample of the window, counted from the stream's (re)start."""
    t0: float
    """Time of the stream's first sample, s."""
    samples: np.ndarray


class WindowFleet:
    """Raw windows of many machines, handed to a method's judge as they close (module docstring).

    Parameters
    ----------
    judge : WindowJudge or StreamEngine
        The method's streaming part: its columns, defaults, window, hop and ``judge`` (and, for a stream
        engine, ``width``, ``new_states`` and ``values``).
    batch : int, default 64
        Most windows judged in one call.
    stagger : bool, default False
        Start each machine's windows ``phase`` samples after its stream (re)starts, ``phase`` in
        [0, hop) fixed by the machine's name (CRC-32): machines started in the same instant then
        close their windows spread over the hop instead of all in one update (the judging work of
        the whole fleet at once), at the price of up to one hop of samples unjudged after each
        (re)start. False: windows start at the stream's first sample (as batch scoring does).
    expected : bool, default False
        Also ask a judge that predicts the sensors (:class:`~hydrowatch.methods.base.ExpectsSensors`) what it
        expected of each window it judged (``WindowVerdict.expected``; the scorer's ``…/expected`` messages).
    """

    def __init__(self, judge: WindowJudge, *, batch: int = 64, stagger: bool = False, expected: bool = False) -> None:
        if int(batch) != batch or batch < 1:
            raise ParameterError(f"batch must be an integer >= 1. Got {batch!r}; 64 is the default.")
        self.expects = judge if expected and isinstance(judge, ExpectsSensors) else None
        if self.expects is not None:
            self.expects.expect()  # before the width is read: a stream engine's grows
        self.judge, self.columns, self.defaults = judge, list(judge.columns), dict(judge.defaults)
        self.window, self.hop = judge.window, judge.hop
        self.engine = judge if isinstance(judge, StreamEngine) else None
        self.batch = int(batch)
        self.stagger = bool(stagger) and (self.engine is None or bool(self.engine.staggers))
        width = len(self.columns) if self.engine is None else int(self.engine.width)
        self._slot: dict[str, int] = {}
        self._names: list[str] = []
        self._states: list[Any] = []
        """Each machine's stream-engine state (empty without an engine)."""
        self._buffer = np.empty((0, self.window, width))
        self._fill = np.zeros(0, dtype=np.int64)
        """Samples in each machine's window in progress."""
        self._skip = np.zeros(0, dtype=np.int64)
        """Samples to pass over before the next window starts (hop > window, or the phase after a (re)start)."""
        self._phase = np.zeros(0, dtype=np.int64)
        """Samples before each machine's first window after a (re)start (``stagger``)."""
        self._fed = np.zeros(0, dtype=np.int64)
        """Samples fed since the machine's stream (re)started."""
        self._count = np.zeros(0, dtype=np.int64)
        """Windows closed since the machine's stream (re)started."""
        self._t0 = np.zeros(0)
        """Time of the first sample since the stream (re)started, s (NaN: none yet)."""
        self._next_t = np.zeros(0)
        """When each machine's next sample is expected, s (NaN: anything goes)."""
        self._seen = np.zeros(0, dtype=np.int64)
        """Samples received since the stream (re)started, the warm-up included."""
        self._start_t = np.zeros(0)
        """Time of the first sample received since the stream (re)started, s (NaN: none yet)."""
        self.samples = 0
        """Samples fed so far, over every machine."""
        self._lacking: dict[int, str] = {}
        """Machines whose last chunk lacked a channel the method reads → the reason said (said once)."""

    @property
    def machines(self) -> list[str]:
        """Machines seen so far."""
        return list(self._names)

    # -- machines -----------------------------------------------------------------------------------
    def _slots(self, machines: Sequence[str]) -> np.ndarray:
        """Each machine's row (new machines get one; the arrays grow by doubling)."""
        slot = self._slot
        missing = set(machines).difference(slot)
        for m in machines if missing else ():
            if m in missing and m not in slot:
                slot[m] = len(self._names)
                self._names.append(m)
                if self.engine is not None:
                    self._states.append(self.engine.new_states())
        n = len(self._names)
        if n > self._fill.size:
            cap = n if self._fill.size == 0 else max(n, 2 * self._fill.size)
            grow = cap - self._fill.size
            self._buffer = np.concatenate([self._buffer, np.empty((grow, *self._buffer.shape[1:]))])
            self._fill, self._skip, self._fed, self._count, self._phase, self._seen = (
                np.concatenate([a, np.zeros(grow, dtype=np.int64)])
                for a in (self._fill, self._skip, self._fed, self._count, self._phase, self._seen))
            self._t0, self._next_t, self._start_t = (np.concatenate([a, np.full(grow, np.nan)])
                                                     for a in (self._t0, self._next_t, self._start_t))
        if missing and self.stagger:
            for s in range(n - len(missing), n):
                self._phase[s] = self._skip[s] = zlib.crc32(self._names[s].encode()) % self.hop
        return np.fromiter(map(slot.__getitem__, machines), dtype=np.int64, count=len(machines))

    def _restart(self, slot: int) -> None:
        self._fill[slot] = self._fed[slot] = self._count[slot] = self._seen[slot] = 0
        self._skip[slot] = self._phase[slot]
        self._t0[slot] = self._start_t[slot] = np.nan
        if self.engine is not None:
            self._states[slot] = self.engine.new_states()

    # -- feeding ------------------------------------------------------------------------------------
    def _feed(self, slots: np.ndarray, t: np.ndarray, x: np.ndarray, closed: list[_Closed]) -> None:
        """Feed clean samples t (m, n), x (m, n, n_columns) of m distinct machines: as they are, or through the
        stream engine's values, each machine's window starting at its first finite value after a (re)start."""
        self._seen[slots] += t.shape[1]
        first = np.isnan(self._start_t[slots])
        self._start_t[slots[first]] = t[first, 0]
        if self.engine is None:
            self._write(slots, t, x, closed)
            return
        values = self.engine.values(x, [self._states[s] for s in slots.tolist()])
        warming = self._fed[slots] == 0
        if not warming.any():
            self._write(slots, t, values, closed)
            return
        self._next_t[slots] = t[:, -1] + DT
        if not warming.all():
            self._write(slots[~warming], t[~warming], values[~warming], closed)
        for i in np.flatnonzero(warming).tolist():
            ready = np.flatnonzero(np.all(np.isfinite(values[i]), axis=1))
            if ready.size:
                r = int(ready[0])
                self._write(slots[i:i + 1], t[i:i + 1, r:], values[i:i + 1, r:], closed)

    def _write(self, slots: np.ndarray, t: np.ndarray, x: np.ndarray, closed: list[_Closed]) -> None:
        """Write samples t (m, n), x (m, n, width) of m distinct machines; closed windows go to ``closed``."""
        m, n = t.shape
        fresh = self._fed[slots] == 0
        self._t0[slots[fresh]] = t[fresh, 0]
        self._fed[slots] += n
        self._next_t[slots] = t[:, -1] + DT
        self.samples += m * n
        k = np.arange(n)
        done = np.zeros(m, dtype=np.int64)
        while True:
            rest = n - done
            skip = np.minimum(self._skip[slots], rest)
            self._skip[slots] -= skip
            done += skip
            rest -= skip
            if not rest.any():
                return
            fill = self._fill[slots]
            take = np.minimum(rest, self.window - fill)
            if not done.any() and np.all(take == n):  # the common case: every chunk fits its window whole
                self._buffer[slots[:, None], fill[:, None] + k] = x
            else:
                rows, cols = np.nonzero(k < take[:, None])
                self._buffer[slots[rows], fill[rows] + cols] = x[rows, done[rows] + cols]
            self._fill[slots] = fill + take
            done += take
            full = np.flatnonzero(self._fill[slots] == self.window)
            if full.size:
                self._close(slots[full], closed)

    def _close(self, slots: np.ndarray, closed: list[_Closed]) -> None:
        """Copy out the full windows of ``slots``; start their next ones (overlap kept, or hop − window skipped)."""
        samples = self._buffer[slots]  # a copy (fancy indexing)
        keep = max(0, self.window - self.hop)
        if keep:
            self._buffer[slots, :keep] = samples[:, self.window - keep:]
        for i, s in enumerate(slots.tolist()):
            closed.append(_Closed(s, int(self._phase[s] + self._count[s] * self.hop), float(self._t0[s]), samples[i]))
        self._count[slots] += 1
        self._fill[slots] = keep
        self._skip[slots] = max(0, self.hop - self.window)

    def _clean(self, batch: ChunkBatch, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Chunk indices that are clean (:func:`~hydrowatch.training.chunks.clean_chunks`) and the rest, in order."""
        once = np.bincount(slots, minlength=len(self._names))[slots] == 1
        ok = clean_chunks(batch, self.columns, self._next_t[slots], once, self.defaults)
        return np.flatnonzero(ok), np.flatnonzero(~ok)

    def _matrix(self, batch: ChunkBatch, rows: np.ndarray) -> np.ndarray:
        """Columns of the samples ``rows`` side by side, (len(rows), n_columns), defaults filled in."""
        x = np.empty((rows.size, len(self.columns)))
        chunk_of = np.searchsorted(batch.offsets, rows, side="right") - 1
        for j, c in enumerate(self.columns):
            x[:, j] = batch.channels[c][rows]
            if c in self.defaults:
                x[batch.absent[c][chunk_of], j] = self.defaults[c]
        return x

    def update(self, chunks: Sequence[Chunk]) -> list[WindowVerdict]:
        """Feed chunks of any machines (in arrival order); returns the verdicts (``WindowVerdict``) of the windows
        they close and of the windows their breaks cut short."""
        batch = ChunkBatch.from_chunks(chunks, self.columns)
        if not len(batch):
            return []
        slots = self._slots(batch.machines)
        clean, rest = self._clean(batch, slots)
        closed: list[_Closed] = []
        out: list[WindowVerdict] = []
        lengths = np.diff(batch.offsets)
        for n in np.unique(lengths[clean]).tolist():
            group = clean[lengths[clean] == n]
            rows = (batch.offsets[group][:, None] + np.arange(n)).reshape(-1)
            self._feed(slots[group], batch.t[rows].reshape(-1, n),
                       self._matrix(batch, rows).reshape(group.size, n, -1), closed)
        for i in rest.tolist():
            self._plan(batch, int(i), int(slots[i]), closed, out)
        return out + self._judge(closed)

    def _plan(self, batch: ChunkBatch, i: int, slot: int, closed: list[_Closed], out: list[WindowVerdict]) -> None:
        """One chunk that is not clean, through :func:`plan_chunk`: segments are fed, breaks restart the window.

        A chunk without a channel the method reads (and has no default for) is one break, dropped whole: the
        window in progress is ``invalid`` with a reason naming the channel, or, when none is in progress, the
        chunk itself, once until the machine sends the channel again."""
        a, b = int(batch.offsets[i]), int(batch.offsets[i + 1])
        t = batch.t[a:b]
        expected = self._next_t[slot]
        lacking = [c for c in self.columns if c not in self.defaults and batch.absent[c][i]]
        if lacking and t.size:
            self._lacks(slot, t, lacking, out)
            return
        self._lacking.pop(slot, None)
        ops, next_t = plan_chunk(t, self._matrix(batch, np.arange(a, b)), self.columns,
                                 None if np.isnan(expected) else float(expected), optional_columns(self.defaults))
        for op in ops:
            if isinstance(op, Break):
                self._break(slot, op, out)
            else:
                one = np.array([slot])
                if op.t.size:
                    self._feed(one, op.t[None], op.x[None], closed)
        self._next_t[slot] = np.nan if next_t is None else next_t

    def _break(self, slot: int, brk: Break, out: list[WindowVerdict]) -> None:
        """The window in progress cut short by ``brk`` (``invalid``, when a sample of it came), the stream restarted."""
        if self._fed[slot]:  # the window in progress began at its place after the (re)start
            begun = int(self._phase[slot] + self._count[slot] * self.hop)
            invalid = cut_short(self._names[slot], begun, int(self._fed[slot]), float(self._t0[slot]), brk)
        else:  # still warming up: the window would have begun with the stream
            invalid = cut_short(self._names[slot], 0, int(self._seen[slot]), float(self._start_t[slot]), brk)
        if invalid is not None:
            out.append(invalid)
        self._restart(slot)

    def _lacks(self, slot: int, t: np.ndarray, lacking: list[str], out: list[WindowVerdict]) -> None:
        """A chunk without the channels ``lacking``: a break naming them (:meth:`_plan`)."""
        reads = [c for c in self.columns if c not in self.defaults]
        reason = f"no {', '.join(repr(c) for c in lacking)} in the chunk: the model reads {reads} (trained on them)"
        said = len(out)
        if self._fed[slot] or self._seen[slot]:
            self._break(slot, Break(reason, float(t[0])), out)
        if len(out) == said and self._lacking.get(slot) != reason:  # no window cut short: say it once, on the chunk
            out.append(WindowVerdict(self._names[slot], float(t[0]), float(t[-1] + DT),
                                     Verdict(INVALID, None, {}, reason)))
        self._lacking[slot] = reason
        self._next_t[slot] = np.nan

    # -- judging ------------------------------------------------------------------------------------
    def _judge(self, closed: list[_Closed]) -> list[WindowVerdict]:
        """Verdicts and ``kl`` scores of closed windows, ``batch`` windows per call, in closing order."""
        out = []
        for lo in range(0, len(closed), self.batch):
            part = closed[lo:lo + self.batch]
            raw, names = np.stack([c.samples for c in part]), [self._names[c.slot] for c in part]
            judged = self.judge.judge(raw, names)
            expected = self.expects.expected(raw, names) if self.expects is not None else [None] * len(part)
            for c, item, seen in zip(part, judged, expected):  # a judge may add each window's degradation index
                out.append(WindowVerdict(self._names[c.slot], c.t0 + c.start * DT, c.t0 + (c.start + self.window) * DT,
                                         item[0], item[1], item[2] if len(item) > 2 else None, seen))
        return out
