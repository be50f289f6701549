"""Independent steps of one analysis run side by side (issue 12, item 5: "under 5 minutes on 2 cores").

A batched simulation shares its models out over :func:`~hydrowatch.gap.align.simulation_threads` threads, but a
fit also simulates one model at a time (the solver's trial step; 14 s screening batches are short), and then
one core waits. Steps whose inputs do not depend on each other's results (the screens of a round's candidates,
two confirmations both certain to run, the polishes of two passing candidates, the backward step's refits)
run here at the same time, each in its own thread, so that one's single simulations overlap the other's.
Every step computes exactly what it computed alone (its own fit, its own solver state; the compiled kernel
releases the GIL and a simulation depends only on its model), so the results are the same numbers; only the
order of the log's events changes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from hydrowatch.gap.align import simulation_threads

T = TypeVar("T")


def side_by_side(steps: Sequence[Callable[[], T]]) -> list[T]:
    """Each step's result, in the order of ``steps``.

    Up to :func:`~hydrowatch.gap.align.simulation_threads` steps run at a time (one: one after the other, in
    this thread), started in the order given, so put the longest first. The error of the first step (in the order
    of ``steps``) that raised one is raised here, once every step has run.
    """
    workers = min(simulation_threads(), len(steps))
    if workers <= 1:
        return [step() for step in steps]
    with ThreadPoolExecutor(workers, thread_name_prefix="gap-step") as pool:
        futures = [pool.submit(step) for step in steps]
        return [future.result() for future in futures]
