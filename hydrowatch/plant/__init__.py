"""The plant: simulator of the servo-valve controlled hydrostatic transmission (plant-model.md).

Public API: :class:`PlantParameters` (nominal coefficients, SI units), the effect catalog
(:data:`EFFECT_IDS`, :data:`EFFECTS`, :func:`parse_effects`, :func:`resolve_effects`) and the
streaming, batched :class:`PlantSimulator` with the one-shot :func:`simulate`.
"""

from hydrowatch.plant.effects import EFFECT_IDS, EFFECTS, Effects, EffectSpec, parse_effects, resolve_effects
from hydrowatch.plant.parameters import PARAMETER_NAMES, PlantParameters
from hydrowatch.plant.simulator import (
    CHANNELS,
    DEFAULT_SUBSTEPS,
    REFERENCE_SUBSTEPS,
    PlantSimulator,
    simulate,
    zero_flow_supply_pressure,
)

__all__ = [
    "CHANNELS",
    "DEFAULT_SUBSTEPS",
    "EFFECTS",
    "EFFECT_IDS",
    "PARAMETER_NAMES",
    "REFERENCE_SUBSTEPS",
    "EffectSpec",
    "Effects",
    "PlantParameters",
    "PlantSimulator",
    "parse_effects",
    "resolve_effects",
    "simulate",
    "zero_flow_supply_pressure",
]
