"""Memory and CPU of processes over time (hydrowatch.testbed.usage, the soak benchmark's sampler), measured on this
test process and a child of it."""

from __future__ import annotations

import mmap
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hydrowatch.testbed.usage import UsageSampler, memory_trend, process_rss, process_tree, tree_usage

pytestmark = pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads /proc (Linux)")


def test_rss_follows_an_allocation_of_this_process() -> None:
    before = process_rss(os.getpid())
    block = np.ones(8_000_000)  # 64 MB, every page written
    grown = process_rss(os.getpid())
    del block
    after = process_rss(os.getpid())
    assert 60e6 < grown - before < 72e6, (before, grown)
    assert grown - after > 60e6, (grown, after)  # numpy's large blocks go back to the system


def test_a_tree_holds_the_children_and_their_memory() -> None:
    child = subprocess.Popen([sys.executable, "-c", "import time, numpy; b = numpy.ones(4_000_000); time.sleep(30)"])
    try:
        deadline = time.monotonic() + 20
        while (process_rss(child.pid) < 32e6) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert child.pid in process_tree(os.getpid())
        mine, alone = tree_usage(os.getpid()), process_rss(os.getpid())
        assert mine is not None and mine.processes >= 2
        assert mine.rss - alone >= 32e6  # the child's 32 MB block counts in this process's tree
        assert mine.cpu_s > 0
    finally:
        child.kill()
    deadline = time.monotonic() + 10
    while Path(f"/proc/{child.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":  # exited, not reaped
        assert time.monotonic() < deadline
        time.sleep(0.01)
    assert tree_usage(child.pid) is None  # a zombie has no memory: not a sample of 0
    child.wait()
    assert tree_usage(child.pid) is None and process_tree(child.pid) == []
    with pytest.raises(ProcessLookupError, match=str(child.pid)):
        process_rss(child.pid)


def test_the_sampler_samples_named_processes_and_leaves_out_those_gone() -> None:
    with UsageSampler(lambda: {"me": os.getpid(), "gone": 2**22 + 12345}, interval_s=0.05) as sampler:
        time.sleep(0.3)  # samples before the block (the sampler's first one may come after the next line)
        # 40 MB of fresh anonymous pages while sampling: an mmap of its own, not malloc, whose freed heap an earlier
        # test may have left resident (then the RSS would not move)
        block = mmap.mmap(-1, 40 << 20)
        for offset in range(0, 40 << 20, mmap.PAGESIZE):
            block[offset] = 1
        time.sleep(0.5)
        block.close()
        time.sleep(0.3)  # and after it is freed
    t, rss, cpu = sampler.series("me")
    assert len(t) >= 5 and np.all(np.diff(t) > 0) and np.all(np.diff(cpu) >= 0)
    assert rss.max() - rss.min() > 30e6
    assert sampler.names() == ["me"] and sampler.series("gone")[0].size == 0
    with pytest.raises(ValueError, match="interval_s must be > 0"):
        UsageSampler(dict, interval_s=0)


def test_the_trend_finds_a_steady_rise_through_a_sawtooth_and_calls_a_flat_series_flat() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(0, 3600, 5.0)  # an hour, every 5 s
    sawtooth = 4e6 * ((t % 300) / 300)  # ±2 MB every 5 min, as garbage collection and rotations do
    rising = 500e6 + 10e6 * t / 3600 + sawtooth + rng.normal(0, 0.5e6, t.size)
    trend = memory_trend(t, rising)
    assert 9.0 < trend.slope < 11.0 and trend.low < 10.0 < trend.high, trend
    assert trend.verdict(5.0) == "growing" and trend.samples == t.size and trend.span_h == pytest.approx(3595 / 3600)
    flat = memory_trend(t, 500e6 + sawtooth + rng.normal(0, 0.5e6, t.size))
    assert abs(flat.slope) < 1.0 and flat.verdict(5.0) == "flat", flat
    short = memory_trend(t[:24], 500e6 + rng.normal(0, 0.5e6, 24))  # flat, but two minutes: the interval holds 5
    assert short.low < 0 < 5.0 < short.high and short.verdict(5.0) == "undecided", short
    stepped = memory_trend(t, 500e6 + 50e6 * (t > 600))  # one step early on (a cache filled): not a slope
    assert abs(stepped.slope) < 1.0, stepped
    with pytest.raises(ValueError, match="at least 3 samples"):
        memory_trend(t[:2], rising[:2])
