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
blamed before the pool could tell it apart (float32, kept until a later window confirms it), and the index the relief
spring and the coil share where a unit whose relief was barely seen cannot tell them apart (float32, one per window:
:mod:`~hydrowatch.condition.degradation_series`). With the default :data:`HISTORY_WINDOWS` (1440: two hours of 5 s
windows) that is 1440 × (8 + 2 × 6 × 4 + 4) B = 87 kB per machine; on a unit whose commissioning left the pump's
capacity undetermined, also pump_leak's reading per window (ŝ, Pc / P̄s, brake factor and q̂, float64, 46 kB), so
that a forecast reads its history on the latest capacity (:mod:`~hydrowatch.condition.index_table`). A
forecast rests on at most that history, so it reaches at most :data:`~hydrowatch.condition.forecast.HORIZON_FACTOR`
× its span ahead (20 h for two hours); a part wearing over days needs a longer ``capacity``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from hydrowatch.condition.attribution import confirmed
from hydrowatch.condition.degradation_series import SHARED_PAIR
from hydrowatch.condition.forecast import Forecast, forecast_alert, ruled_out_forecast
from hydrowatch.condition.index_table import LEAK, reread_leak
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
        self._shared = Ring(self.capacity, (), np.float32)
        """The index :data:`~.degradation_series.SHARED_PAIR` shared in each window, NaN where none."""
        self._untold: dict[str, str] = {}
        """Each part of the pair the latest window that reads either shares its index with, and the other."""
        self._ruled_out: set[str] = set()
        """Valve-side parts the latest window rules out (another blamed by the margin): no forecast for them; for the
        pair, once it shared an index, the latest window that reads either (Degradation.ruled_out)."""
        self._paired = False
        """Whether a window of this history shared the pair's index (Degradation.shared not None)."""
        self._seen: set[str] = set()
        """Parts that had a finite value in some window: the parts forecast (as ``score --json`` forecasts the parts
        with a finite value in the file)."""
        self._readings: Ring | None = None
        """pump_leak's reading per window (ŝ, Pc / P̄s, brake factor, q̂; NaN where none): made at the first window
        that carries one (a unit whose commissioning left the pump's capacity undetermined)."""
        self._nominal: Any = None
        """θ0 of the readings held; a reading on another θ0 starts the readings again, so the windows before it are
        kept as read (the scorer starts its histories again on a model switch; a stream fed across one does this)."""

    def __len__(self) -> int:
        return len(self._t)

    @property
    def nbytes(self) -> int:
        """Bytes of the history's arrays."""
        readings = 0 if self._readings is None else self._readings.nbytes
        return int(self._t.nbytes + self._index.nbytes + self._provisional.nbytes + self._shared.nbytes + readings)

    def update(self, start_s: float, degradation: Mapping[str, Mapping[str, Any]]) -> None:
        """Add one valid window: its start time, s, and ``{fault: {"value", "measured", "provisional"}}``
        (``measured`` absent reads True; a ``provisional`` value waits for a later window to confirm it,
        :func:`~hydrowatch.condition.attribution.confirmed`; one naming ``untold_from`` carries the index the pair
        shares, ``"pair"``, :meth:`~.degradation_series.Degradation.window`). Returns nothing."""
        row, waiting = (np.full(len(FAULTS), np.nan, dtype=np.float32) for _ in range(2))
        shared = {f: e for f, e in degradation.items() if e.get("untold_from")}
        says = any(f in degradation and np.isfinite(degradation[f]["value"]) for f in SHARED_PAIR)
        if says:  # says which
            self._untold = {g: h for f, e in shared.items() for g, h in ((f, e["untold_from"]), (e["untold_from"], f))}
        self._seen.update(self._untold)
        pair = set() if says or not self._paired else self._ruled_out & set(SHARED_PAIR)  # a window silent on the pair
        self._ruled_out = ({f for f, e in degradation.items() if not e.get("measured", True)
                            and not e.get("provisional", False) and e["value"] == 0.0} | pair) - set(self._untold)
        self._paired = self._paired or bool(shared)
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
        self._add_reading((degradation.get(LEAK) or {}).get("reading"))
        self._t.add(start_s)
        self._index.add(row)
        self._provisional.add(waiting)
        self._shared.add(np.float32(next(iter(shared.values()))["pair"]) if shared else np.float32(np.nan))

    def _add_reading(self, reading: Mapping[str, Any] | None) -> None:
        """Keep the window's pump_leak reading (None: none), before the window joins the history."""
        if reading is not None and self._nominal is not None and reading["nominal"] != self._nominal:
            self._readings = None  # read on another θ0: the windows before keep their values as read
        if reading is None and self._readings is None:
            return
        if self._readings is None:  # the first (on this θ0): the windows before it have none
            self._readings = Ring(self.capacity, (4,))
            for _ in range(len(self._t)):
                self._readings.add(np.nan)
        if reading is None:
            self._readings.add(np.nan)
            return
        self._nominal = reading["nominal"]
        self._readings.add([reading[k] for k in ("severity", "limit_ratio", "brake", "capacity")])

    def history(self) -> tuple[np.ndarray, np.ndarray]:
        """The windows held in arrival order: start times (n,), s, and each part's history (n, len(FAULTS)), float64:
        its own index, its provisional values that a later window confirmed, for the pair the index it shared
        where it has none of its own, and pump_leak re-read on the latest capacity (as
        :meth:`~.degradation_series.Degradation.history`)."""
        index, waiting = self._index.rows().astype(np.float64), self._provisional.rows().astype(np.float64)
        pair = self._shared.rows().astype(np.float64)
        out = np.stack([confirmed(index[:, j], waiting[:, j]) for j in range(len(FAULTS))], axis=1)
        for f in SHARED_PAIR:
            j = FAULTS.index(f)
            out[:, j] = np.where(np.isnan(out[:, j]), pair, out[:, j])
        if self._readings is not None:  # pump_leak re-read on the latest capacity (index_table)
            j = FAULTS.index(LEAK)
            severity, ratio, brake, capacity = self._readings.rows().T
            out[:, j] = reread_leak(out[:, j], severity, ratio, brake, capacity, self._nominal)
        return self._t.rows(), out

    def get(self, *, max_gap_s: float = 3600.0, min_span_s: float = 300.0) -> dict[str, Forecast]:
        """Each part seen: :func:`~hydrowatch.condition.forecast.forecast_alert` of its history (the defaults and
        seed of ``score --json``), or none for a valve-side part the latest window rules out
        (:func:`~hydrowatch.condition.forecast.ruled_out_forecast`). Changes nothing; ``{}`` before any window."""
        t, index = self.history()
        return {f: ruled_out_forecast() if f in self._ruled_out
                else replace(forecast_alert(t, index[:, j], max_gap_s=max_gap_s, min_span_s=min_span_s),
                             untold_from=self._untold.get(f))
                for j, f in enumerate(FAULTS) if f in self._seen}
