"""A relief that the commissioning recording left undetermined: the load states follow each window's relief.

A load fault raises the load pressure P̂L towards the supply pressure, which the relief holds near its
cracking pressure Pc (plant-model.md Eqs. 1–5). So the load states test the relief where a healthy
recording seldom does: the valve relation's flow Kq·x·√(Ps − P̂L) at a high P̂L depends on Pc, and the
load fault's levels (the brake torque that drops the speed at 2 V by 15 % or 30 %) scale with it
(:func:`~hydrowatch.plant.faults.level_severity`: ×0.76 at 0.8 Pc, ×1.24 at 1.2 Pc).

A working duty cycle of 0.5–3.5 V often leaves Pc undetermined: the valve gain and the relief trade
along a ridge, the recording's halves disagree, and whichever supply commissioning chooses (the
trained unit's, or the whole recording's fit) can be 13–31 % off the unit's relief (seed 2037,
7 states: four of 19 units; docs/unseen-units.md). Each such unit read its load alerts ``unknown``:
the valve relation misfit 28 × its floor at a load alert, and the brake torque lay between the
commissioned warning and alert levels.

On such a unit (``ConditionFeatures.relief_spread_`` > 0, set by commissioning), every load state:

- lets the relief move within e^(±spread) of the commissioned Pc in the valve relation (the
  ``relief_spring`` severity s, Pc·(1 − s), within :func:`relief_range`);
- scales its load box, per window, by g(ŝ) = level(Pc·(1 − ŝ)) / level(Pc), ŝ the window's own free
  relief estimate clipped to that range (:class:`LoadScale`): the brake torque is judged against the
  levels of the relief the window shows.

No other state changes: an unseen valve-side fault (a worn relief spring) still reads ``unknown``, since
its brake torque stays in the healthy box and no load state's load box holds it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from hydrowatch.plant.faults import level_severity
from hydrowatch.plant.parameters import PlantParameters

GRID = 13
"""Points of :class:`LoadScale`'s table over the relief range (linear interpolation between them)."""


def relief_range(spread: float) -> tuple[float, float]:
    """``relief_spring`` severities of a cracking pressure within e^(±``spread``) of the commissioned one.

    Severity s means Pc·(1 − s): the range is (1 − e^spread, 1 − e^−spread), e.g. (−0.35, 0.26) for 0.3.
    """
    return float(1.0 - np.exp(spread)), float(1.0 - np.exp(-spread))


def free_relief(box: Mapping[str, tuple[float, float]], spread: float) -> dict[str, tuple[float, float]]:
    """``box`` (fault → severity range) with the relief allowed anywhere in :func:`relief_range` as well."""
    lo, hi = relief_range(spread)
    a, b = box["relief_spring"]
    return {**box, "relief_spring": (min(a, lo), max(b, hi))}


class LoadScale:
    """g(s) = level_severity(load, alert) at Pc·(1 − s) over that at Pc, for relief severities s in the range.

    The warning level scales the same way within 0.1 % (default unit, Pc × 0.8–1.3), so one table serves
    both levels.

    Parameters
    ----------
    p : PlantParameters
        The commissioned unit.
    spread : float
        Log-scale half-width of the relief's range (:func:`relief_range`), > 0.
    """

    def __init__(self, p: PlantParameters, spread: float) -> None:
        lo, hi = relief_range(spread)
        self.grid = np.linspace(lo, hi, GRID)
        base = level_severity("load", "alert", p)
        self.values = np.array([level_severity("load", "alert", p.replace(Pc=p.Pc * (1.0 - s))) / base
                                for s in self.grid])

    def __call__(self, relief: np.ndarray) -> np.ndarray:
        """g at the windows' relief severities (m,), clipped to the range."""
        return np.interp(np.clip(relief, self.grid[0], self.grid[-1]), self.grid, self.values)


    def span(self) -> tuple[float, float]:
        """Smallest and largest g over the range."""
        return float(self.values.min()), float(self.values.max())


def determined(relief: np.ndarray, curvature: np.ndarray, limits: tuple[float, float]) -> np.ndarray:
    """Windows whose own relief estimate means something: a positive curvature, off the search limits.

    Where the valve relation does not depend on the relief (the supply pump-limited, or a hold far below the
    relief) its fit stops on a search limit with zero curvature (seed 2037, unit 11: one load-warning window at
    s = −0.5, g 1.37, against 0.05 in the others).
    """
    lo, hi = limits  # the relief fit's search range (parity.SEVERITY_LIMITS)
    return (curvature > 0.0) & (relief > lo) & (relief < hi)


def window_factors(scale: LoadScale, relief: np.ndarray, curvature: np.ndarray, limits: tuple[float, float]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per window: the load box's lower and upper factor, and the factor of its severity's frame (0: none).

    A window that :func:`determined` its relief scales the load box by g(ŝ) and its severity by 1/g(ŝ); one that
    did not lets the load range stretch over every g of the range and gives no frame (its severity then carries
    no weight in a pool, :meth:`~hydrowatch.condition.features.ConditionFeatures.transform_evidence`).
    """
    g = scale(relief)
    ok = determined(relief, curvature, limits)
    low, high = scale.span()
    return np.where(ok, g, low), np.where(ok, g, high), np.where(ok, g, 0.0)


def scaled_load_box(box: Mapping[str, tuple[float, float]], low: np.ndarray, high: np.ndarray
                    ) -> dict[str, tuple[float, float]]:
    """``box`` with its load range (lo, hi) per window (lo·``low``, hi·``high``), arrays (m,)."""
    lo, hi = box["load"]
    return {**box, "load": (lo * low, hi * high)}  # type: ignore[dict-item]
