"""The topology of compose.yaml started on one machine: a router, an MLflow server (PostgreSQL, else SQLite), and
plant, two recorder shards, two scorer shards and the trainer, each its own process on its own host.

Hosts are network namespaces joined by a bridge where :func:`~hydrowatch.testbed.hosts.namespaces_unavailable`
allows, else loopback. Every bus service is a zenoh client of the router; the trainer is not on the bus: it trains
on the recorders' folder (one filesystem stands for compose's shared volume) and registers each model over HTTP;
the scorers load the model by registry alias over HTTP and follow it. :meth:`Topology.commands` lists each
service's command line (tests/test_bus_compose.py checks that compose.yaml runs the same); :meth:`Topology.kill`
and :meth:`Topology.start` make faults.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from hydrowatch.bus.session import BusSettings
from hydrowatch.testbed.hosts import Network
from hydrowatch.testbed.postgres import PostgresCluster
from hydrowatch.testbed.tracking_server import TrackingServer

MODULES = {"router": "services.router", "plant": "services.plant", "record": "services.recorder",
           "trainer": "services.trainer", "scorer": "services.scorer", "web": "services.web"}
"""``hydrowatch`` command → its service package (``python -m``)."""
HOSTS = ("router", "mlflow", "plant", "record-0", "record-1", "trainer", "score-0", "score-1", "web")
"""One host per process, named as compose.yaml's services (``mlflow`` also holds its PostgreSQL cluster)."""
ROUTER_PORT = 7447
MLFLOW_PORT = 5000
WEB_PORT = 8050


@dataclass(frozen=True)
class TopologySettings:
    """What the topology runs.

    Parameters
    ----------
    fleet : str
    machines : int
        Simulated machines.
    states : str
        Health states given to the machines in turn (the plant's ``--states``).
    speed : float
        Plant speed, simulated s per wall-clock s.
    plant_seconds : float or None
        Simulated seconds the plant runs (None: until stopped).
    history : float
        Seconds of chunks the plant keeps for recovery (its ``--history``; 30 as compose.yaml: enough for a router
        restart).
    retrain : float
        Seconds between the trainer's trainings (its ``--every``).
    rotate_s : float
        Seconds after which a recorder closes a file (finished files are what the trainer reads).
    flush_s : float
        Seconds after which a recorder closes a chunk (its ``--flush``: 0.2 loses little to a kill; compose.yaml
        keeps the recorder's default, 1).
    follow_s : float
        Seconds between the scorers' looks at the registry alias (``--follow-alias``).
    smoothing : int or None
        Scorers' ``--smoothing`` (None: their default).
    namespaces : bool
        Hosts in network namespaces (else loopback).
    postgres : bool
        The MLflow server's backend store in PostgreSQL (else SQLite).
    model_name, alias : str
        What the trainer registers and the scorers follow.
    train_data : str or None
        Folder the trainer trains on (None: the recorders' folder, as compose.yaml).
    extra : dict of str to tuple of str
        More flags per service, by host name (e.g. ``{"score-0": ("--no-recovery",)}``).
    """

    fleet: str = "topo"
    machines: int = 6
    states: str = "healthy,load_warning"
    speed: float = 20.0
    plant_seconds: float | None = None
    history: float = 30.0
    retrain: float = 15.0
    rotate_s: float = 5.0
    flush_s: float = 0.2
    follow_s: float = 2.0
    smoothing: int | None = None
    namespaces: bool = True
    postgres: bool = True
    model_name: str = "hydrowatch"
    alias: str = "champion"
    train_data: str | None = None
    extra: dict[str, tuple[str, ...]] = field(default_factory=dict)


