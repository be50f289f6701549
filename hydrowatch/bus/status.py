"""Liveliness and heartbeat of services and machines on ``hydro/<fleet>/<id>/status``.

A liveliness token says "this process is up" and vanishes at once when it closes or is killed
(after ~10 s when it hangs); the heartbeat (schema ``status``, every ``interval`` seconds) says
how it is doing: its status and message counters. A fleet-wide service uses the id
``<service>.<host>.<pid>`` in place of a machine id.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Callable, Iterable

import pyarrow as pa
import zenoh

from hydrowatch.bus.keys import key
from hydrowatch.bus.pubsub import Publisher
from hydrowatch.schemas import STATUS, wire_schema

COUNTERS = ("messages_in", "messages_out", "messages_dropped", "messages_undecodable")
STATES = ("starting", "running", "degraded", "draining", "stopped")


def service_id(service: str) -> str:
    """Id of this process on the bus: ``<service>.<host>.<pid>`` (dots in the host become '-')."""
    return f"{service}.{socket.gethostname().replace('.', '-')}.{os.getpid()}"


def status_batch(service: str, machine: str | None, status: str, counters: dict[str, int]) -> pa.RecordBatch:
    """One heartbeat row of schema ``status`` (time = now, s since the Unix epoch)."""
    if status not in STATES:
        raise ValueError(f"status must be one of {STATES}. Got {status!r}.")
    row = {"service": [service], "machine": [machine], "time": [time.time()], "status": [status]}
    row.update({name: [int(counters.get(name, 0))] for name in COUNTERS})
    return pa.RecordBatch.from_pydict(row, schema=wire_schema(STATUS))


class StatusReporter:
    """Liveliness tokens plus a heartbeat thread for one service.

    Parameters
    ----------
    session : zenoh.Session
    fleet : str
    service : str
        ``plant``, ``record``, ``replay``, ...
    counters : callable returning dict of str to int
        Read at every heartbeat; keys among :data:`COUNTERS`.
    machines : iterable of str
        Machines the service stands for (the plant): each gets a liveliness token of its own.
    interval : float
        Seconds between heartbeats.
    """

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        service: str,
        counters: Callable[[], dict[str, int]],
        *,
        machines: Iterable[str] = (),
        interval: float = 1.0,
    ) -> None:
        self.session = session
        self.fleet = fleet
        self.service = service
        self.counters = counters
        self.machines = tuple(machines)
        self.interval = interval
        self.id = service_id(service)
        self.key = key(fleet, self.id, "status")
        self.status = "starting"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._tokens: list[zenoh.LivelinessToken] = []
        self._publisher = Publisher(session, congestion_control=zenoh.CongestionControl.DROP)

    def start(self) -> StatusReporter:
        """Declare the liveliness tokens and start the heartbeat thread."""
        liveliness = self.session.liveliness()
        self._tokens = [liveliness.declare_token(self.key)]
        self._tokens += [liveliness.declare_token(key(self.fleet, m, "status")) for m in self.machines]
        self.beat()
        self._thread = threading.Thread(target=self._run, name=f"{self.service}-heartbeat", daemon=True)
        self._thread.start()
        return self

    def beat(self) -> None:
        """Publish one heartbeat now."""
        self._publisher.put(self.key, status_batch(self.service, None, self.status, self.counters()))

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            self.beat()

    def stop(self) -> None:
        """Last heartbeat (``stopped``), then undeclare the tokens and the publisher."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self.status = "stopped"
        self.beat()
        for token in self._tokens:
            token.undeclare()
        self._tokens = []
        self._publisher.close()

    def __enter__(self) -> StatusReporter:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def alive(session: zenoh.Session, key_expr: str = "hydro/*/*/status", timeout: float = 1.0) -> list[str]:
    """Keys of the liveliness tokens currently declared under ``key_expr``."""
    found = []
    for reply in session.liveliness().get(key_expr, timeout=timeout):
        if reply.ok is not None:
            found.append(str(reply.ok.key_expr))
    return sorted(found)


def wait_alive(session: zenoh.Session, service: str, fleet: str = "*", count: int = 1, timeout: float = 60.0) -> bool:
    """Wait until ``count`` processes of ``service`` have declared their liveliness token.

    A service declares it once it has subscribed, so afterwards its subscriptions are in place.
    Returns False when ``timeout`` seconds pass first.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if sum(f"/{service}." in k for k in alive(session, f"hydro/{fleet}/*/status", 0.5)) >= count:
            return True
        time.sleep(0.2)
    return False
