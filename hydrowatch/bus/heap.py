"""Giving freed memory back to the operating system in long-running services.

A subscriber that falls behind for a moment holds its backlog in zenoh's FIFO (up to 100,000 messages of
~3.3 kB per key expression, :class:`~hydrowatch.bus.pubsub.Subscriber`). Those buffers are freed once the backlog
is read, but glibc's allocator keeps the freed pages in its arenas (zenoh's threads each allocate in their own), so
the process's resident memory stays at the backlog's high-water mark and climbs in steps with every larger one.
Measured (2026-11-27, ``benchmarks/bench_bus_backlog_memory.py``: two peer sessions on loopback in one process, a
backlog of 60,000 sensor chunks of 2.2 kB, then read to the end; beside two benchmark processes): RSS 128 → 275 MB
with the backlog, **still 276 MB once it was read, 146 MB after** ``malloc_trim(0)`` (17–25 ms); in three rounds the
trimmed RSS stayed at 146–147 MB. This is not what made the 1-hour soaks' scorers grow after their rings were full:
with the trimmer they still rose +6 and +15 MB/h (docs/bus.md, "Soak").

Arrow has an allocator of its own (pyarrow's default pool is mimalloc, or jemalloc), which ``malloc_trim`` does not
reach and which keeps what was freed for reuse by the thread that freed it: every message the services decode or
encode is an Arrow buffer, allocated on zenoh's threads and freed on others. Measured (2026-11-27): 150 MB of 64 kB
Arrow buffers freed stay resident (RSS 69 → 271 → **271** MB) until ``MemoryPool.release_unused()`` (83 MB); four
threads doing the same left 619 MB resident, 85 after the release. A scorer of 200 machines in real time (the scorer
service in one process, ``recordings/diag/mem_probe*.py``) grew outside glibc's heap with its arenas flat
(docs/bus.md, "Arrow's allocator").

:class:`HeapTrimmer` gives back both every :data:`TRIM_INTERVAL_S` from a daemon thread while a service runs
(:func:`hydrowatch.bus.service.run_service`), so its RSS follows what it holds: ``malloc_trim(0)`` where the C library
has it (not musl or macOS), and Arrow's ``release_unused()``. It first fixes glibc's mmap threshold
(:data:`MMAP_THRESHOLD_BYTES`), so that large blocks are mapped on their own and given back when freed instead of
widening the arenas.

**What a process holds** (:func:`heap_stats`): every :data:`STATS_INTERVAL_S` the trimmer logs one ``memory`` event
(INFO) that splits the resident set into what the allocators hold and what they keep: glibc's bytes in use and free
in its arenas (``mallinfo2``), its mmapped chunks, Arrow's allocated bytes, CPython's allocated blocks, and the
resident set's anonymous and shared parts (zenoh's shared-memory segments, mapped by every process on the host that
receives from them, count in each one's RSS). A resident set that grows while every holder is flat is an
allocator's kept memory or a shared segment, not a leak; one whose holder grows names it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import re
import sys
import threading
import time
from collections.abc import Callable
from types import TracebackType

from hydrowatch.log import event, get_logger

log = get_logger(__name__)

STATS_INTERVAL_S = 300.0
"""Seconds between two ``memory`` events."""

MEMORY_EVENT = "memory"
"""The message of the event that :class:`HeapTrimmer` logs with :func:`heap_stats`' figures."""

HOLDERS = ("rss_mb", "rss_anon_mb", "rss_shared_mb", "glibc_in_use_mb", "glibc_free_mb", "glibc_mmap_mb", "arrow_mb",
           "python_blocks")
"""The figures of :func:`heap_stats`, in the order a table shows them."""

TRIM_INTERVAL_S = 10.0
"""Seconds between two trims. One trim that gave back 130–230 MB took 17–25 ms. Between two trims a scorer's
allocations walk through the free space its arenas keep and make it resident again: in the sixth 1-hour soak
(2026-11-28, trims once a minute) a scorer's RSS fell 14–20 MB at a trim and was back within minutes, while glibc's
bytes in use stayed flat (+0.2 MB in 10 minutes). Every 10 s (the seventh soak) a trim took 0.8–1.0 ms (at most
1.9); what the scorers still gained was free space inside pages in use, which no trim returns (docs/bus.md)."""

