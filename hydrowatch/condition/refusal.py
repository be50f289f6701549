"""Commissioning's refusals: a recording too short, a command that never loads the parts, a fault already present.

The unit keeps the fleet model when its healthy recording cannot commission it (:mod:`hydrowatch.condition.commission`,
whose docstring explains each refusal and where its limits were measured).
"""

from __future__ import annotations

import numpy as np

from hydrowatch.condition import layout as L
from hydrowatch.condition import parity
from hydrowatch.condition.features import ConditionFeatures
from hydrowatch.condition.unit import UnitFit
from hydrowatch.errors import DataError
from hydrowatch.plant.faults import level_severity
from hydrowatch.plant.parameters import PlantParameters


class CommissioningError(DataError):
    """The healthy recording cannot commission the unit; the message says what is missing."""


MIN_SECONDS = 300.0
"""Healthy operation needed, s of valid windows (the issue's ≥ 5 minutes)."""
MIN_COMMAND_SPREAD = 1.0
"""Smallest 5–95 % spread of the valve command, V."""
MOVING_SPEED = 2.0
"""Gearbox speed, rad/s, above which the motor counts as turning (a healthy 0.5–3.5 V duty cycle: below it 5 % of
the time; a motor_leak warning on it: 10–20 %)."""
MIN_MOVING = 0.5
"""Smallest share of samples with the motor turning."""
FAULT_FRACTION: dict[str, float] = {"load": 0.6, "motor_leak": 0.6, "pump_leak": 1.0}
"""Share of the way from the trained unit to a fault's warning level at which a parameter reads as that fault.

pump_leak's is the warning level itself: on a working duty cycle the pump leakage Cp absorbs what the recording does
not separate from it (the pump's displacement and speed, ±20 % each between units), so a healthy unit whose pump
delivers less than the trained one's reads as a pump leak. Measured with the first unit's 7-state model on 300 s
duty cycles (``implied_severities`` / warning, healthy units): development populations seed 7 and 8, 38 units, up to
0.45; seed 2028, 0.65–0.73 on 3 of 19 (refused at 0.6); the same units with a pump_leak warning already present read
0.62–1.61 on 30 of 31 units whose supply was kept, ≤ 0.23 on 6 of 7 whose supply was identified (the fit gave the
leak to a smaller pump): the ranges meet, so a warning already present is refused on 11 of 38 units instead of 31
(docs/unseen-units.md, "Refusing a unit for a pump leak")."""
def implied_severities(fleet: PlantParameters, unit: PlantParameters) -> dict[str, float]:
    """Severity of each fault that a parameter-level difference between the units would mean (plant/faults.py scales).

    load: TL_unit / TL_fleet − 1; motor_leak: (Ctm_unit − Ctm_fleet) / c_ref; pump_leak:
    (Cp + Cpl)_unit − (Cp + Cpl)_fleet over c_ref, with c_ref = Dp·ωp / Pc of the fleet unit.
    """
    c_ref = parity.reference_conductance(fleet)
    return {"load": unit.TL / fleet.TL - 1.0, "motor_leak": (unit.Ctm - fleet.Ctm) / c_ref,
            "pump_leak": (unit.Cp + unit.Cpl - fleet.Cp - fleet.Cpl) / c_ref}


def check_excitation(windows: np.ndarray, seconds: float) -> None:
    """Refuse (:class:`CommissioningError`) a recording too short or on a command that never loads the parts."""
    if seconds < MIN_SECONDS:
        raise CommissioningError(f"commissioning needs at least {MIN_SECONDS:.0f} s of valid healthy operation. "
                                 f"Got {seconds:.0f} s; record longer on a working command.")
    u = windows[:, :, L.CHANNELS.index("voltage")]
    spread = float(np.quantile(u, 0.95) - np.quantile(u, 0.05))
    if spread < MIN_COMMAND_SPREAD:
        raise CommissioningError(f"the command must move over at least {MIN_COMMAND_SPREAD} V (5–95 % spread) to "
                                 f"load the parts. Got {spread:.2f} V: a hold cannot tell inertia, damping and valve "
                                 "gain apart; record a duty cycle or filtered noise.")
    moving = float(np.mean(np.abs(windows[:, :, L.CHANNELS.index("speed")]) > MOVING_SPEED))
    if moving < MIN_MOVING:
        raise CommissioningError(f"the motor must turn (|speed| > {MOVING_SPEED} rad/s) in at least "
                                 f"{MIN_MOVING:.0%} of the samples. Got {moving:.0%}; record the unit working.")


def fault_present(features: ConditionFeatures, unit: UnitFit, faults: tuple[str, ...] | None = None) -> str | None:
    """The refusal message when an identified parameter reads as a trained fault (:data:`FAULT_FRACTION`; of
    ``faults`` only, when given), else None."""
    for fault, severity in implied_severities(features.nominal_, unit.parameters).items():
        if faults is not None and fault not in faults:
            continue
        warning = level_severity(fault, "warning", features.nominal_)
        if severity > FAULT_FRACTION[fault] * warning:
            return (f"the healthy recording looks like a {fault} fault already present: its parameters mean severity "
                    f"{severity:.2f} (warning {warning:.2f}) against the trained unit. Repair the unit, or commission "
                    "on a recording from when it was healthy.")
    return None
