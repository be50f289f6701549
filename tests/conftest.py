"""What every test shares: one BLAS thread, in this process and in the services it starts.

On 2 shared cores OpenBLAS's worker threads spin between calls and take the CPU from everything else: a
discriminant's SVD (~1000 x ~300) took 1-6 s instead of 0.03-0.08 s, and the gap analysis's simulation threads
starved (``test_unknown_physics_is_reported_unidentified_with_a_correction`` 33 s → 17 s). The benchmarks pin BLAS
the same way (``threadpool_limits(1)``); what the tests assert does not depend on the thread count.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
from threadpoolctl import threadpool_limits

BLAS_THREADS = "OPENBLAS_NUM_THREADS"
"""Read by OpenBLAS when a child process (a service, a CLI run) loads it."""


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
