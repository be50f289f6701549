"""What a commissioning recording informs: the parameters it leaves to their prior, and how uncertain it leaves the
trained fault levels on the unit (:mod:`hydrowatch.condition.commission`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hydrowatch.condition import parity
from hydrowatch.condition.unit import INFORMED as INFORMED  # the public names stay here
from hydrowatch.condition.unit import UnitFit
from hydrowatch.condition.unit import informed as _informed
from hydrowatch.condition.unit import left_to_prior as left_to_prior
from hydrowatch.plant.faults import level_severity, parse_state
from hydrowatch.plant.parameters import PlantParameters

if TYPE_CHECKING:
    from hydrowatch.condition.features import ConditionFeatures

LEAKS = ("pump_leak", "motor_leak", "valve_leak")
"""Faults whose severity is a conductance in units of the reference conductance."""


def levels(features: ConditionFeatures, p: PlantParameters) -> np.ndarray:
    """The trained fault levels on a unit of parameters ``p`` (steady speed drop at 2 V), in physical terms.

    A leakage fault's severity counts in units of the unit's own reference conductance Dp·ωp/Pc
    (:func:`parity.reference_conductance`), a scale, not physics: the leaks are compared as conductances,
    m³/(s·Pa), the others as their severities (load: TL factor; valve_coil, relief_spring: Kc, Pc fractions).
    """
    named = [parse_state(s) for s in features.levels_]
    scale = parity.reference_conductance(p)
    return np.array([level_severity(f, lvl, p) * (scale if f in LEAKS else 1.0)
                     for f, lvl in named if f is not None and lvl is not None] or [1.0])


def level_uncertainty(features: ConditionFeatures, fit: UnitFit, step: float = 0.01) -> float:
    """Largest standard deviation of ln(fault level) (:func:`levels`) that the fit's posterior covariance implies
    (linearised), counting only the parameters the recording informs.

    A parameter the recording leaves to its prior (posterior standard deviation ≥ :data:`INFORMED` × its prior
    spread τ, e.g. the pump displacement on a duty cycle that never saturates the pump) stays at the trained unit's
    value whether the supply is identified or kept
    (:func:`~hydrowatch.condition.commission.identify_for_commissioning`): its uncertainty is the build spread
    between units that both choices share, and does not tell them apart.
    """
    base = np.log(levels(features, fit.parameters))
    variance = np.zeros_like(base)
    for names, covariance in fit.covariance.values():
        informed = _informed(names, covariance)
        if not informed.any():
            continue
        kept = [n for n, ok in zip(names, informed) if ok]
        slopes = np.column_stack([(np.log(levels(features, fit.parameters.replace(
            **{n: getattr(fit.parameters, n) * np.exp(step)}))) - base) / step for n in kept])
        variance += np.einsum("ij,jk,ik->i", slopes, covariance[np.ix_(informed, informed)], slopes)
    return float(np.sqrt(variance.max()))
