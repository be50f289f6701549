"""The fleet's forecasts online: each machine's index history and a cheap schedule (issue 15).

:class:`FleetForecasts` keeps one :class:`~hydrowatch.condition.forecast_stream.ForecastStream` per machine, fed
with the degradation index of every window the scorer judges, and forecasts a machine every ``every`` of its
windows with an index, at a phase of its own (CRC-32 of its name), so that a fleet started in one instant does not
forecast every machine in the same update.

**Cost.** One forecast is :func:`~hydrowatch.condition.forecast.forecast_alert` per part: about 12 ms for a part
that wears (its 200-resample bootstrap) and 2 ms for one too flat to forecast, on 2 h of history (one core); a
machine with six parts costs 12–22 ms per forecast (docs/degradation.md, "Online"). Every
:data:`FORECAST_EVERY` = 60 windows (5 min) that is 0.04–0.07 of a core for 1000 machines; every 12 windows
(1 min), 0.2–0.4. Wear that reaches the alert in tens of minutes or more is not served better by fresher forecasts
than every five minutes.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass

from hydrowatch.condition.forecast import Forecast
from hydrowatch.condition.forecast_stream import HISTORY_WINDOWS, ForecastStream
from hydrowatch.errors import ParameterError
from hydrowatch.training.chunks import WindowVerdict

FORECAST_EVERY = 60
"""Default windows with an index between two forecasts of a machine: 5 minutes of 5 s windows."""


@dataclass(frozen=True)
class MachineForecast:
    """The forecast of one machine's parts after one of its windows.

    Attributes
    ----------
    machine : str
        ``fleet/machine``.
    start_s : float
        Start of the machine's last window with an index, s: what ``alert_in_s`` counts from.
    parts : dict of str to Forecast
        Each part seen (:meth:`ForecastStream.get`).
    history_windows : int
        Windows of history held.
    """

    machine: str
    start_s: float
    parts: dict[str, Forecast]
    history_windows: int


class FleetForecasts:
    """Forecasts of many machines from the verdicts' degradation indices, on a schedule (module docstring).

    Parameters
    ----------
    every : int, default :data:`FORECAST_EVERY`
        Windows with an index between two forecasts of a machine (1: after each).
    capacity : int, default :data:`~hydrowatch.condition.forecast_stream.HISTORY_WINDOWS`
        Windows of history per machine.
    stagger : bool, default True
        Each machine's forecasts fall at a phase of its own in ``every`` (from its name); False: after its
        ``every``-th, ``2·every``-th … window.
    """

    def __init__(self, *, every: int = FORECAST_EVERY, capacity: int = HISTORY_WINDOWS, stagger: bool = True) -> None:
        if int(every) != every or every < 1:
            raise ParameterError(f"every must be an integer >= 1 (windows between forecasts). Got {every!r}; "
                                 f"{FORECAST_EVERY} is the default.")
        self.every, self.capacity, self.stagger = int(every), int(capacity), bool(stagger)
        self._streams: dict[str, ForecastStream] = {}
        self._count: dict[str, int] = {}

    @property
    def machines(self) -> list[str]:
        """Machines with a history."""
        return list(self._streams)

    def stream(self, machine: str) -> ForecastStream | None:
        """The machine's history, None before its first window with an index."""
        return self._streams.get(machine)

    def update(self, verdicts: Sequence[WindowVerdict]) -> list[MachineForecast]:
        """Add the windows' indices (windows without one are skipped, as ``score``'s forecast skips them) and return
        the forecasts that fall due, in order (none for a machine whose windows index no part: sensors that test no
        relation)."""
        out = []
        for item in verdicts:
            if item.degradation is None:
                continue
            stream = self._streams.get(item.machine)
            if stream is None:
                stream = self._streams[item.machine] = ForecastStream(self.capacity)
                self._count[item.machine] = zlib.crc32(item.machine.encode()) % self.every if self.stagger else 0
            stream.update(item.start_s, item.degradation)
            self._count[item.machine] += 1
            if self._count[item.machine] % self.every == 0 and (parts := stream.get()):  # none: no part indexed
                out.append(MachineForecast(item.machine, item.start_s, parts, len(stream)))
        return out
