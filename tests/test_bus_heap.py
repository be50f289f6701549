"""Freed memory goes back to the operating system in long-running services (hydrowatch.bus.heap)."""

from __future__ import annotations

import logging
import threading
import time

import pytest

from hydrowatch.bus import heap
from hydrowatch.bus.heap import HeapTrimmer, resident_mb, trim_heap

needs_trim = pytest.mark.skipif(heap._TRIM is None or resident_mb() is None,
                                reason="the C library has no malloc_trim, or /proc is absent")


@needs_trim
def test_trimming_gives_back_what_was_freed_in_the_middle_of_the_heap() -> None:
    trim_heap()
    start = resident_mb()
    blocks = [b"\x01" * (64 * 1024) for _ in range(2400)]  # 150 MB of malloc'd blocks (above pymalloc, below mmap)
    pin = [b"\x01" * (64 * 1024) for _ in range(4)]  # keeps the heap's top in use: glibc cannot give it back by itself
    grown = resident_mb()
    del blocks
    freed = resident_mb()
    returned = trim_heap()
    assert grown - start > 120.0
    assert freed - start > 100.0  # freed, still resident: the allocator keeps it
    assert returned is not None and returned > 100.0
    assert resident_mb() - start < 30.0
    del pin


@needs_trim
def test_the_trimmer_trims_while_the_service_runs_and_one_per_process() -> None:
    stop = threading.Event()
    with HeapTrimmer(stop, interval=0.02) as first, HeapTrimmer(stop, interval=0.02) as second:
        time.sleep(0.3)
        assert first.trims >= 3
        assert second._thread is None and second.trims == 0
    assert not first._thread.is_alive()
    with HeapTrimmer(stop, interval=0.02) as again:  # the first has ended: the next one runs
        time.sleep(0.1)
    assert again.trims >= 1
    stop.set()
    with HeapTrimmer(stop, interval=0.02) as stopped:  # a service told to stop does not trim
        time.sleep(0.1)
    assert stopped.trims == 0


@pytest.mark.skipif(resident_mb() is None, reason="/proc is absent: the resident set cannot be read")
def test_trimming_gives_back_what_arrows_allocator_kept() -> None:
    import pyarrow as pa

    trim_heap()
    start = resident_mb()
    buffers = [pa.allocate_buffer(64 * 1024) for _ in range(2400)]  # 150 MB from Arrow's own pool (mimalloc)
    pin = buffers[::100]
    grown = resident_mb()
    del buffers
    freed = resident_mb()
    returned = trim_heap()
    assert grown - start > 120.0
    assert returned is not None and returned > 100.0, (pa.default_memory_pool().backend_name, freed - start)
    assert resident_mb() - start < 30.0
    del pin


@pytest.mark.skipif(heap._MALLINFO2 is None or resident_mb() is None,
                    reason="the C library has no mallinfo2 (glibc < 2.33), or /proc is absent")
def test_the_memory_figures_say_which_allocator_holds_what() -> None:
    import pyarrow as pa

    trim_heap()
    before = heap.heap_stats()
    blocks = [b"\x01" * (64 * 1024) for _ in range(800)]  # 50 MB from glibc (above pymalloc's 512 B)
    arrow = [pa.allocate_buffer(64 * 1024) for _ in range(800)]  # 50 MB from Arrow's pool
    held = heap.heap_stats()
    glibc = (held["glibc_in_use_mb"] + held["glibc_mmap_mb"]) - (before["glibc_in_use_mb"] + before["glibc_mmap_mb"])
    assert 45.0 < glibc < 60.0
    assert 45.0 < held["arrow_mb"] - before["arrow_mb"] < 55.0
    assert held["rss_mb"] - before["rss_mb"] > 75.0  # 100 MB allocated; free space already resident is reused
    assert held["python_blocks"] - before["python_blocks"] >= 800
    del blocks, arrow
    freed = heap.heap_stats()
    assert freed["arrow_mb"] - before["arrow_mb"] < 1.0
    assert freed["glibc_in_use_mb"] - before["glibc_in_use_mb"] < 5.0


