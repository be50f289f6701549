"""What every test shares: one BLAS thread, in this process and in the services it starts.

On 2 shared cores OpenBLAS's worker threads spin between calls and take the CPU from everything else: a
discriminant's SVD (~1000 x ~300) took 1-6 s instead of 0.03-0.08 s, and the gap analysis's simulation threads
starved (``test_unknown_physics_is_reported_unidentified_with_a_correction`` 33 s → 17 s). The benchmarks pin BLAS
the same way (``threadpool_limits(1)``); what the tests assert does not depend on the thread count.

``make test`` runs the suite on three pytest-xdist workers (``-n 3 --dist loadfile``): each module stays on one worker
(its module-scoped models and recordings are built once), and the modules in :data:`SERVICE_MODULES` share one
worker, so that at most one test at a time starts a fleet of service processes, servers or a browser and waits for
their messages against a deadline. Plain ``pytest`` runs everything in one process, as before.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import pytest
from threadpoolctl import threadpool_limits

BLAS_THREADS = "OPENBLAS_NUM_THREADS"
"""Read by OpenBLAS when a child process (a service, a CLI run) loads it."""

SERVICE_GROUP = "services"
"""The pytest-xdist work unit of the modules that start several processes and wait on them."""
SERVICE_MODULES = frozenset({
    "test_bus_fuzz.py", "test_bus_services.py", "test_bus_topology.py", "test_demo_live.py", "test_mlflow_model.py",
    "test_pipeline_online.py", "test_pipeline_parity.py", "test_rig_scorer.py", "test_sparse_sensors.py",
    "test_web_browser.py",
})
"""Modules whose tests run plant, recorder, scorer, trainer or web services, a zenoh router, an MLflow server,
PostgreSQL or Chromium as child processes, and wait for their messages with timeouts: two of them at once on two
cores would halve each one's CPU and stretch those waits."""


@pytest.hookimpl(optionalhook=True)  # a pytest-xdist hook: without the plugin, plain pytest ignores it
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """Under ``--dist loadfile``: each module's tests on one worker, as pytest-xdist does, and the tests of every
    module of :data:`SERVICE_MODULES` on one worker too (pytest-xdist's own ``--dist loadgroup`` cannot be used: it
    renames the tests' ids, which pytest 9 no longer lets a plugin do, and it then groups nothing). Other ``--dist``
    modes are pytest-xdist's."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ServicesTogether(LoadScopeScheduling):
        """Work units: one module, or all of :data:`SERVICE_MODULES`; the unit with the most tests goes first."""

        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return SERVICE_GROUP if module.rsplit("/", 1)[-1] in SERVICE_MODULES else module

    return ServicesTogether(config, log)


@pytest.fixture(scope="session", autouse=True)
def one_blas_thread() -> Iterator[None]:
    """BLAS on one thread for the whole session (a value already in the environment is kept for child processes)."""
    previous = os.environ.get(BLAS_THREADS)
    os.environ.setdefault(BLAS_THREADS, "1")
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
    finally:
        if previous is None:
            os.environ.pop(BLAS_THREADS, None)
