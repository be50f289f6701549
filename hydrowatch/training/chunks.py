"""Chunks of sensor samples as the scorer receives them, and how a machine's stream is cut into clean segments.

:func:`chunks_from_batches` turns the ``sensor_chunk`` record batches of one scorer tick into a
:class:`ChunkBatch` (flat arrays, one Arrow → NumPy conversion per column); :func:`plan_chunk`
cuts one machine's chunk into :class:`Segment` s and the :class:`Break` s between them (a gap, a
late or out-of-order chunk, NaN, irregular spacing), which make the window in progress ``invalid``
(:func:`cut_short`). :func:`clean_chunks` finds, for a whole update at once, the chunks that need no
cutting. :class:`WindowVerdict` is what the scorer makes of a window. These rules are the same for
every health method: both online engines call these functions.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from hydrowatch.expected import ExpectedWindow
from hydrowatch.recording import SAMPLE_RATE_HZ
from hydrowatch.verdict import INVALID, Verdict

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
        bundle uses it; unknown, NaN, when missing: condition/oil.py).
    """

    machine: str
    t: np.ndarray
    channels: Mapping[str, np.ndarray]


class ChunkBatch(Sequence[Chunk]):
    """Chunks of many machines held as flat arrays (what :func:`chunks_from_batches` returns).

    Indexing gives :class:`Chunk` views; the parity scorer reads the flat arrays directly.

    Attributes
    ----------
    machines : list of str, length m
    offsets : ndarray of int, shape (m + 1,)
        Chunk i holds samples ``offsets[i]:offsets[i + 1]``.
    t : ndarray, shape (n,)
        Sample times of every chunk, one after another, s.
    channels : dict of str to ndarray, shape (n,)
        The columns read (NaN where a batch lacks the column: see ``absent``).
    absent : dict of str to ndarray of bool, shape (m,)
        For each column, the chunks that lack it.
    """

    def __init__(self, machines: list[str], offsets: np.ndarray, t: np.ndarray, channels: dict[str, np.ndarray],
                 absent: dict[str, np.ndarray]) -> None:
        self.machines, self.offsets, self.t, self.channels, self.absent = machines, offsets, t, channels, absent

    def __len__(self) -> int:
        return len(self.machines)

    def __iter__(self) -> Iterator[Chunk]:
        return (self[i] for i in range(len(self)))

    def __getitem__(self, i: Any) -> Any:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        if not -len(self) <= i < len(self):
            raise IndexError(f"chunk index must be in [-{len(self)}, {len(self)}). Got {i}.")
        i = i % len(self)
        a, b = int(self.offsets[i]), int(self.offsets[i + 1])
        return Chunk(self.machines[i], self.t[a:b], {c: x[a:b] for c, x in self.channels.items()
                                                      if not self.absent[c][i]})

    @classmethod
    def from_chunks(cls, chunks: Sequence[Chunk], columns: Sequence[str]) -> ChunkBatch:
        """The flat form of any chunks (one concatenation per column)."""
        if isinstance(chunks, ChunkBatch):
            return chunks
        lengths = [len(c.t) for c in chunks]
        offsets = np.concatenate([[0], np.cumsum(lengths, dtype=np.int64)]).astype(np.int64)
        nan = [np.full(n, np.nan) for n in lengths]
        t = np.concatenate([np.asarray(c.t, dtype=np.float64) for c in chunks]) if chunks else np.empty(0)
        channels = {k: np.concatenate([np.asarray(c.channels.get(k, v), dtype=np.float64) for c, v in zip(chunks, nan)])
                    if chunks else np.empty(0) for k in columns}
        absent = {k: np.array([k not in c.channels for c in chunks], dtype=bool) for k in columns}
        return cls([c.machine for c in chunks], offsets, t, channels, absent)


