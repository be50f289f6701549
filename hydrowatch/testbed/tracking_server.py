"""An MLflow tracking server as its own process (``mlflow server``), on a host, that can be killed and restarted.

Clients reach it over HTTP at ``uri``; artifacts go through it (``--artifacts-destination``: the server stores them
in a folder and serves them, so a client needs no access to that folder). ``--workers 1``: ready in ~6–9 s on
2 cores (../shared/docs/stack-notes.md). The server runs in a process group of its own: :meth:`kill` (SIGKILL)
and :meth:`stop` (SIGTERM) reach its worker processes too, so that a restart finds its port free.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from types import TracebackType

from hydrowatch.testbed.hosts import Host

SERVER_ENV = {"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
"""MLflow 3.17's server otherwise starts a job runner with seven Huey consumer processes (for GenAI evaluation
jobs, which hydrowatch does not use): on 2 cores it was ready in 34 s with them (load ~9) and stopped in ~3 s."""


class TrackingServer:
    """``mlflow server`` on ``host`` with backend store ``backend_uri`` (PostgreSQL or SQLite).

    Parameters
    ----------
    host : Host
    backend_uri : str
        SQLAlchemy URI of the backend store, e.g. ``postgresql://…`` or ``sqlite:///…/mlflow.db``.
    artifacts : path
        Folder where the server keeps artifacts.
    log : path
        The server's output is appended here.
    port : int
    """

    def __init__(self, host: Host, backend_uri: str, artifacts: Path, log: Path, *, port: int = 5000) -> None:
        self.host = host
        self.backend_uri = backend_uri
        self.artifacts = artifacts
        self.log = log
        self.port = port
        self.process: subprocess.Popen | None = None

    @property
    def uri(self) -> str:
        """The tracking URI clients use: ``http://<host address>:<port>``."""
        return f"http://{self.host.address}:{self.port}"

    def start(self) -> None:
        """Start the server process (does not wait: :meth:`wait_ready`)."""
        argv = [sys.executable, "-m", "mlflow", "server", "--host", self.host.address, "--port", str(self.port),
                "--workers", "1", "--backend-store-uri", self.backend_uri,
                "--artifacts-destination", str(self.artifacts)]
        self.process = self.host.popen(argv, self.log, env=SERVER_ENV)

    def ready(self) -> bool:
        """True when the server answers ``/health``."""
        try:
            with urllib.request.urlopen(f"{self.uri}/health", timeout=2) as answer:
                return bool(answer.status == 200)
        except (urllib.error.URLError, OSError):
            return False

    def wait_ready(self, timeout: float = 120.0) -> float:
        """Wait until the server answers; returns the seconds waited. Raises RuntimeError when it exited or
        ``timeout`` passed (the log's tail says why)."""
        began = time.monotonic()
        while not self.ready():
            if self.process is not None and self.process.poll() is not None:
                raise RuntimeError(f"mlflow server exited ({self.process.returncode}): {self._tail()}")
            if time.monotonic() - began > timeout:
                raise RuntimeError(f"mlflow server not ready after {timeout:.0f} s: {self._tail()}")
            time.sleep(0.25)
        return time.monotonic() - began

    def _tail(self) -> str:
        return self.log.read_text(errors="replace")[-800:] if self.log.exists() else "(no log)"

    def _signal(self, sig: int, wait: float) -> None:
        if self.process is None:
            return
        try:
            os.killpg(self.process.pid, sig)
        except ProcessLookupError:
            pass
        try:
            self.process.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait()
        self.process = None

    def kill(self) -> None:
        """SIGKILL the server and its workers (a crash)."""
        self._signal(signal.SIGKILL, 10.0)

    def stop(self) -> None:
        """SIGTERM the server and its workers, SIGKILL after 20 s."""
        self._signal(signal.SIGTERM, 20.0)

    def __enter__(self) -> TrackingServer:
        self.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.stop()
