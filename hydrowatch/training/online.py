"""Online scoring of a fleet, chunk by chunk (river style: ``update`` feeds, nothing is re-read).

:class:`OnlineScorer` is the fleet driver of every health method: it asks the bundle's method for
its streaming part (:meth:`HealthMethod.online <hydrowatch.methods.base.HealthMethod.online>`) and
runs it in one :class:`~hydrowatch.training.window_fleet.WindowFleet`, which applies chunk hygiene,
breaks, warm-up, staggering, batching and the verdicts' times the same way for all: every machine's
window is a row of one fleet-wide array, clean chunks are written with one vectorised scatter per
update (after the method's per-machine values, for the entropy method the reference models'
prediction errors, batched over the machines), and closed windows are judged as they close in
batches of at most ``batch`` (the parity judge optionally pools each verdict over the machine's
last ``smoothing`` windows).

A stream breaks, and the window in progress is published as ``invalid`` with its reason instead of
producing a wrong verdict, when a chunk

* leaves a gap (its first sample is later than one sample after the previous chunk's last),
* arrives late or out of order (its first sample is not after the previous chunk's last),
* has NaN in the voltage or a sensor the method reads (the NaN samples are skipped),
* is irregular inside (sample spacing off 1/200 s).

After a break the stream restarts: the reference models warm up again (``bundle.warmup`` samples,
none for the raw-window methods) and windows are counted from the first sample after the warm-up.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from hydrowatch.methods.base import HealthMethod, refuse_smoothing
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.chunks import DT, TOLERANCE, Chunk, ChunkBatch, WindowVerdict, chunks_from_batches
from hydrowatch.training.window_fleet import WindowFleet

__all__ = ["DT", "TOLERANCE", "Chunk", "ChunkBatch", "OnlineScorer", "WindowVerdict", "chunks_from_batches"]


class OnlineScorer:
    """Streaming verdicts for many machines from one model bundle (module docstring).

    Parameters
    ----------
    bundle : ModelBundle
        Any method's bundle.
    smoothing : int, default 1
        Valid windows of a machine whose evidence each verdict pools, for a method that pools (parity,
        :class:`~hydrowatch.condition.stream.ConditionStream`; 1: each window alone). Other methods take only 1.
    batch : int, default 64
        Most windows judged in one call (bounds the work between verdicts).
    stagger : bool, default False
        Each machine's windows start at a phase of its own (:class:`WindowFleet`), so machines started together
        do not close their windows in the same update (methods with a warm-up are not staggered).
    unit_method : callable, optional
        Machine → its commissioned method (:attr:`ModelBundle.health_method` of its commissioning) or None.
    expected : bool, default False
        Give each judged window what the model expected its sensors to read (``WindowVerdict.expected``), for
        methods that predict them (parity, entropy; :class:`~hydrowatch.methods.base.ExpectsSensors`).
    """

    def __init__(self, bundle: ModelBundle, *, smoothing: int = 1, batch: int = 64, stagger: bool = False,
                 unit_method: Callable[[str], HealthMethod | None] | None = None, expected: bool = False) -> None:
        self.bundle = bundle
        self.smoothing = smoothing
        method = bundle.health_method
        if smoothing != 1 and not method.pools:
            refuse_smoothing(method.name, smoothing)
        self._fleet = WindowFleet(method.online(smoothing=smoothing, unit_method=unit_method), batch=batch,
                                  stagger=stagger, expected=expected)

    @property
    def samples(self) -> int:
        """Samples fed so far (after any warm-up), over every machine."""
        return int(self._fleet.samples)

    @property
    def columns(self) -> list[str]:
        """Channels the bundle's method reads from every chunk."""
        return list(self._fleet.columns)

    @property
    def machines(self) -> list[str]:
        """Machines seen so far."""
        return self._fleet.machines

    def update(self, chunks: Sequence[Chunk]) -> list[WindowVerdict]:
        """Feed chunks of any machines (in arrival order); returns the verdicts of the windows they close and of
        the windows their breaks cut short.

        ``chunks`` may be a :class:`ChunkBatch` (:func:`chunks_from_batches`), read without per-chunk Python work.
        """
        return self._fleet.update(chunks)