class Topology:
    """The deployment, as a context manager: entering builds the hosts, starts PostgreSQL (or picks SQLite), the
    MLflow server and the router; :meth:`start` starts the services; leaving stops everything (SIGTERM, in reverse
    start order: subscribers drain after their publishers) and removes what was made.

    Parameters
    ----------
    work : path
        Folder for recordings (``recordings/``), the trainer's bundle, the server's artifacts and each process's
        log (``logs/<host>.log``).
    settings : TopologySettings
    """

    def __init__(self, work: Path, settings: TopologySettings) -> None:
        self.work = work
        self.settings = settings
        self.logs = work / "logs"
        self.recordings = work / "recordings"
        self.network = Network(HOSTS, namespaces=settings.namespaces)
        self.postgres: PostgresCluster | None = None
        self.tracking: TrackingServer | None = None
        self.processes: dict[str, subprocess.Popen] = {}
        self._stack = contextlib.ExitStack()

    # -- addresses and command lines ------------------------------------------------------------------------------
    @property
    def router_endpoint(self) -> str:
        return f"tcp/{self.network.hosts['router'].address}:{ROUTER_PORT}"

    @property
    def web_url(self) -> str:
        """The fleet page's address (the web service's host)."""
        return f"http://{self.network.hosts['web'].address}:{WEB_PORT}"

    @property
    def tracking_uri(self) -> str:
        return f"http://{self.network.hosts['mlflow'].address}:{MLFLOW_PORT}"

    @property
    def model_uri(self) -> str:
        return f"models:/{self.settings.model_name}@{self.settings.alias}"

    def client_settings(self) -> BusSettings:
        """Bus settings for this process to join as one more client of the router (to listen to verdicts)."""
        return BusSettings(mode="client", connect=(self.router_endpoint,))

    def commands(self) -> dict[str, tuple[str, list[str]]]:
        """Host → (``hydrowatch`` command, its flags): what each service process runs (as ``python -m``)."""
        s, bus = self.settings, ["--connect", self.router_endpoint]
        tracking = ["--tracking-uri", self.tracking_uri]
        plant = ["--fleet", s.fleet, "--machines", str(s.machines), "--states", s.states, "--speed", str(s.speed),
                 "--history", str(s.history), "--wait-subscribers", "30", *bus]
        if s.plant_seconds is not None:
            plant += ["--seconds", str(s.plant_seconds)]
        found = {
            "router": ("router", ["--listen", f"tcp/{self.network.hosts['router'].address}:{ROUTER_PORT}"]),
            "plant": ("plant", plant),
            "trainer": ("trainer", ["--data", s.train_data or str(self.recordings),
                                    "--out", str(self.work / "models" / "latest"), "--every", str(s.retrain),
                                    "--method", "parity", "--model-name", s.model_name, "--alias", s.alias,
                                    *tracking]),
            "web": ("web", ["--fleet", s.fleet, "--host", self.network.hosts["web"].address, "--port", str(WEB_PORT),
                            *bus]),
        }
        for i in range(2):
            found[f"record-{i}"] = ("record", ["--fleet", s.fleet, "--shard", f"{i}/2", "--out", str(self.recordings),
                                               "--rotate-s", str(s.rotate_s), "--flush", str(s.flush_s), *bus])
            smoothing = [] if s.smoothing is None else ["--smoothing", str(s.smoothing)]
            found[f"score-{i}"] = ("scorer", ["--fleet", s.fleet, "--shard", f"{i}/2", "--model", self.model_uri,
                                              "--follow-alias", str(s.follow_s), *smoothing, *tracking, *bus])
        return {host: (command, [*argv, *s.extra.get(host, ())]) for host, (command, argv) in found.items()}

    # -- processes ------------------------------------------------------------------------------------------------
    def start(self, host: str) -> subprocess.Popen:
        """Start (or restart) the service of ``host``."""
        if host == "mlflow":
            assert self.tracking is not None
            self.tracking.start()
            return self.tracking.process  # type: ignore[return-value]
        command, argv = self.commands()[host]
        proc = self.network.hosts[host].popen([sys.executable, "-m", MODULES[command], "-v", *argv],
                                              self.logs / f"{host}.log")
        self.processes[host] = proc
        return proc

    def kill(self, host: str, sig: int = signal.SIGKILL) -> None:
        """Send ``sig`` (default SIGKILL: a crash) to the service of ``host`` and its children, and reap it."""
        if host == "mlflow":
            assert self.tracking is not None
            self.tracking.kill() if sig == signal.SIGKILL else self.tracking.stop()
            return
        proc = self.processes[host]
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        proc.wait(timeout=60)

    def wait_router(self, timeout: float = 30.0) -> None:
        """Wait until the router accepts TCP connections."""
        host, began = self.network.hosts["router"].address, time.monotonic()
        while True:
            with contextlib.suppress(OSError), socket.create_connection((host, ROUTER_PORT), timeout=1):
                return
            proc = self.processes.get("router")
            if proc is not None and proc.poll() is not None:
                raise RuntimeError(f"router exited ({proc.returncode}); see {self.logs / 'router.log'}")
            if time.monotonic() - began > timeout:
                raise RuntimeError(f"router not reachable at {host}:{ROUTER_PORT} after {timeout:.0f} s")
            time.sleep(0.1)

    @property
    def backend(self) -> str:
        """``postgresql`` or ``sqlite``."""
        return "postgresql" if self.postgres is not None else "sqlite"

    def __enter__(self) -> Topology:
        self.logs.mkdir(parents=True, exist_ok=True)
        self.recordings.mkdir(parents=True, exist_ok=True)
        try:
            self._stack.enter_context(self.network)
            if self.settings.postgres:
                self.postgres = self._stack.enter_context(PostgresCluster())
                backend = self.postgres.uri
            else:
                backend = f"sqlite:///{self.work / 'mlflow.db'}"
            self.tracking = TrackingServer(self.network.hosts["mlflow"], backend, self.work / "mlartifacts",
                                           self.logs / "mlflow.log", port=MLFLOW_PORT)
            self._stack.callback(self.tracking.stop)
            self.tracking.start()
            self.start("router")
            self.wait_router()
        except BaseException:
            self.close()
            raise
        return self

    def running(self) -> Iterator[tuple[str, subprocess.Popen]]:
        """Services still running, latest started first."""
        for host, proc in reversed(list(self.processes.items())):
            if proc.poll() is None:
                yield host, proc

    def close(self, grace_s: float = 30.0) -> dict[str, int]:
        """Stop every service with SIGTERM, in three waves each waited for (SIGKILL after ``grace_s``): the
        publishers and the trainer, then the subscribers (they drain what was published), then the router; then the
        MLflow server, PostgreSQL and the hosts. Returns each service's exit status."""
        for wave in (("plant", "trainer"), ("score-0", "score-1", "record-0", "record-1", "web"), ("router",)):
            procs = [self.processes[h] for h in wave if h in self.processes]
            for proc in procs:
                if proc.poll() is None:
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(proc.pid, signal.SIGTERM)
            deadline = time.monotonic() + grace_s
            for proc in procs:
                try:
                    proc.wait(timeout=max(deadline - time.monotonic(), 0.1))
                except subprocess.TimeoutExpired:
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
        codes = {host: int(proc.returncode) for host, proc in self.processes.items()}
        self._stack.close()
        return codes

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()