MMAP_THRESHOLD_BYTES = 128 * 1024
"""Allocations at least this large get pages of their own (``mmap``), given back whole when freed: glibc's initial
threshold, made fixed (:func:`fix_mmap_threshold`). Left to itself glibc raises the threshold to the size of every
mapped block freed (up to 32 MiB), after which a scorer's batch arrays of that size are carved from its arenas, which
grow to the largest batch so far and leave holes between the small objects allocated meanwhile (the eighth soak's
scorers: glibc's bytes in use flat, the free space in its arenas rising in steps; docs/bus.md)."""

_ACTIVE = threading.Lock()
"""Held by the one trimmer running in this process (``hydrowatch up`` runs several services in one)."""


def _c_library() -> ctypes.CDLL | None:
    """The C library, loaded once (None where it cannot be found or loaded)."""
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name) if name else None
    except OSError:
        return None


_LIBC = _c_library()
_TRIM: Callable[[int], int] | None = getattr(_LIBC, "malloc_trim", None)

_M_MMAP_THRESHOLD = -3
"""mallopt's parameter number of the mmap threshold (malloc.h)."""


def fix_mmap_threshold(nbytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's mmap threshold at ``nbytes`` (:data:`MMAP_THRESHOLD_BYTES`): larger blocks are mapped on their own
    from now on, whatever was freed before. Process-wide. False where the C library has no ``mallopt`` or refuses."""
    mallopt = getattr(_LIBC, "mallopt", None)
    return bool(mallopt is not None and mallopt(_M_MMAP_THRESHOLD, int(nbytes)) == 1)


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                     "fsmblks", "uordblks", "fordblks", "keepcost")]


def _mallinfo2() -> Callable[[], _MallInfo2] | None:
    call = getattr(_LIBC, "mallinfo2", None)  # glibc >= 2.33
    if call is not None:
        call.restype = _MallInfo2
    return call


_MALLINFO2 = _mallinfo2()


def _proc_status_mb(fields: tuple[str, ...]) -> dict[str, float]:
    """Fields of /proc/self/status given in kB, as MB; {} where /proc is absent."""
    found: dict[str, float] = {}
    try:
        with open("/proc/self/status") as f:
            for line in f:
                name, _, value = line.partition(":")
                if name in fields:
                    found[name] = int(value.split()[0]) / 1024
    except (OSError, ValueError, IndexError):
        return {}
    return found


def heap_stats() -> dict[str, float]:
    """What this process holds and keeps, MB unless named otherwise (module docstring): ``rss_mb``, ``rss_anon_mb``,
    ``rss_shared_mb`` (shared memory and files mapped), ``glibc_in_use_mb``, ``glibc_free_mb`` (free in its arenas),
    ``glibc_mmap_mb`` (chunks mmapped on their own), ``arrow_mb`` (Arrow's default pool, allocated),
    ``python_blocks`` (CPython's allocated blocks, a count). A figure the platform cannot give is left out."""
    stats: dict[str, float] = {}
    status = _proc_status_mb(("VmRSS", "RssAnon", "RssFile", "RssShmem"))
    if status:
        stats["rss_mb"] = status.get("VmRSS", float("nan"))
        stats["rss_anon_mb"] = status.get("RssAnon", float("nan"))
        stats["rss_shared_mb"] = status.get("RssFile", 0.0) + status.get("RssShmem", 0.0)
    if _MALLINFO2 is not None:
        info = _MALLINFO2()
        stats.update(glibc_in_use_mb=info.uordblks / 2**20, glibc_free_mb=info.fordblks / 2**20,
                     glibc_mmap_mb=info.hblkhd / 2**20)
    arrow = sys.modules.get("pyarrow")
    if arrow is not None:
        stats["arrow_mb"] = arrow.total_allocated_bytes() / 2**20
    stats["python_blocks"] = float(sys.getallocatedblocks())
    return {name: round(value, 2) for name, value in stats.items()}


def resident_mb() -> float | None:
    """This process's resident set size, MB (None where /proc is absent)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:
        return None


def _release_arrow() -> None:
    """Give Arrow's allocator's unused memory back (module docstring); nothing where pyarrow is not loaded."""
    arrow = sys.modules.get("pyarrow")
    if arrow is not None:
        arrow.default_memory_pool().release_unused()


def trim_heap() -> float | None:
    """Give the allocators' free pages back to the operating system (glibc's and Arrow's); the MB the resident set
    fell by (None when /proc cannot say)."""
    before = resident_mb()
    if _TRIM is not None:
        _TRIM(0)
    _release_arrow()
    after = resident_mb()
    return None if before is None or after is None else before - after


class HeapTrimmer:
    """``with HeapTrimmer(stop):`` fixes glibc's mmap threshold (:func:`fix_mmap_threshold`), trims the heap every
    ``interval`` s (:func:`trim_heap`) until the block ends or ``stop`` is set, and logs a ``memory`` event
    (:func:`heap_stats`, with the trims' count and time since the last one) every ``stats_interval`` s. A second trimmer
    in the same process does nothing while the first runs.

    Attributes
    ----------
    trims : int
        Trims done.
    """

    def __init__(self, stop: threading.Event, interval: float = TRIM_INTERVAL_S,
                 stats_interval: float = STATS_INTERVAL_S) -> None:
        self.stop, self.interval, self.stats_interval = stop, float(interval), float(stats_interval)
        self.trims = 0
        self._done = threading.Event()
        self._thread: threading.Thread | None = None

    def _run(self) -> None:
        try:
            logged, took = time.monotonic(), []
            while not (self._done.wait(self.interval) or self.stop.is_set()):
                began = time.perf_counter()
                returned = trim_heap()
                took.append(time.perf_counter() - began)
                self.trims += 1
                if returned is not None and returned >= 1.0:
                    event(log, "heap trimmed", logging.DEBUG, returned_mb=round(returned, 1))
                if time.monotonic() - logged >= self.stats_interval:
                    event(log, MEMORY_EVENT, logging.INFO, **heap_stats(), trims=len(took),
                          trim_ms_mean=round(1e3 * sum(took) / len(took), 2), trim_ms_max=round(1e3 * max(took), 2))
                    logged, took = time.monotonic(), []
        finally:
            _ACTIVE.release()

    def __enter__(self) -> HeapTrimmer:
        if self.interval > 0 and _ACTIVE.acquire(blocking=False):
            fixed = fix_mmap_threshold()
            event(log, "allocator", logging.DEBUG, mmap_threshold_fixed=fixed, mmap_threshold=MMAP_THRESHOLD_BYTES)
            self._thread = threading.Thread(target=self._run, name="heap-trim", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self._done.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)


def memory_events(text: str) -> list[tuple[float, dict[str, float]]]:
    """The ``memory`` events in a service's log (hydrowatch.log's ``key=value`` lines, INFO): (Unix time of the line,
    s, read in local time as the log writes it; its figures). Other lines are skipped."""
    line_of = re.compile(rf"^(\S+) info {re.escape(log.name)} {MEMORY_EVENT} (.*)$")
    found = []
    for line in text.splitlines():
        if (match := line_of.match(line)) is not None:
            when = time.mktime(time.strptime(match.group(1), "%Y-%m-%dT%H:%M:%S"))
            found.append((when, {k: float(v) for k, v in (f.split("=", 1) for f in match.group(2).split())}))
    return found


def holder_changes(events: list[tuple[float, dict[str, float]]]) -> dict[str, tuple[float, float, float]]:
    """Per figure of :data:`HOLDERS` present in the first and the last of ``events`` (at least two, time-ordered):
    (first, last, change per hour) — which allocator, if any, holds what a resident set gained between them."""
    if len(events) < 2:
        raise ValueError(f"holder_changes needs two memory events or more, got {len(events)}")
    (t0, first), (t1, last) = events[0], events[-1]
    hours = (t1 - t0) / 3600.0
    if hours <= 0:
        raise ValueError(f"memory events not in time order: first at {t0}, last at {t1}")
    return {k: (first[k], last[k], (last[k] - first[k]) / hours) for k in HOLDERS if k in first and k in last}
