"""One machine's degradation-index history online, and its forecast (river style): :class:`ForecastStream`.

The scorer keeps one per machine. :meth:`ForecastStream.update` takes each window's index (as the parity judge
gives it, :meth:`~hydrowatch.condition.degradation_stream.DegradationStream.update`) and returns nothing;
:meth:`ForecastStream.get` forecasts every part seen from the history it holds, with the one implementation
:func:`~hydrowatch.condition.forecast.forecast_alert`, as ``score --json``'s summary does for a file
(:func:`hydrowatch.training.scoring.degradation_forecast`): the same windows give the same forecast.

**Bounded memory.** The history is a ring of the last ``capacity`` windows that had an index: their start times
(float64) and each part's index (float32: the index travels rounded to 1e-4, float32 keeps that exactly enough,
≤ 1e-6 at the index's scale of ≤ 10), NaN where the part's value was not its own estimate (a valve-side look-alike
was blamed, :meth:`~hydrowatch.condition.degradation.Degradation.history`), and its provisional value where it was
blamed before the pool could tell it apart (float32, kept until a later window confirms it). With the default
:data:`HISTORY_WINDOWS` (1440: two hours of 5 s windows) that is 1440 × (8 + 2 × 6 × 4) B = 81 kB per machine. A
forecast rests on at most that history, so it reaches at most :data:`~hydrowatch.condition.forecast.HORIZON_FACTOR`
× its span ahead (20 h for two hours); a part wearing over days needs a longer ``capacity``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from hydrowatch.condition.attribution import confirmed
from hydrowatch.condition.forecast import Forecast, forecast_alert, ruled_out_forecast
from hydrowatch.condition.ring import Ring
from hydrowatch.errors import ParameterError
from hydrowatch.plant.faults import FAULTS

HISTORY_WINDOWS = 1440
"""Default windows of history kept per machine: two hours of 5 s windows (what the benchmark forecasts from)."""


class ForecastStream:
    """The last ``capacity`` windows of one machine's degradation index, and the forecast they give (module
    docstring).

    Parameters
    ----------
    capacity : int, default :data:`HISTORY_WINDOWS`
        Windows with an index kept (older ones are dropped).
    """

    def __init__(self, capacity: int = HISTORY_WINDOWS) -> None:
        if int(capacity) != capacity or capacity < 1:
            raise ParameterError(f"capacity must be an integer >= 1 (windows of history). Got {capacity!r}; "
                                 f"{HISTORY_WINDOWS} (two hours of 5 s windows) is the default.")
        self.capacity = int(capacity)
        self._t = Ring(self.capacity)
        self._index = Ring(self.capacity, (len(FAULTS),), np.float32)
        self._provisional = Ring(self.capacity, (len(FAULTS),), np.float32)
        """Each part's index where it was blamed but not yet told apart (``"provisional"`` entries), NaN elsewhere."""
        self._ruled_out: set[str] = set()
        """Valve-side parts the latest window rules out (another blamed by the margin): no forecast for them."""
        self._seen: set[str] = set()
        """Parts that had a finite value in some window: the parts forecast (as ``score --json`` forecasts the parts
        with a finite value in the file)."""

    def __len__(self) -> int:
        return len(self._t)

    @property
    def nbytes(self) -> int:
        """Bytes of the history's arrays."""
        return int(self._t.nbytes + self._index.nbytes + self._provisional.nbytes)

    def update(self, start_s: float, degradation: Mapping[str, Mapping[str, Any]]) -> None:
        """Add one valid window: its start time, s, and ``{fault: {"value", "measured", "provisional"}}``
        (``measured`` absent reads True; a ``provisional`` value waits for a later window to confirm it,
        :func:`~hydrowatch.condition.attribution.confirmed`). Returns nothing."""
        row, waiting = (np.full(len(FAULTS), np.nan, dtype=np.float32) for _ in range(2))
        self._ruled_out = {f for f, e in degradation.items()
                           if not e.get("measured", True) and not e.get("provisional", False) and e["value"] == 0.0}
        for j, fault in enumerate(FAULTS):
            entry = degradation.get(fault)
            if entry is None or not np.isfinite(entry["value"]):
                continue
            if entry.get("provisional", False):
                waiting[j] = entry["value"]
                continue
            self._seen.add(fault)
            if entry.get("measured", True):
                row[j] = entry["value"]
        self._t.add(start_s)
        self._index.add(row)
        self._provisional.add(waiting)

    def history(self) -> tuple[np.ndarray, np.ndarray]:
        """The windows held in arrival order: start times (n,), s, and each part's history (n, len(FAULTS)), float64:
        its own index, and its provisional values that a later window confirmed."""
        index, waiting = self._index.rows().astype(np.float64), self._provisional.rows().astype(np.float64)
        return self._t.rows(), np.stack([confirmed(index[:, j], waiting[:, j]) for j in range(len(FAULTS))], axis=1)

    def get(self, *, max_gap_s: float = 3600.0, min_span_s: float = 300.0) -> dict[str, Forecast]:
        """Each part seen: :func:`~hydrowatch.condition.forecast.forecast_alert` of its history (the defaults and
        seed of ``score --json``), or none for a valve-side part the latest window rules out
        (:func:`~hydrowatch.condition.forecast.ruled_out_forecast`). Changes nothing; ``{}`` before any window."""
        t, index = self.history()
        return {f: ruled_out_forecast() if f in self._ruled_out
                else forecast_alert(t, index[:, j], max_gap_s=max_gap_s, min_span_s=min_span_s)
                for j, f in enumerate(FAULTS) if f in self._seen}