def chunks_from_batches(machines: Sequence[str], batches: Sequence[pa.RecordBatch],
                        columns: Sequence[str]) -> ChunkBatch:
    """The chunks of ``sensor_chunk`` batches with only ``columns`` read (float64; nulls become NaN).

    Batches with the same schema (nearly always all of them) are converted together: one table of
    all of them and one Arrow → NumPy conversion per column (16× cheaper than concatenating the
    arrays batch by batch at 1000 chunks). Batches of other schemas are converted per schema and
    the result concatenated in arrival order. Columns a batch lacks are marked ``absent`` (the
    scorer then uses its default or breaks the stream); the label column is never read.
    """
    if not batches:
        return ChunkBatch([], np.zeros(1, dtype=np.int64), np.empty(0), {c: np.empty(0) for c in columns},
                          {c: np.zeros(0, dtype=bool) for c in columns})
    schema = batches[0].schema
    if any(b.schema != schema for b in batches[1:]):
        groups: dict[pa.Schema, list[int]] = {}
        for i, batch in enumerate(batches):
            groups.setdefault(batch.schema, []).append(i)
        out: list[Chunk | None] = [None] * len(batches)
        for members in groups.values():
            part = chunks_from_batches([machines[i] for i in members], [batches[i] for i in members], columns)
            for i, chunk in zip(members, part):
                out[i] = chunk
        return ChunkBatch.from_chunks([c for c in out if c is not None], columns)
    table = pa.Table.from_batches(list(batches))
    n = table.num_rows
    offsets = np.zeros(len(batches) + 1, dtype=np.int64)
    np.cumsum([b.num_rows for b in batches], out=offsets[1:])
    have = set(schema.names)
    channels = {c: table.column(c).to_numpy().astype(np.float64, copy=False) if c in have else np.full(n, np.nan)
                for c in columns}
    absent = {c: np.full(len(batches), c not in have) for c in columns}
    return ChunkBatch(list(machines), offsets, table.column("t").to_numpy().astype(np.float64, copy=False),
                      channels, absent)


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
    degradation : dict or None
        Degradation index per part, ``{fault: {"value", "ci95": [lo, hi], "measured"}}`` (parity method, valid
        windows; :meth:`hydrowatch.condition.degradation.Degradation.window`; ``measured`` False where a valve-side
        look-alike was blamed; a part blamed before the pool told it apart appears as ``{"value", "measured": False,
        "provisional": True}``, for the forecast's history only: the health message leaves it out), None otherwise.
    expected : dict or None
        What the model expected each sensor to read, beside what it read (:class:`hydrowatch.expected.ExpectedSensor`
        by sensor), when the driver was asked for it and the method predicts sensors; None otherwise.
    """

    machine: str
    start_s: float
    end_s: float
    verdict: Verdict
    scores: np.ndarray | None = None
    degradation: dict[str, dict[str, Any]] | None = None
    expected: ExpectedWindow | None = None


@dataclass
class Segment:
    """Clean samples of one machine: regular, finite, following the previous ones."""

    t: np.ndarray
    x: np.ndarray
    """Shape (n, n_columns): voltage then the sensors the method reads."""


@dataclass
class Break:
    """Where a machine's stream breaks (the window in progress becomes ``invalid``) and why."""

    reason: str
    t: float


def chunk_matrix(chunk: Chunk, columns: Sequence[str], defaults: Mapping[str, float]) -> np.ndarray:
    """The chunk's columns side by side, shape (n, n_columns); a missing column is its default, else NaN."""
    x = np.empty((len(chunk.t), len(columns)))
    for j, c in enumerate(columns):
        column = chunk.channels.get(c)
        x[:, j] = (defaults[c] if c in defaults else np.nan) if column is None else column
    return x


def optional_columns(defaults: Mapping[str, float]) -> set[str]:
    """Columns whose default is NaN: a NaN there means "not known" (the oil temperature), never a break."""
    return {c for c, v in defaults.items() if np.isnan(v)}


def plan_chunk(t: np.ndarray, x: np.ndarray, columns: Sequence[str],
               next_t: float | None, optional: Collection[str] = ()) -> tuple[list[Segment | Break], float | None]:
    """Cut one chunk (times ``t`` (n,), columns ``x`` (n, n_columns)) into clean segments and the breaks between them.

    ``next_t`` is when the machine's next sample is expected (None: anything goes). Returns the
    operations in time order and the new ``next_t``; a late chunk is dropped whole. NaN in an
    ``optional`` column (:func:`optional_columns`) is not a break.
    """
    t = np.asarray(t, dtype=np.float64)
    ops: list[Segment | Break] = []
    if t.size == 0:
        return ops, next_t
    if next_t is not None:
        lag = t[0] - next_t
        if lag < -TOLERANCE:
            ops.append(Break(f"late or out-of-order chunk: t={t[0]:.3f} s arrived after t={next_t - DT:.3f} s",
                             float(next_t)))
            return ops, next_t  # the chunk is dropped: its samples belong to the past
        if lag > TOLERANCE:
            ops.append(Break(f"gap of {lag:.3f} s before t={t[0]:.3f} s", float(next_t)))
    required = [j for j, c in enumerate(columns) if c not in optional]
    bad = ~np.all(np.isfinite(x[:, required]), axis=1) | ~np.isfinite(t)
    jumps = np.flatnonzero(np.abs(np.diff(t) - DT) > TOLERANCE) + 1
    start = 0
    for i in sorted({*np.flatnonzero(bad).tolist(), *jumps.tolist()}):
        if i > start:
            ops.append(Segment(t[start:i], x[start:i]))
        if bad[i]:
            names = [c for c, v in zip(columns, x[i]) if not np.isfinite(v) and c not in optional] or ["t"]
            ops.append(Break(f"NaN in {', '.join(names)} at t={t[i]:.3f} s", float(t[i])))
            start = i + 1
        elif i >= start:
            ops.append(Break(f"irregular sample spacing before t={t[i]:.3f} s", float(t[i])))
            start = i
    if start < t.size:
        ops.append(Segment(t[start:], x[start:]))
    return ops, float(t[-1] + DT) if np.isfinite(t[-1]) else next_t


def clean_chunks(batch: ChunkBatch, columns: Sequence[str], expected: np.ndarray, once: np.ndarray,
                 defaults: Mapping[str, float]) -> np.ndarray:
    """Which chunks of an update are clean: fed whole, without :func:`plan_chunk`.

    A chunk is clean when it is its machine's only chunk in the update (``once``), has at least
    2 samples, every column in ``columns`` (or a default for it), only finite times and values,
    regular spacing (1/200 s ± :data:`TOLERANCE`) and its first sample where its machine's next one
    is expected. Anything else goes through :func:`plan_chunk`, which finds the breaks.

    Parameters
    ----------
    batch : ChunkBatch
        The update's chunks, m of them.
    columns : sequence of str
        The columns the method reads.
    expected : ndarray, shape (m,)
        When each chunk's machine's next sample is expected, s (NaN: anything goes).
    once : ndarray of bool, shape (m,)
        Whether the chunk is its machine's only one in the update.
    defaults : mapping of str to float
        Columns a chunk may lack (their value is then the default).

    Returns
    -------
    ndarray of bool, shape (m,)
    """
    lengths = np.diff(batch.offsets)
    ok = np.asarray(once, dtype=bool) & (lengths >= 2)
    for c in columns:
        if c not in defaults:
            ok &= ~batch.absent[c]
    starts = batch.offsets[:-1]
    bad = ~np.isfinite(batch.t)
    optional = optional_columns(defaults)
    for c in columns:
        if c not in optional:
            bad |= ~np.isfinite(batch.channels[c]) & ~np.repeat(batch.absent[c], lengths)
    if bad.any():
        ok[np.unique(np.searchsorted(batch.offsets, np.flatnonzero(bad), side="right") - 1)] = False
    step = np.abs(np.diff(batch.t) - DT) > TOLERANCE
    joins = starts[1:]
    step[joins[(joins > 0) & (joins < batch.t.size)] - 1] = False  # from one chunk to the next is no spacing
    if step.any():
        ok[np.unique(np.searchsorted(batch.offsets, np.flatnonzero(step) + 1, side="right") - 1)] = False
    first = batch.t[np.minimum(starts, max(batch.t.size - 1, 0))] if batch.t.size else np.zeros(len(batch))
    return ok & (np.isnan(expected) | (np.abs(first - expected) <= TOLERANCE))


def cut_short(machine: str, begun: int, fed: int, t0: float, brk: Break) -> WindowVerdict | None:
    """The ``invalid`` verdict of the window in progress when ``brk`` breaks a machine's stream.

    Parameters
    ----------
    machine : str
    begun : int
        First sample of the window in progress, counted from ``t0``.
    fed : int
        Samples received since ``t0``.
    t0 : float
        Time of the stream's sample 0, s.
    brk : Break

    Returns
    -------
    WindowVerdict or None
        From ``t0 + begun·DT`` to the break, state ``invalid`` with the break's reason; None when
        no sample of that window has come yet (nothing was cut short).
    """
    if fed <= begun:
        return None
    return WindowVerdict(machine, t0 + begun * DT, float(brk.t), Verdict(INVALID, None, {}, brk.reason))
