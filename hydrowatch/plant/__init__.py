"""The plant: simulator of the servo-valve controlled hydrostatic transmission (plant-model.md).

Public API: :class:`PlantParameters` (nominal coefficients, SI units), the effect catalog
(:data:`EFFECT_IDS`, :data:`EFFECTS`, :func:`parse_effects`, :func:`resolve_effects`) and the
streaming, batched :class:`PlantSimulator` with the one-shot :func:`simulate`; health states
(:mod:`~hydrowatch.plant.faults`), the algebraic steady state (:mod:`~hydrowatch.plant.steady`),
commands (:mod:`~hydrowatch.plant.excitation`), fleets (:mod:`~hydrowatch.plant.fleet`) and degradation paths
(:mod:`~hydrowatch.plant.wear`).
"""

from hydrowatch.plant.effects import EFFECT_IDS, EFFECTS, Effects, EffectSpec, parse_effects, resolve_effects
from hydrowatch.plant.excitation import (
    FilteredNoiseCommand,
    chirp,
    duty_cycle,
    filtered_noise,
    parse_volts,
    ramp,
    read_command,
    sine,
    steps,
)
from hydrowatch.plant.faults import (
    EXTENDED_STATES,
    FAULTS,
    LEVEL_BANDS,
    LEVELS,
    STUDY_STATES,
    fault_parameters,
    level_for_speed_drop,
    level_severity,
    parse_state,
    random_state_parameters,
    severity_for_speed_drop,
    speed_drop,
    state_name,
    state_parameters,
)
from hydrowatch.plant.fleet import Fleet, MachineSpec, scatter_parameters, simulate_states, state_seeds
from hydrowatch.plant.parameters import PARAMETER_NAMES, PlantParameters
from hydrowatch.plant.simulator import (
    CHANNELS,
    DEFAULT_SUBSTEPS,
    REFERENCE_SUBSTEPS,
    PlantSimulator,
    simulate,
    zero_flow_supply_pressure,
)
from hydrowatch.plant.steady import SteadyState, steady_curve, steady_speed, steady_state
from hydrowatch.plant.wear import DegradationPath

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
    "FilteredNoiseCommand", "chirp", "duty_cycle", "filtered_noise", "parse_volts", "ramp", "read_command", "sine",
    "steps",
    "EXTENDED_STATES", "FAULTS", "LEVEL_BANDS", "LEVELS", "STUDY_STATES", "fault_parameters",
    "level_for_speed_drop", "level_severity", "parse_state", "random_state_parameters",
    "severity_for_speed_drop", "speed_drop", "state_name", "state_parameters",
    "DegradationPath", "Fleet", "MachineSpec", "scatter_parameters", "simulate_states", "state_seeds",
    "SteadyState", "steady_curve", "steady_speed", "steady_state",
]
