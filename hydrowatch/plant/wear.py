"""A fault developing over time: its speed drop at 2 V along a :class:`DegradationPath`, and the machines wearing.

A path moves a fault's speed drop at 2 V from ``start_drop`` to ``final_drop`` over ``duration_s``, at a constant rate
(``linear``) or accelerating (``exp``); :func:`worn_parameters` turns the drop at a time into that unit's parameters
(the severity causing the drop is found on the unit itself) and :func:`path_state` into the label of the nearest named
level. :class:`Wear` moves the parameters of a simulator's wearing rows on a time grid: what
:class:`~hydrowatch.plant.fleet.Fleet` does for its specs and the plant service's ``--degrade``. Paths as text and as
recordings are :mod:`hydrowatch.plant.paths`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.plant.faults import FAULTS, fault_parameters, level_for_speed_drop, speed_drop_table, state_name
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SAMPLE_RATE_HZ

SHAPES: tuple[str, ...] = ("linear", "exp")
"""How a :class:`DegradationPath`'s speed drop moves from its start to its end value."""
EXP_GROWTH = float(np.log(10.0))
"""λ of the ``exp`` shape: drop = from + (to − from)·(e^{λx} − 1)/(e^λ − 1), x the elapsed fraction; the wear rate
at the end is e^λ = 10× the rate at the start (accelerating wear, as a seal or bearing that wears faster the more
it has worn)."""


@dataclass(frozen=True)
class DegradationPath:
    """A fault developing over time: its speed drop at 2 V moves from ``start_drop`` to ``final_drop``.

    Attributes
    ----------
    fault : str
        One of :data:`hydrowatch.plant.faults.FAULTS`.
    start_s : float
        Time the wear starts, s (fleet time); the drop is ``start_drop`` before it.
    duration_s : float
        Time from start to ``final_drop``, s (hours: e.g. 4·3600).
    final_drop : float, default 0.30
        Speed drop reached at the end and held afterwards, fraction (0.30 = the study's alert).
    start_drop : float, default 0.0
        Speed drop at and before ``start_s``, fraction (0 = as new).
    shape : {"linear", "exp"}, default "linear"
        ``linear``: constant wear rate; ``exp``: accelerating wear (:data:`EXP_GROWTH`).
    """

    fault: str
    start_s: float
    duration_s: float
    final_drop: float = 0.30
    start_drop: float = 0.0
    shape: str = "linear"

    def __post_init__(self) -> None:
        if self.fault not in FAULTS:
            raise ParameterError(f"degradation fault must be one of {list(FAULTS)}. Got {self.fault!r}.")
        if not (np.isfinite(self.start_s) and np.isfinite(self.duration_s) and self.duration_s > 0):
            raise ParameterError(
                f"degradation start_s must be finite and duration_s > 0. Got {self.start_s!r}, {self.duration_s!r}."
            )
        if not 0.0 < self.final_drop < 1.0:
            raise ParameterError(f"degradation final_drop must be in (0, 1). Got {self.final_drop!r}.")
        if not 0.0 <= self.start_drop < 1.0:
            raise ParameterError(f"degradation start_drop must be in [0, 1). Got {self.start_drop!r}.")
        if self.shape not in SHAPES:
            raise ParameterError(f"degradation shape must be one of {list(SHAPES)}. Got {self.shape!r}.")

    @property
    def top_drop(self) -> float:
        """Largest speed drop along the path, fraction."""
        return max(self.start_drop, self.final_drop)

    def drop_at(self, t: float | np.ndarray) -> float | np.ndarray:
        """Speed drop at time t, s (``start_drop`` before ``start_s``, ``final_drop`` after the end); float for a
        float, an array for an array."""
        x = np.clip((np.asarray(t, dtype=np.float64) - self.start_s) / self.duration_s, 0.0, 1.0)
        if self.shape == "exp":
            x = np.expm1(EXP_GROWTH * x) / np.expm1(EXP_GROWTH)
        drop = self.start_drop + (self.final_drop - self.start_drop) * x
        return float(drop) if drop.ndim == 0 else drop


def path_state(path: DegradationPath, drop: float) -> str:
    """Health label of a machine on ``path`` at speed drop ``drop``: the nearest named level, ``healthy`` below it."""
    return state_name(path.fault, level_for_speed_drop(drop)) if drop > 0 else "healthy"


def worn_parameters(path: DegradationPath, healthy: PlantParameters, table: tuple[np.ndarray, np.ndarray],
                    t: float) -> tuple[PlantParameters, float]:
    """Parameters of a machine on ``path`` at time ``t``, s, and its speed drop at 2 V then (fraction).

    ``table`` is :func:`~hydrowatch.plant.faults.speed_drop_table` of the path's fault up to ``path.top_drop`` on
    the machine's ``healthy`` parameters (drop → severity on that unit)."""
    drop = float(path.drop_at(t))
    severity = float(np.interp(max(drop, DROP_SEEN), *table)) if drop > 0 else float(unseen_severity(path, table, t))
    return (fault_parameters(healthy, path.fault, severity) if severity > 0 else healthy), drop


