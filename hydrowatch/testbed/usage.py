"""What processes use over time, for soak benchmarks (issue 18, item 4): resident memory and CPU time of a process
and its descendants, read from ``/proc`` (Linux), sampled by a thread; and the trend of memory over time.

A service's memory is its **tree's** resident set size (RSS, ``VmRSS`` of ``/proc/<pid>/status``) summed over the
process and every descendant (the MLflow server's workers, PostgreSQL's backends): pages shared between them are
counted once per process, so a tree's figure is an upper bound on what it holds. CPU time is ``utime + stime`` of
``/proc/<pid>/stat`` over the same tree (descendants that have exited are no longer counted).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np

PROC = Path("/proc")
TICKS_PER_S = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
"""Clock ticks per second of ``/proc/<pid>/stat``'s CPU times."""


def process_rss(pid: int) -> int:
    """Resident set size of one process, bytes (0 for a process without memory of its own: a zombie).

    Raises
    ------
    ProcessLookupError
        When no process ``pid`` exists (any more).
    """
    try:
        text = (PROC / str(pid) / "status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        raise ProcessLookupError(f"no process {pid}") from None
    for line in text.splitlines():
        if line.startswith("VmRSS:"):  # "VmRSS:    123456 kB"
            return int(line.split()[1]) * 1024
    return 0


def _stat(pid: int) -> tuple[int, float, str]:
    """(parent pid, CPU s, state letter) from ``/proc/<pid>/stat`` (the command name, field 2, may hold spaces and
    parentheses: fields are counted after its last ``)``)."""
    text = (PROC / str(pid) / "stat").read_text()
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[1]), (int(fields[11]) + int(fields[12])) / TICKS_PER_S, fields[0]  # ppid; utime + stime


def process_tree(pid: int) -> list[int]:
    """``pid`` and every descendant alive now (one pass over ``/proc``); empty when ``pid`` is gone."""
    children: dict[int, list[int]] = {}
    for entry in PROC.iterdir():
        if entry.name.isdigit():
            try:
                children.setdefault(_stat(int(entry.name))[0], []).append(int(entry.name))
            except (FileNotFoundError, ProcessLookupError, ValueError):
                continue  # gone between listing and reading
    if not (PROC / str(pid)).exists():
        return []
    tree, todo = [], [pid]
    while todo:
        found = todo.pop()
        tree.append(found)
        todo.extend(children.get(found, ()))
    return tree


@dataclass(frozen=True)
class TreeUsage:
    """What a process and its descendants use at one instant.

    Parameters
    ----------
    rss : int
        Resident set size summed over the tree, bytes.
    cpu_s : float
        CPU time (user + system) summed over the tree's living processes, s.
    processes : int
    """

    rss: int
    cpu_s: float
    processes: int


def tree_usage(pid: int) -> TreeUsage | None:
    """Memory and CPU time of ``pid`` and its descendants now; None when ``pid`` is gone or has exited and waits to
    be reaped (a zombie: no memory, which would read as a drop to 0). Processes that end while they are read, and
    zombies, are left out."""
    rss, cpu_s, count = 0, 0.0, 0
    for member in process_tree(pid):
        try:
            _, cpu, state = _stat(member)
            if state == "Z":
                continue
            rss += process_rss(member)
        except (FileNotFoundError, ProcessLookupError):
            continue
        cpu_s += cpu
        count += 1
    return TreeUsage(rss, cpu_s, count) if count and _alive(pid) else None


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (exists and is not a zombie)."""
    try:
        return _stat(pid)[2] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


class UsageSampler:
    """Samples :func:`tree_usage` of named processes every ``interval_s`` on a thread; a context manager.

    Parameters
    ----------
    pids : callable returning dict of str to int
        Name → process id, asked at every sample (a restarted service gets its new id); a name whose process is
        gone is left out of that sample.
    interval_s : float
        Seconds between samples (the first is taken on entering).

    Attributes
    ----------
    samples : list of (float, dict of str to TreeUsage)
        Wall-clock time (``time.monotonic()``, s) and each process's usage, in order.
    """

    def __init__(self, pids: Callable[[], Mapping[str, int]], interval_s: float = 5.0) -> None:
        if not interval_s > 0:
            raise ValueError(f"interval_s must be > 0 s. Got {interval_s!r}.")
        self.pids = pids
        self.interval_s = interval_s
        self.samples: list[tuple[float, dict[str, TreeUsage]]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="usage-sampler", daemon=True)

    def sample(self) -> None:
        """Take one sample now."""
        found = {name: usage for name, pid in self.pids().items() if (usage := tree_usage(pid)) is not None}
        self.samples.append((time.monotonic(), found))

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            self.sample()

    def series(self, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One process's samples: times (monotonic s), RSS (bytes) and CPU time (s); empty where never seen."""
        rows = [(t, u[name].rss, u[name].cpu_s) for t, u in self.samples if name in u]
        if not rows:
            return np.empty(0), np.empty(0), np.empty(0)
        t, rss, cpu = map(np.asarray, zip(*rows))
        return t.astype(float), rss.astype(float), cpu.astype(float)

    def names(self) -> list[str]:
        """Every name seen, in order of first appearance."""
        return list(dict.fromkeys(name for _, usage in self.samples for name in usage))

    def __enter__(self) -> UsageSampler:
        self.sample()
        self._thread.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self._stop.set()
        self._thread.join(timeout=30)


