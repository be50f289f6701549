"""One machine's degradation index online (river style): :class:`DegradationStream`, the scorer's per-machine
state, equal window by window to :func:`~hydrowatch.condition.degradation.features_degradation` of the machine's
consecutive windows (issue 15)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from hydrowatch.condition import parity
from hydrowatch.condition.attribution import ATTRIBUTION_WINDOWS, NOMINAL_VALVE, pool_misfit, say_of
from hydrowatch.condition.brake import brake_factor
from hydrowatch.condition.capacity import PUMP_LIMIT, PUMP_LIMITED, MachineCapacity, capacity_error
from hydrowatch.condition.degradation import DETERMINED_STEP, window_degradation
from hydrowatch.condition.estimates import MOVING_LOAD, ParityEstimates
from hydrowatch.condition.features import ConditionFeatures
from hydrowatch.condition.ring import Ring
from hydrowatch.condition.unit_checks import relief_barely_seen


class DegradationStream:
    """One machine's degradation index online (river style): :meth:`update` with each valid window's free fits
    returns that window's index, which equals :func:`~.degradation.features_degradation` of the machine's
    consecutive windows: the valve-side part is the hypothesis with the smallest :func:`pool_misfit` over the last
    ``pool`` valid windows (a ring of ``pool`` × 4 × 3 floats: each hypothesis's ŝ, MSE and c; one of ``pool``
    nominal MSEs), the rest is the window's own; where the unit's pump capacity is not known (``capacity_known_``
    false), also a ring of ``pool`` × 3 floats (pump_leak's ŝ, Pc / P̄s, determined) and the machine's
    :class:`~hydrowatch.condition.capacity.MachineCapacity` (101 counts).

    Parameters
    ----------
    features : ConditionFeatures
        Fitted (or commissioned): the unit's nominal parameters, window and relations.
    pool : int, default :data:`ATTRIBUTION_WINDOWS`
    """

    def __init__(self, features: ConditionFeatures, pool: int = ATTRIBUTION_WINDOWS) -> None:
        self.features, self.pool = features, pool
        self._fits = Ring(pool, (len(parity.VALVE_HYPOTHESES), 3))
        """Each valid window's ŝ, MSE and c per valve hypothesis."""
        self._context = Ring(pool, (2,))
        """Each valid window's valve MSE at nominal and share at the pump's limit (NaN: not in the estimates)."""
        self._loads = Ring(pool)
        known = getattr(features, "capacity_known_", True)
        self._capacity = None if known else MachineCapacity()
        self._held = -1
        """The valve-side part the last pool told apart while worn (attribution.contenders; −1: none)."""
        self._limits = Ring(1 if known else pool, (3,))
        """Each valid window's pump_leak ŝ, Pc / P̄s and whether its fit determines pump_leak (1/0)."""

    def update(self, severity: Mapping[str, float], mse: Mapping[str, float],
               curvature: Mapping[str, float]) -> dict[str, dict[str, Any]]:
        """The index of a valid window from its free fits (one window's values of
        :class:`~hydrowatch.condition.estimates.ParityEstimates`): ``{fault: {"value", "ci95", "measured"}}``, finite
        only (``measured``: :meth:`Degradation.window`)."""
        f = self.features
        blamed, excess, capacity, medians = np.array([-1]), None, np.zeros(1), None
        if "valve" in f.relations_:
            self._fits.add([[a[h] for a in (severity, mse, curvature)] for h in parity.VALVE_HYPOTHESES])
            self._context.add([mse.get(NOMINAL_VALVE, np.nan), severity.get(PUMP_LIMITED, np.nan)])
            ring, context = np.moveaxis(self._fits.rows(), 0, -1), self._context.rows()  # (hypothesis, ŝ/MSE/c, window)
            misfit = pool_misfit(ring[:, 0], ring[:, 1], ring[:, 2], context[None, :, 0], say_of(context[None, :, 1]))
            blamed, excess = np.array([int(np.argmin(misfit))]), (misfit - misfit.min())[None, :]
            medians = {h: np.array([np.nanmedian(ring[j, 0])]) for j, h in enumerate(parity.VALVE_HYPOTHESES)}
            if self._capacity is not None:  # θ0's capacity not determined: the history's (capacity module)
                self._limits.add([severity["pump_leak"], severity.get(PUMP_LIMIT, np.nan),
                                  float(curvature["pump_leak"] * DETERMINED_STEP**2 >= mse["pump_leak"])])
                rows = self._limits.rows()
                capacity = np.array([self._capacity.add(capacity_error(rows[:, 0], rows[:, 1], rows[:, 2] > 0.5))])
        brake = np.ones(1)
        if "load" in f.relations_:
            self._loads.add(float(severity.get(MOVING_LOAD, severity["load"])))
            brake = np.array([brake_factor(self._loads.rows())])  # the ring holds the pool's last windows
        one = ParityEstimates(*({k: np.array([v]) for k, v in part.items()} for part in (severity, mse, curvature)))
        found = window_degradation(one, np.ones(1, dtype=bool), f.nominal_, (f.window - 1) // parity.BLOCK,
                                   f.relations_, self.pool, blamed, excess, brake, capacity,
                                   capacity_known=self._capacity is None, pool_severity=medians, held=self._held,
                                   relief_barely_seen=relief_barely_seen(getattr(f, "pump_at_limit_", None)))
        self._held = found.held
        return found.window(0, measured=True)
