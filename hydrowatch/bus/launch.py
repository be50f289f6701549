"""Start services as local processes on one loopback bus and stop them together (``hydrowatch up``)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from hydrowatch.log import event, get_logger

log = get_logger(__name__)


@dataclass(frozen=True)
class ServiceSpec:
    """A service to start: ``python -m <module>`` when given (lighter), else ``hydrowatch <command>``."""

    name: str
    command: str
    argv: tuple[str, ...] = ()
    verbose: int = 0
    module: str | None = None

    def popen_args(self) -> list[str]:
        """The process command line (this interpreter)."""
        verbose = ["-" + "v" * self.verbose] if self.verbose else []
        if self.module:
            return [sys.executable, "-m", self.module, *verbose, *self.argv]
        return [sys.executable, "-m", "hydrowatch", *verbose, self.command, *self.argv]


def _stop(processes: Mapping[str, subprocess.Popen], grace_s: float) -> None:
    """SIGTERM each in start order, waiting for it: publishers (started first) stop before their subscribers."""
    for name, proc in processes.items():
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            event(log, "service did not stop in time; killing it", name=name, pid=proc.pid)
            proc.kill()
            proc.wait()


def supervise(
    specs: Sequence[ServiceSpec],
    stop: threading.Event,
    *,
    seconds: float | None = None,
    grace_s: float = 15.0,
    env: Mapping[str, str] | None = None,
) -> int:
    """Start every service, wait, and stop them all together.

    All stop (SIGTERM in start order, each waited for, SIGKILL after ``grace_s``) when ``stop`` is
    set, when ``seconds`` of wall-clock time have passed, or as soon as any one of them exits.

    Returns
    -------
    int
        0 when every service exited cleanly, else the first non-zero exit status.
    """
    processes: dict[str, subprocess.Popen] = {}
    child_env = {**os.environ, **(env or {})}
    try:
        for spec in specs:
            processes[spec.name] = subprocess.Popen(spec.popen_args(), env=child_env)
            event(log, "service started", name=spec.name, pid=processes[spec.name].pid)
        deadline = None if seconds is None else time.monotonic() + seconds
        while not stop.wait(0.2):
            if deadline is not None and time.monotonic() >= deadline:
                break
            ended = [name for name, proc in processes.items() if proc.poll() is not None]
            if ended:
                event(log, "service exited; stopping the others", name=ended[0],
                      status=processes[ended[0]].returncode)
                break
    finally:
        _stop(processes, grace_s)
    codes = [proc.returncode for proc in processes.values()]
    return next((c for c in codes if c not in (0, -signal.SIGTERM)), 0)
