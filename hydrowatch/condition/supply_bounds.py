"""The supply a commissioning recording leaves undetermined, bounded (:mod:`hydrowatch.condition.commission`).

A recording may leave the supply (pump, relief, supply line) off: its halves disagree, the relief ends on its search
bound, or the pump is never driven to its limit. These rules say what is identified then (:data:`RESTRICTED_PARAMETERS`,
:func:`kept_supply`), which parameter the fit left on its bound (:func:`on_search_limit`) and how much capacity a pump
left to its prior is given (:func:`pump_capacity`). Split from :mod:`~hydrowatch.condition.commission`, which
chooses among them (docs/unseen-units.md).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import TYPE_CHECKING

import numpy as np

from hydrowatch.condition.informed import left_to_prior
from hydrowatch.condition.unit import BOUND, BOUNDS, RELATION_PARAMETERS, UnitFit, identify_unit
from hydrowatch.condition.unit_checks import drawn_flow
from hydrowatch.log import event, get_logger
from hydrowatch.plant.parameters import PlantParameters

if TYPE_CHECKING:
    from hydrowatch.condition.features import ConditionFeatures

_log = get_logger(__name__)

RESTRICTED_PARAMETERS = {**RELATION_PARAMETERS, "valve": ("Kq", "Cp")}
"""What commissioning identifies when the recording does not determine the supply
(:data:`~hydrowatch.condition.commission.SPLIT_AGREEMENT`): load and motor relations in full, of the valve and supply
only the valve gain and the pump leakage; Dp, Pc, Kr, Vs and ωv stay the trained unit's. A recording whose halves
disagree has a second basin along the supply's ridge (development population, seed 7, duty cycles: load-warning levels
off by a factor 2.7 in the whole fit of such units), and the trained unit's supply is then the better guess
(docs/unseen-units.md)."""
RELIEF = ("Pc", "Kr")
"""The relief valve's cracking pressure and gain: a ridge along which a recording may leave them
(:func:`on_search_limit`)."""
LIMIT_SHARE = 0.95
"""A parameter whose |ln(identified / trained)| reaches this share of its search bound ends *on* the bound
(:func:`on_search_limit`): the fit wanted it further, so the recording did not determine it. Over the duty-cycle
commissionings of seeds 2033 and 2038–2040 and 2044 the relief's share was ≤ 0.83 on every unit that read ≥ 92 %
right, 0.985–1.0 on the three that read 67–79 % (0.999 until the evening of 2026-11-26 missed 2044's, at 0.985)."""
CAPACITY_MARGIN = 0.15
"""A pump the recording never drove to its limit (Dp left to its prior) is given at most this much more capacity
than the recording drew from it (:func:`pump_capacity`). 0.05 until 2026-11-27: seed 2054's unit 6, whose duty cycle
drew 0.865 × its capacity, read valve-side faults as the coil (89.4 % right, 98.5 uncapped, 93.1 at 0.15); fresh
2055 no pooled accuracy worse (docs/unseen-units.md)."""
def kept_supply(features: ConditionFeatures, windows: np.ndarray) -> UnitFit:
    """The unit with the trained unit's supply: only :data:`RESTRICTED_PARAMETERS` identified, the pump's capacity
    Dp·ωp at most (1 + :data:`CAPACITY_MARGIN`) × what the recording drew from it (as :func:`pump_capacity` bounds a
    pump left to its prior).

    A kept pump larger than the unit's is never at its limit in the model where the unit's is, and the fit makes up
    the missing flow with the pump's leakage: seed 2044, unit 7 (capacity 0.63 × the trained unit's, the relief kept
    from 0.985 of its search bound) took Cp 10 × and read 15 % of its healthy windows as a pump leak.
    """
    p = features.nominal_
    start = _drawn_capacity(features, windows, p)
    fit = identify_unit(windows, start, features.sensors, features.viscosity_coefficient, RESTRICTED_PARAMETERS)
    return fit if start is p else dataclasses.replace(fit, factors={**fit.factors, "Dp": start.Dp / p.Dp})


def on_search_limit(fit: UnitFit, names: tuple[str, ...] = RELIEF) -> list[str]:
    """Which of ``names`` the fit left on its search bound (:data:`~hydrowatch.condition.unit.BOUND`, a factor 4.5
    from the trained unit's value).

    Such a value is no estimate: the criterion still falls towards the bound, along the relief's ridge the recording
    does not close. Both halves of a recording can share the ridge point, so the split-half test does not see it (seed
    2040, duty cycles: the relief gain Kr on its bound on 2 of 19 units; commissioned with it, the worst units, 67.6
    and 79.3 % right on a later day's duty cycle and slow noise (7 states)). :func:`identify_for_commissioning` holds
    such a parameter at the trained unit's value and fits the rest again: those two units 100 % right, the cracking
    pressure 1.25 × and 1.50 × the trained unit's (true 1.29 ×, 1.46 ×); with the trained unit's whole supply instead,
    97.5 % and healthy windows 88.3 %. On the 76 duty-cycle and 76 filtered-noise commissionings of seeds 2033 and
    2038–2040 no other relief ended near its bound; the supply line's volume Vs did on two units that read 100 %,
    and is not tested (docs/unseen-units.md).
    """
    return [n for n in names if n in fit.factors
            and abs(np.log(fit.factors[n])) >= LIMIT_SHARE * BOUNDS.get(n, BOUND)]


def pump_capacity(features: ConditionFeatures, fit: UnitFit, windows: np.ndarray) -> UnitFit:
    """``fit`` with the pump's capacity Dp·ωp at most (1 + :data:`CAPACITY_MARGIN`) × what the recording drew from
    it (:func:`~hydrowatch.condition.unit_checks.drawn_flow`), when the recording left Dp to its prior
    (:func:`left_to_prior`).

    Such a recording never drove the pump to its limit, so Dp stays at the trained unit's value; a unit whose pump
    delivers less then reaches its limit on a later day where the model expects spare capacity, and reads healthy
    windows at high demand as a pump leak or ``unknown``. The recording does bound the capacity from below, and a
    unit with more spare capacity than that bound loses nothing on commands like the commissioning one (it never
    draws more). Measured on seed 2030 (7 states, 8 recordings that left Dp to its prior; the population chose
    the rule): the worst unit (true capacity 0.78 × the trained unit's, kept at 1.0, capped at 0.82)
    went from 72.1 to 95.0 % right on a later day's duty cycle, its healthy windows from 65 to 100 %
    (docs/unseen-units.md).
    """
    if "Dp" not in left_to_prior(fit):
        return fit
    p = fit.parameters
    capped = _drawn_capacity(features, windows, p)
    if capped is p:
        return fit
    event(_log, "pump capacity bounded by the recording", logging.INFO, factor=round(capped.Dp / p.Dp, 3))
    return dataclasses.replace(fit, parameters=capped, factors={**fit.factors, "Dp": capped.Dp / features.nominal_.Dp})


def _drawn_capacity(features: ConditionFeatures, windows: np.ndarray, p: PlantParameters) -> PlantParameters:
    """``p`` with the pump's capacity Dp·ωp at most (1 + :data:`CAPACITY_MARGIN`) × the flow the recording drew from
    it (:func:`~hydrowatch.condition.unit_checks.drawn_flow`); ``p`` itself when it is within."""
    bound = (1.0 + CAPACITY_MARGIN) * drawn_flow(windows, p, features.sensors, features.viscosity_coefficient)
    return p if bound >= p.Dp * p.omega_p else p.replace(Dp=bound / p.omega_p)

