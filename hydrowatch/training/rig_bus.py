"""A rig's recording scored on the bus by the services (``hydrowatch demo --rig``, docs/rigs.md, issue 17).

The scorer service (a cycles bundle: ``hydro/<fleet>/*/cycles`` in, ``…/cycle_health`` out) and the replay service
(the ``import --rig`` recording, as fast as it can) run as separate processes on a loopback bus of their own
(Zenoh peer mode, a free port), as ``hydrowatch up`` starts them; this process subscribes to the verdicts and
collects them. Each service's log goes to a file beside the outputs.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import Any

from hydrowatch.bus import BusSettings, Subscriber, free_port, open_session, wait_alive
from hydrowatch.bus.launch import ServiceSpec
from hydrowatch.errors import DataError

SCORER_START_S = 120.0
"""Longest wait for the scorer to announce itself (it loads the model from the registry), s."""


def score_on_bus(recording: Path, model: str, tracking: str | None, *, fleet: str, rows: int, logs: Path,
                 timeout_s: float = 300.0) -> tuple[list[dict[str, Any]], float]:
    """Replay ``recording`` to a scorer of ``model`` and collect ``rows`` ``cycle_verdict`` rows (or what came within
    ``timeout_s`` s of the replay's start); returns the rows (each with its ``machine``) and the seconds from the
    replay's start to the last row.

    Raises
    ------
    DataError
        When the scorer does not come up (its log, under ``logs``, says why) or the replay fails.
    """
    logs.mkdir(parents=True, exist_ok=True)
    port = free_port()
    bus = ("--bus-port", str(port))
    tracking_args = ("--tracking-uri", tracking) if tracking else ()
    scorer = ServiceSpec("scorer", "scorer", ("--model", model, *tracking_args, "--fleet", fleet, *bus),
                         module="services.scorer")
    replay = ServiceSpec("replay", "replay", (str(recording), "--speed", "inf", "--linger", "2", *bus),
                         module="services.replay")
    got: list[dict[str, Any]] = []
    start = last = time.perf_counter()
    with (logs / "scorer.log").open("w") as scorer_log, (logs / "replay.log").open("w") as replay_log:
        processes = [subprocess.Popen(scorer.popen_args(), stdout=scorer_log, stderr=subprocess.STDOUT)]
        try:
            with open_session(BusSettings(port=port)) as session, \
                    Subscriber(session, f"hydro/{fleet}/*/cycle_health") as health:
                if not wait_alive(session, "scorer", fleet, 1, timeout=SCORER_START_S):
                    raise DataError(f"the scorer must come up within {SCORER_START_S:g} s. Got no heartbeat; see "
                                    f"{logs / 'scorer.log'}.", model)
                start = last = time.perf_counter()
                processes.append(subprocess.Popen(replay.popen_args(), stdout=replay_log, stderr=subprocess.STDOUT))
                deadline = time.monotonic() + timeout_s
                while len(got) < rows and time.monotonic() < deadline:
                    message = health.recv(timeout=0.5)
                    if message is not None:
                        got += [{**r, "machine": message.key.machine} for r in message.batch.to_pylist()]
                        last = time.perf_counter()
                if processes[1].wait(timeout=60) != 0:
                    raise DataError(f"the replay must publish the recording. Got exit code {processes[1].returncode}; "
                                    f"see {logs / 'replay.log'}.", str(recording))
        finally:
            for proc in reversed(processes):  # the replay first, then the scorer (it drains on SIGTERM)
                if proc.poll() is None:
                    proc.terminate()
                proc.wait(timeout=60)
    return got, last - start