@needs_trim
def test_the_trimmer_logs_what_the_process_holds_and_what_trimming_cost(caplog: pytest.LogCaptureFixture) -> None:
    stop = threading.Event()

    def logged() -> list[dict]:
        return [r.fields for r in caplog.records if r.getMessage() == "memory"]  # type: ignore[attr-defined]

    with caplog.at_level("INFO", logger="hydrowatch.bus.heap"), \
            HeapTrimmer(stop, interval=0.01, stats_interval=0.1) as trimmer:
        start = time.monotonic()
        while len(logged()) < 3 and time.monotonic() - start < 10.0:  # a loaded machine may run the thread late
            time.sleep(0.05)
        elapsed = time.monotonic() - start
    records = logged()
    assert 3 <= len(records) <= elapsed / 0.1 + 2  # one per stats interval, never more
    assert sum(f["trims"] for f in records) <= trimmer.trims
    assert {"rss_mb", "glibc_in_use_mb", "arrow_mb", "python_blocks"} <= set(records[0])
    assert 0.0 < records[0]["trim_ms_mean"] <= records[0]["trim_ms_max"] < 100.0


def test_a_services_memory_events_are_read_back_from_its_log_with_each_holders_change_per_hour() -> None:
    from hydrowatch.log import _KeyValueFormatter

    formatter = _KeyValueFormatter()
    lines = []
    for minute, in_use in ((0, 100.0), (30, 101.5), (60, 103.0)):
        record = heap.log.makeRecord(heap.log.name, logging.INFO, __file__, 0, heap.MEMORY_EVENT, None, None,
                                     extra={"fields": {"rss_mb": 400.0 + minute, "glibc_in_use_mb": in_use,
                                                       "python_blocks": 1.29e6, "trims": 30}})
        record.created = 1.8e9 + 60.0 * minute
        lines.append(formatter.format(record))
    lines.insert(1, formatter.format(heap.log.makeRecord(heap.log.name, logging.INFO, __file__, 0, "heap trimmed",
                                                         None, None, extra={"fields": {"returned_mb": 3.0}})))
    events = heap.memory_events("\n".join(lines) + "\nnot a log line\n")
    assert [round(t - events[0][0]) for t, _ in events] == [0, 1800, 3600]
    assert events[1][1] == {"rss_mb": 430.0, "glibc_in_use_mb": 101.5, "python_blocks": 1.29e6, "trims": 30.0}
    changes = heap.holder_changes(events)
    assert set(changes) == {"rss_mb", "glibc_in_use_mb", "python_blocks"}  # the trims' count is no holder
    assert changes["rss_mb"] == pytest.approx((400.0, 460.0, 60.0))
    assert changes["glibc_in_use_mb"] == pytest.approx((100.0, 103.0, 3.0))
    assert changes["python_blocks"][2] == 0.0
    with pytest.raises(ValueError, match="two memory events"):
        heap.holder_changes(events[:1])
    with pytest.raises(ValueError, match="time order"):
        heap.holder_changes(events[::-1])


@pytest.mark.skipif(heap._MALLINFO2 is None, reason="the C library has no mallinfo2 (glibc < 2.33)")
def test_a_fixed_mmap_threshold_maps_large_blocks_after_a_larger_one_was_freed() -> None:
    """glibc raises its mmap threshold to the size of a mapped block freed; then a 6 MB array comes from the arena (not
    mapped) unless the threshold is fixed. A fresh process each, so nothing before changed the allocator."""
    import subprocess
    import sys

    probe = ("import sys, numpy as np; from hydrowatch.bus import heap\n"
             "mapped = lambda: heap.heap_stats()['glibc_mmap_mb']\n"
             "x = np.ones(2**20); del x\n"  # 8 MB mapped, freed: the threshold rises to 8 MB
             "if sys.argv[1] == 'fixed': assert heap.fix_mmap_threshold()\n"
             "before = mapped(); y = np.ones(6 * 2**17); print(round(mapped() - before, 1))\n")
    got = {how: float(subprocess.run([sys.executable, "-c", probe, how], capture_output=True, text=True,
                                     check=True).stdout) for how in ("dynamic", "fixed")}
    assert got == {"dynamic": 0.0, "fixed": 6.0}
