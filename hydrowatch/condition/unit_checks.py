"""What a unit's healthy recording tells beside its fit (:mod:`hydrowatch.condition.unit`): how well a fit explains
windows it was not fitted to (:func:`valve_error`) and the most flow the recording drew from the pump
(:func:`drawn_flow`), both for commissioning's choices
(:func:`hydrowatch.condition.commission.identify_for_commissioning`).
Split from ``unit.py`` (one module, one job).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hydrowatch.condition import parity
from hydrowatch.condition.unit import _valid_signals, _valve_relation
from hydrowatch.errors import DataError
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SENSORS


def valve_error(windows: np.ndarray, p: PlantParameters, sensors: Sequence[str] = SENSORS,
                viscosity_coefficient: float = 0.04) -> np.ndarray:
    """Mean squared block residual of the valve relation (Eqs. 1–5) at parameters ``p`` on each valid raw healthy
    window, (L/min)², shape (windows,): how well a unit fit explains windows it was not fitted to (held-out error,
    commissioning's choice of supply, :func:`hydrowatch.condition.commission.identify_for_commissioning`).

    Raises
    ------
    DataError
        With fewer than 2 valid windows, or without the flow, speed and torque the relation needs.
    """
    missing = {"flow", "speed", "torque"} - set(sensors)
    if missing:
        raise DataError(f"the valve relation needs flow, speed and torque. Missing: {', '.join(sorted(missing))}.")
    residual, _ = _valve_relation(_valid_signals(windows, sensors, viscosity_coefficient, "a held-out error"))
    return np.asarray(np.mean(residual(p) ** 2, axis=1), dtype=np.float64)


DRAWN_QUANTILE = 0.995
"""Quantile of the block-mean pump draw taken as the most the recording drew from the pump (:func:`drawn_flow`):
robust to the sensor noise on one block, which the maximum is not."""


def drawn_flow(windows: np.ndarray, p: PlantParameters, sensors: Sequence[str] = SENSORS,
               viscosity_coefficient: float = 0.04) -> float:
    """The most flow the recording drew from the pump, m³/s: the :data:`DRAWN_QUANTILE` of block means of
    |Q| + C·Ps (Eqs. 1, 5: the pump delivers the valve flow, its own and the valve's leakage and the relief's share,
    so Dp·ωp is at least this), with Ps from the supply line integrated at ``p`` (:func:`parity.supply_and_valve_flow`).

    A healthy recording that never drives the pump to its limit leaves Dp to its prior; this is what it does tell:
    a lower bound on the pump's capacity (:func:`hydrowatch.condition.commission.identify_for_commissioning`).
    """
    s = _valid_signals(windows, sensors, viscosity_coefficient, "the pump's draw")
    pl = parity.load_pressure(s.speed, s.torque, p, leak=s.leak)
    leakage = (p.Cp + p.Cpl + p.Cvl) * s.leak.reshape(-1)
    ps, _ = parity.supply_and_valve_flow(p.Kq * parity.spool_position(s.voltage, p), pl, p, leakage,
                                         np.full(s.flow.shape[0], p.Pc))
    return float(np.quantile(parity.block_means(np.abs(s.flow) + leakage[:, None] * ps), DRAWN_QUANTILE))