@dataclass(frozen=True)
class HeardVerdict:
    """One verdict heard on the bus: when (s since :class:`VerdictLog` began, wall clock), for which window."""

    t: float
    machine: str
    window_start: float
    state: str
    model_version: str


class VerdictLog:
    """Every verdict of ``fleet`` heard by a client of the router, gathered by a thread; a context manager.

    The session is opened inside the thread and lives as long as the block, so the zenoh subscriber is always
    undeclared before the interpreter exits (../shared/docs/stack-notes.md, "Exit hang").
    """

    def __init__(self, settings: BusSettings, fleet: str) -> None:
        self.settings = settings
        self.fleet = fleet
        self.verdicts: list[HeardVerdict] = []
        self.began = time.monotonic()
        self._ready = threading.Event()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._listen, name="verdicts", daemon=True)

    def _listen(self) -> None:
        from hydrowatch.bus import Subscriber, open_session

        with open_session(self.settings) as session, \
                Subscriber(session, f"hydro/{self.fleet}/*/health") as health:
            self._ready.set()
            while not self._done.is_set():
                for message in health.recv_many(timeout=0.2):
                    now = time.monotonic() - self.began
                    for row in message.batch.to_pylist():
                        self.verdicts.append(HeardVerdict(now, message.key.machine, float(row["window_start"]),
                                                     str(row["state"]), str(row["model_version"])))

    def by_machine(self) -> dict[str, list[HeardVerdict]]:
        out: dict[str, list[HeardVerdict]] = {}
        for v in list(self.verdicts):
            out.setdefault(v.machine, []).append(v)
        return out

    def __enter__(self) -> VerdictLog:
        self._thread.start()
        if not self._ready.wait(60):
            raise RuntimeError("the verdict listener did not join the bus in 60 s")
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self._done.set()
        self._thread.join(timeout=30)
