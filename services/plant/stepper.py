"""The plant's simulation in its own thread, a step or two ahead of the publishing thread.

The compiled kernel of :class:`hydrowatch.plant.PlantSimulator` is most of the plant's CPU. Run
here, the publishing thread encodes and sends step k while step k+1 is simulated: the two overlap
whenever the kernel releases the GIL (numba ``nogil``), and simply take turns when it does not.
A bounded queue keeps the simulation at most ``depth`` steps ahead, so memory stays constant and
real-time pacing (done by the consumer) is unchanged.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterator

import numpy as np

from hydrowatch.plant import PlantSimulator
from hydrowatch.plant.excitation import FilteredNoiseCommand
from hydrowatch.plant.wear import Wear

_POLL_S = 0.1
"""How often a blocked producer looks whether it was closed, s."""


class SimulationThread:
    """Yields ``(outputs, end_time)`` per step: :meth:`PlantSimulator.step`'s dict for the next
    ``n`` samples of every machine and the simulated time after them, s.

    Parameters
    ----------
    sim : PlantSimulator
    command : FilteredNoiseCommand
        The machines' valve commands, ``n`` samples per step.
    n : int
        Samples per step.
    seconds : float
        Stop before the first sample at or after this simulated time, s (inf: endless).
    stop : threading.Event
        Stops the simulation (steps already queued are still yielded).
    depth : int
        Steps simulated ahead at most.
    wear : Wear, optional
        Machines whose fault follows a path (``--degrade``): their parameters move before the steps it says.
    """

    def __init__(self, sim: PlantSimulator, command: FilteredNoiseCommand, n: int, seconds: float,
                 stop: threading.Event, depth: int = 2, wear: Wear | None = None) -> None:
        self.sim, self.command, self.n, self.seconds, self.stop = sim, command, n, seconds, stop
        self.wear = wear
        self.error: BaseException | None = None
        self.cpu_s = 0.0
        """CPU time the simulation thread used, s (thread_time; set when it ends)."""
        self._queue: queue.Queue[tuple[dict[str, np.ndarray], float] | None] = queue.Queue(maxsize=depth)
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="plant-simulation", daemon=True)

    def start(self) -> None:
        """Start simulating."""
        self._thread.start()

    def _offer(self, item: tuple[dict[str, np.ndarray], float] | None) -> bool:
        while not self._closed.is_set():
            try:
                self._queue.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        cpu0 = time.thread_time()
        try:
            half_sample = 0.5 / self.sim.sample_rate
            while not self.stop.is_set() and self.sim.time + half_sample < self.seconds:
                for row, parameters in self.wear.due(self.sim.time) if self.wear is not None else ():
                    self.sim.set_parameters(row, parameters)
                out = self.sim.step(self.command.next(self.n))
                if not self._offer((out, self.sim.time)):
                    return
        except BaseException as exc:  # handed to the consumer, raised there
            self.error = exc
        finally:
            self.cpu_s = time.thread_time() - cpu0
            self._offer(None)

    def __iter__(self) -> Iterator[tuple[dict[str, np.ndarray], float]]:
        while (item := self._queue.get()) is not None:
            yield item
        if self.error is not None:
            raise self.error

    def close(self) -> None:
        """Stop the thread and wait for it (safe to call twice, and before :meth:`start`)."""
        self._closed.set()
        if self._thread.is_alive():
            self._thread.join()


__all__ = ["SimulationThread"]