@dataclass(frozen=True)
class MemoryTrend:
    """How a memory series moves over time.

    Parameters
    ----------
    slope, low, high : float
        Theil–Sen slope and its ``confidence`` interval (widened for autocorrelation: :func:`memory_trend`), MB/h.
    samples : int
    span_h : float
        Time the samples cover, h.
    """

    slope: float
    low: float
    high: float
    samples: int
    span_h: float

    def verdict(self, limit_mb_h: float) -> str:
        """``flat`` (the interval's upper end below ``limit_mb_h``), ``growing`` (its lower end above it) or
        ``undecided`` (the interval holds the limit: a longer run would tell)."""
        if self.high < limit_mb_h:
            return "flat"
        if self.low > limit_mb_h:
            return "growing"
        return "undecided"


def memory_trend(t_s: np.ndarray, rss_bytes: np.ndarray, confidence: float = 0.95) -> MemoryTrend:
    """Slope of memory over time, MB/h (1 MB = 10⁶ bytes), by Theil–Sen (the median of the slopes between every
    pair of samples: a one-off step or spike moves it little, a steady rise moves it fully), with its
    ``confidence`` interval. :func:`scipy.stats.theilslopes`'s interval takes the residuals as independent; memory
    samples a few seconds apart are not (a sawtooth of garbage collections or file rotations), so the interval is
    widened by √((1 + r) / (1 − r)), r the lag-1 autocorrelation of the residuals (the effective sample size of an
    AR(1) series, n (1 − r) / (1 + r)); a sawtooth that ends part-way still biases a short series.

    Parameters
    ----------
    t_s : array of shape (n,)
        Sample times, s.
    rss_bytes : array of shape (n,)
        Memory at those times, bytes.

    Raises
    ------
    ValueError
        Fewer than 3 samples, arrays of different lengths, or every sample at one time.
    """
    from scipy.stats import theilslopes

    t, m = np.asarray(t_s, dtype=float), np.asarray(rss_bytes, dtype=float)
    if t.shape != m.shape or t.ndim != 1:
        raise ValueError(f"t_s and rss_bytes must be 1-D arrays of one length. Got shapes {t.shape} and {m.shape}.")
    if t.size < 3 or np.ptp(t) <= 0:
        raise ValueError(f"memory_trend needs at least 3 samples over a time span > 0. Got {t.size} samples over "
                         f"{np.ptp(t) if t.size else 0.0:g} s; sample longer or more often.")
    hours, mb = (t - t[0]) / 3600.0, m / 1e6
    slope, intercept, low, high = theilslopes(mb, hours, alpha=confidence)
    residuals = mb - (intercept + slope * hours)
    residuals -= residuals.mean()
    power = float(residuals @ residuals)
    r = float(np.clip(residuals[1:] @ residuals[:-1] / power, 0.0, 0.99)) if power > 0 else 0.0
    widen = np.sqrt((1 + r) / (1 - r))
    return MemoryTrend(float(slope), float(slope - widen * (slope - low)), float(slope + widen * (high - slope)),
                       int(t.size), float(hours[-1]))