DROP_SEEN = 1e-5
"""Speed drop at 2 V (fraction) below which a part's wear counts as unseen there: a thousandth of a percent, far
below what a speed sensor resolves. A path's drop between 0 and this is read as this (:func:`unseen_severity`)."""
LEAD_FRACTION = 0.01
"""Share of a path's duration over which :func:`unseen_severity` measures the severity rate at its start."""


def unseen_severity(path: DegradationPath, table: tuple[np.ndarray, np.ndarray], t: float | np.ndarray
                    ) -> float | np.ndarray:
    """Severity of a path's part at times ``t`` before its speed drop at 2 V starts to move: the part wearing
    *unseen* from new, at the rate at which the path goes on.

    Some parts hardly lower the speed at 2 V until they have worn some way: a relief spring on a unit whose pump is
    at its limit at 2 V (the supply pressure there below the cracking pressure) leaves its relief shut at 2 V until
    the cracking pressure has fallen by 2–23 % (about 1 unit in 90 of :func:`~hydrowatch.plant.population.
    random_unit`: 19 of 1660 drawn on seeds 2000, 2001, 3021 and 3022, every one with its pump at its limit in half
    or more of a noise commissioning of its true parameters). The severity of the first drop seen,
    ``s0 = severity(DROP_SEEN)``, is then well above 0, and a path from index 0 jumped there at its start: the
    cracking pressure falling up to 23 % in an instant, which no spring wearing from new does. Here the part
    reaches ``s0`` at ``start_s`` from 0, at the severity rate r of the path's first :data:`LEAD_FRACTION` of its
    duration, so that the severity and its rate go on without a step: ``max(0, s0 − r·(start_s − t))`` before
    ``start_s`` (elsewhere s0 is 1e-5–3e-4 of the fault's scale on the default unit, and the lead a few seconds). The
    drop, the index and the labels are the path's, unchanged (0 before ``start_s``); a path whose ``start_drop`` is
    above 0 starts there and has none of this."""
    t = np.asarray(t, dtype=np.float64)
    if path.start_drop > 0.0:
        severity = np.zeros(t.shape)
    else:
        s0 = float(np.interp(DROP_SEEN, *table))
        step = LEAD_FRACTION * path.duration_s
        rate = max(float(np.interp(max(float(path.drop_at(path.start_s + step)), DROP_SEEN), *table)) - s0, 0.0) / step
        lead = np.maximum(0.0, path.start_s - t)
        severity = np.clip(s0 - rate * lead, 0.0, s0) if rate > 0 else np.where(lead > 0, 0.0, s0)
    return float(severity) if severity.ndim == 0 else severity


class Wear:
    """Machines of one :class:`~hydrowatch.plant.PlantSimulator` whose fault follows a path: their parameters at a
    time, moved on a grid of ``update_seconds`` (what :class:`Fleet` does for its specs; the plant service's
    ``--degrade``).

    Parameters
    ----------
    paths : mapping of int to DegradationPath
        Simulator row → its path.
    healthy : mapping of int to PlantParameters
        Simulator row → its parameters as new (the drops are relative to its own speed).
    update_seconds : float, default 1.0
        How often the parameters move, s of simulated time.
    """

    def __init__(self, paths: Mapping[int, DegradationPath], healthy: Mapping[int, PlantParameters],
                 update_seconds: float = 1.0) -> None:
        if not (np.isfinite(update_seconds) and update_seconds > 0):
            raise ParameterError(f"update_seconds must be positive. Got {update_seconds!r}.")
        self.paths, self.healthy, self.update_seconds = dict(paths), dict(healthy), float(update_seconds)
        self._tables = {i: speed_drop_table(p.fault, p.top_drop, self.healthy[i]) for i, p in self.paths.items()}
        self._next_t = -np.inf

    def due(self, t: float) -> list[tuple[int, PlantParameters]]:
        """The rows whose parameters move at time ``t``, s, with their parameters then (none between grid
        points)."""
        half_sample = 0.5 / SAMPLE_RATE_HZ  # a grid point reached by summed sample times is reached
        if t < self._next_t - half_sample:
            return []
        self._next_t = (np.floor((t + half_sample) / self.update_seconds) + 1.0) * self.update_seconds
        return [(i, worn_parameters(p, self.healthy[i], self._tables[i], t)[0]) for i, p in self.paths.items()]

    def states(self, t: float, labels: Sequence[str]) -> list[str]:
        """``labels`` with each wearing row's label at time ``t``, s (:func:`path_state`)."""
        out = list(labels)
        for i, p in self.paths.items():
            out[i] = path_state(p, float(p.drop_at(t)))
        return out
