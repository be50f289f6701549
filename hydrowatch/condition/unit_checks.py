"""What a unit's healthy recording tells beside its fit (:mod:`hydrowatch.condition.unit`): how well a fit explains
windows it was not fitted to (:func:`valve_error`), the most flow the recording drew from the pump
(:func:`drawn_flow`), both for commissioning's choices
(:func:`hydrowatch.condition.commission.identify_for_commissioning`), and whether it ever drove the pump to its limit
(:func:`pump_at_limit_share`, what commissioning reports).
Split from ``unit.py`` (one module, one job).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hydrowatch.condition import parity
from hydrowatch.condition.unit import _Signals, _valid_signals, _valve_relation
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


def _supply(s: _Signals, p: PlantParameters) -> tuple[np.ndarray, np.ndarray]:
    """Supply pressure Ps [Pa] integrated at ``p`` (:func:`parity.supply_and_valve_flow`) over the signals' windows,
    and the total supply-side leakage per window, m³/(s·Pa)."""
    pl = parity.load_pressure(s.speed, s.torque, p, leak=s.leak)
    leakage = (p.Cp + p.Cpl + p.Cvl) * s.leak.reshape(-1)
    ps, _ = parity.supply_and_valve_flow(p.Kq * parity.spool_position(s.voltage, p), pl, p, leakage,
                                         np.full(s.flow.shape[0], p.Pc))
    return ps, leakage


def drawn_flow(windows: np.ndarray, p: PlantParameters, sensors: Sequence[str] = SENSORS,
               viscosity_coefficient: float = 0.04) -> float:
    """The most flow the recording drew from the pump, m³/s: the :data:`DRAWN_QUANTILE` of block means of
    |Q| + C·Ps (Eqs. 1, 5: the pump delivers the valve flow, its own and the valve's leakage and the relief's share,
    so Dp·ωp is at least this), with Ps from the supply line integrated at ``p`` (:func:`parity.supply_and_valve_flow`).

    A healthy recording that never drives the pump to its limit leaves Dp to its prior; this is what it does tell:
    a lower bound on the pump's capacity (:func:`hydrowatch.condition.commission.identify_for_commissioning`).
    """
    s = _valid_signals(windows, sensors, viscosity_coefficient, "the pump's draw")
    ps, leakage = _supply(s, p)
    return float(np.quantile(parity.block_means(np.abs(s.flow) + leakage[:, None] * ps), DRAWN_QUANTILE))


PUMP_LIMIT_SHARE = 0.002
"""Smallest share of a recording's samples at the pump's limit (:func:`pump_at_limit_share`, at the identified
parameters) for which the recording counts as having determined the pump's capacity Dp·ωp. Measured on 24 units
(seeds 2054, 2055 and 2072 of ``benchmarks/bench_degradation.py``, 300 s of filtered noise 0–4 V each): every share
from 0.001 to 0.57 left the identified capacity within 0.2–6.5 % of the unit's; the eight units at 0 (pumps that
outdeliver the valve: on two of them 30 s of steps to full stroke did not reach the limit either) were identified at
0.75–1.14 ×. 0.0005 until 2026-12-02: on seeds 2076 and 2077 three recordings whose unit never reached the limit
(0 samples under its true parameters) read 0.0007–0.001 at fits whose capacity was too low (0.83–0.94 ×) and so
touched it; every share from 0.002 up (18 units of seeds 2074–2077) had the capacity within 0–2.1 %."""


RELIEF_SHUT_SHARE = 0.3
"""Share of a recording's samples at the pump's limit (:func:`pump_at_limit_share`: the relief shut) from which the
recording barely sees the relief's gain Kr. First 0.5, measured after the fresh runs of seeds 2055 and 2073 (16 units,
300 s of filtered noise 0–4 V): the three units at 0.52–0.78 had Kr identified at 0.61–0.76 × the unit's and read a
worn relief spring as the coil in up to 20 % of its windows (docs/degradation.md, "Limits"); the units at 0–0.23 had
Kr within 0.81–1.15 ×. 0.3 since stop 60: on the 24 regular units of seeds 2098–2103 the two at 0.37 and 0.38 had Kr
at 0.86 and 0.79 × (the 22 at 0–0.20: 0.85–1.15 ×; the 56 flagged units at 0.50–0.71: 0.55–0.97 ×, median 0.75), and
on the one at 0.38 (2102 unit 0) the coil was told apart during the relief's early wear by 7–17 nats and read up to
0.26 in 2.7 % of its relief path's windows; barely seen, none (docs/degradation.md, "A relief barely seen")."""


def relief_barely_seen(share: float | None) -> bool:
    """Whether a commissioning recording with ``share`` of its samples at the pump's limit barely saw the relief's
    gain (:data:`RELIEF_SHUT_SHARE`; None: not known, as in bundles saved before 2026-12-03: False)."""
    return share is not None and share >= RELIEF_SHUT_SHARE


def pump_at_limit_share(windows: np.ndarray, p: PlantParameters, sensors: Sequence[str] = SENSORS,
                        viscosity_coefficient: float = 0.04) -> float:
    """Share of the valid samples at which the pump of a unit with parameters ``p`` delivers all it can: the supply
    pressure integrated at ``p`` (:func:`parity.supply_and_valve_flow`) below the relief's cracking pressure.

    Where the relief is open, Ps ≈ Pc + (Dp·ωp − QL)/Kr: the capacity trades with Pc and Kr, and the valve relation
    does not determine it, although its Gauss-Newton posterior may look narrow (seed 2055, units 0 and 5, 300 s of
    filtered noise 0–4 V: posterior sd of ln Dp 0.044–0.058, identified capacity 0.75–0.78 × the unit's, 0 of the
    samples at the limit under either). Below :data:`PUMP_LIMIT_SHARE` the capacity is not determined by the
    recording (:func:`~hydrowatch.condition.commission.commission` reports it).
    """
    s = _valid_signals(windows, sensors, viscosity_coefficient, "the pump's limit")
    ps, _ = _supply(s, p)
    return float(np.mean(ps < p.Pc))


def capacity_determined(windows: np.ndarray, p: PlantParameters, sensors: Sequence[str] = SENSORS,
                        viscosity_coefficient: float = 0.04) -> tuple[bool, float | None]:
    """Whether a healthy recording (valid windows) determined the pump's capacity of its identified parameters ``p``
    (:func:`pump_at_limit_share` ≥ :data:`PUMP_LIMIT_SHARE`), and that share; (True, None) where the sensors cannot
    tell (flow, speed and torque are needed). Where not, pump_leak's degradation index waits for the machine's history
    (:mod:`hydrowatch.condition.capacity`)."""
    if not {"flow", "speed", "torque"} <= set(sensors):
        return True, None
    share = pump_at_limit_share(windows, p, sensors, viscosity_coefficient)
    return share >= PUMP_LIMIT_SHARE, share
