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
has it (not musl or macOS), and Arrow's ``release_unused()``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import sys
import threading
from collections.abc import Callable
from types import TracebackType

from hydrowatch.log import event, get_logger

log = get_logger(__name__)

TRIM_INTERVAL_S = 60.0
"""Seconds between two trims. One trim that gave back 130–230 MB took 17–25 ms: once a minute, < 0.05 % of a
core."""

_ACTIVE = threading.Lock()
"""Held by the one trimmer running in this process (``hydrowatch up`` runs several services in one)."""


def _malloc_trim() -> Callable[[int], int] | None:
    name = ctypes.util.find_library("c")
    try:
        return getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None
    except OSError:
        return None


_TRIM = _malloc_trim()


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
    """``with HeapTrimmer(stop):`` trims the heap every ``interval`` s (:func:`trim_heap`) until the block ends or
    ``stop`` is set. A second trimmer in the same process does nothing while the first runs.

    Attributes
    ----------
    trims : int
        Trims done.
    """

    def __init__(self, stop: threading.Event, interval: float = TRIM_INTERVAL_S) -> None:
        self.stop, self.interval = stop, float(interval)
        self.trims = 0
        self._done = threading.Event()
        self._thread: threading.Thread | None = None

    def _run(self) -> None:
        try:
            while not (self._done.wait(self.interval) or self.stop.is_set()):
                returned = trim_heap()
                self.trims += 1
                if returned is not None and returned >= 1.0:
                    event(log, "heap trimmed", logging.DEBUG, returned_mb=round(returned, 1))
        finally:
            _ACTIVE.release()

    def __enter__(self) -> HeapTrimmer:
        if self.interval > 0 and _ACTIVE.acquire(blocking=False):
            self._thread = threading.Thread(target=self._run, name="heap-trim", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self._done.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
