"""The catalog of effects the nominal plant model leaves out (plant-model.md, last table).

Each effect can be switched on in the simulator, alone or together with others, to make data in
which real-rig physics is concealed. An effect is given as ``{id: {parameter: value}}``; missing
parameters take the catalog's default. ``parse_effects`` reads the command-line form
``"id[:k=v,...];id2"``. The kernel receives every machine's effects as one row of floats laid out
by :data:`EFFECT_OFFSET` (a 1.0/0.0 switch followed by the parameters in catalog order).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from hydrowatch.channels import PLANT
from hydrowatch.errors import ParameterError

EFFECT_IDS: tuple[str, ...] = (
    "stribeck_friction", "quadratic_drag", "valve_deadband", "valve_saturation", "valve_hysteresis",
    "transport_delay", "entrained_air", "pump_ripple", "thermal_drift", "gear_backlash", "shaft_compliance",
    "sensor_lowpass",
)

Effects = Mapping[str, Mapping[str, float]]
"""Effects as ``{effect id: {parameter name: value}}``, e.g. ``{"stribeck_friction": {"Ts": 0.4}}``."""

SENSOR_NAMES: tuple[str, ...] = PLANT.sensors
"""Values of sensor_lowpass's ``sensor`` parameter: 0 flow, 1 speed, 2 torque (the kernel's output columns)."""

REFERENCE_TEMPERATURE_C = 40.0
"""Oil temperature at which the nominal parameters hold, °C (reported when thermal_drift is off)."""


@dataclass(frozen=True)
class EffectSpec:
    """One catalog entry.

    Attributes
    ----------
    id : str
        Identifier from plant-model.md.
    parameters : dict of str to (default, unit, description, lower, upper)
        Realistic default and the accepted closed range of each parameter.
    regime : str
        Where the effect shows in the outputs.
    """

    id: str
    parameters: dict[str, tuple[float, str, str, float, float]]
    regime: str


EFFECTS: dict[str, EffectSpec] = {
    spec.id: spec
    for spec in (
        EffectSpec(
            "stribeck_friction",
            {
                "Tc": (0.1, "N·m", "Coulomb friction torque at the motor shaft (~4 % of the 2 V motor torque)",
                       0.0, 1.0),
                "Ts": (0.3, "N·m", "breakaway (static) friction torque at the motor shaft, >= Tc", 0.0, 2.0),
                "omega_st": (5.0, "rad/s", "Stribeck speed at the motor shaft (1 rad/s at the gearbox output)",
                             0.1, 50.0),
                "omega_eps": (2.0, "rad/s", "motor speed that smooths the friction's sign (tanh)", 0.5, 20.0),
            },
            "speed/torque error at low speed, starts and stops",
        ),
        EffectSpec(
            "quadratic_drag",
            {"Kd": (0.006, "N·m·s²/rad²", "windage torque Kd·ωg·|ωg| at the gearbox output (0.5 N·m at 9 rad/s)",
                    0.0, 0.05)},
            "torque error growing with speed squared",
        ),
        EffectSpec(
            "valve_deadband",
            {"d": (0.05, "1", "spool overlap as a fraction of full stroke (0.25 V of a 5 V command)", 0.0, 0.3)},
            "flow/speed error near zero command",
        ),
        EffectSpec(
            "valve_saturation",
            {"x_max": (0.6, "1", "largest metering opening as a fraction of full stroke (reached at 3 V)", 0.2, 1.0)},
            "error only at high commands, flat top",
        ),
        EffectSpec(
            "valve_hysteresis",
            {"r": (0.1, "V", "half width of the play in the command (2 % of u_max)", 0.0, 0.5)},
            "error depends on the command's direction of change",
        ),
        EffectSpec(
            "transport_delay",
            {"tau": (0.010, "s", "dead time between command and spool", 0.0, 0.05)},
            "phase lag growing linearly with frequency, all sensors",
        ),
        EffectSpec(
            "entrained_air",
            {
                "alpha": (0.01, "1", "free-air volume fraction at atmospheric pressure", 0.0, 0.2),
                "n": (1.4, "1", "polytropic exponent of the air (1 isothermal, 1.4 adiabatic)", 1.0, 1.4),
            },
            "resonance shifts with pressure level, softer transients",
        ),
        EffectSpec(
            "pump_ripple",
            {
                "a1": (0.05, "1", "relative flow ripple amplitude at the pump shaft frequency ωp", 0.0, 0.3),
                "a2": (0.02, "1", "relative flow ripple amplitude at 2·ωp", 0.0, 0.3),
            },
            "narrow spectral lines in flow/torque error at the shaft frequency (29.2 Hz) and 58.3 Hz",
        ),
        EffectSpec(
            "thermal_drift",
            {
                "T_start": (40.0, "°C", "oil temperature at t = 0 (the nominal parameters hold at 40 °C)",
                            -10.0, 100.0),
                "T_end": (60.0, "°C", "temperature the oil warms up to", -10.0, 120.0),
                "tau": (600.0, "s", "time constant of the first-order warm-up", 10.0, 7200.0),
                "k_visc": (0.04, "1/K", "viscosity ~ exp(-k·(T - 40 °C)); leakages scale with its inverse",
                           0.0, 0.1),
            },
            "slow drift of the error over time, pressure-dependent",
        ),
        EffectSpec(
            "gear_backlash",
            {
                "b": (0.01, "rad", "half of the free play at the gearbox output (0.57°)", 0.0, 0.1),
                "K": (2000.0, "N·m/rad", "tooth contact stiffness at the gearbox output", 100.0, 10000.0),
                "c": (0.5, "N·m·s/rad", "tooth contact damping", 0.0, 10.0),
            },
            "torque/speed error at direction reversals",
        ),
        EffectSpec(
            "shaft_compliance",
            {
                "G": (500.0, "N·m/rad", "torsional stiffness between gearbox and load (the G·θ term, Eq. 2.4)",
                      50.0, 10000.0),
                "c": (0.2, "N·m·s/rad", "torsional damping of the shaft (modes at 14 Hz, ζ 0.37, and 148 Hz, ζ 0.15)",
                      0.0, 10.0),
            },
            "an extra lightly damped resonance in torque",
        ),
        EffectSpec(
            "sensor_lowpass",
            {
                "sensor": (2.0, "1", "which sensor: 0 flow, 1 speed, 2 torque (names accepted by parse_effects)",
                           0.0, 2.0),
                "tau": (0.02, "s", "time constant of the sensor's first-order filter", 0.001, 1.0),
            },
            "phase lag and attenuation in one sensor only",
        ),
    )
}


def _layout() -> tuple[dict[str, int], int]:
    offsets, column = {}, 0
    for effect_id in EFFECT_IDS:
        offsets[effect_id] = column
        column += 1 + len(EFFECTS[effect_id].parameters)
    return offsets, column


EFFECT_OFFSET, EFFECT_WIDTH = _layout()
"""Column of each effect's switch in the kernel's effect row; its parameters follow in catalog order."""


def resolve_effects(effects: Effects | None) -> dict[str, dict[str, float]]:
    """Fill catalog defaults and check names and ranges.

    Parameters
    ----------
    effects : mapping of effect id to mapping of parameter to value, or None
        Effects to switch on; ``None`` or ``{}`` is the nominal model.

    Returns
    -------
    dict
        Every switched-on effect with all its parameters, in catalog order.

    Raises
    ------
    ParameterError
        Unknown effect or parameter, a non-finite value, or a value outside the catalog's range.
    """
    resolved: dict[str, dict[str, float]] = {}
    for effect_id, given in (effects or {}).items():
        if effect_id not in EFFECTS:
            raise ParameterError(f"effect id must be one of {list(EFFECT_IDS)}. Got '{effect_id}'.")
        spec = EFFECTS[effect_id].parameters
        unknown = sorted(set(given or {}) - set(spec))
        if unknown:
            raise ParameterError(
                f"parameters of effect '{effect_id}' must be among {list(spec)}. Got unknown {unknown}."
            )
        values: dict[str, float] = {}
        for name, (default, unit, _, lower, upper) in spec.items():
            value = float((given or {}).get(name, default))
            if not (math.isfinite(value) and lower <= value <= upper):
                raise ParameterError(
                    f"effect parameter '{effect_id}.{name}' must be in [{lower:g}, {upper:g}] {unit}. Got {value!r}. "
                    "Pick a value inside the catalog range."
                )
            values[name] = value
        resolved[effect_id] = values
    friction = resolved.get("stribeck_friction")
    if friction is not None and friction["Ts"] < friction["Tc"]:
        raise ParameterError(
            f"effect parameter 'stribeck_friction.Ts' must be >= Tc ({friction['Tc']:g} N·m). Got {friction['Ts']:g}. "
            "The breakaway torque is the larger one."
        )
    lowpass = resolved.get("sensor_lowpass")
    if lowpass is not None and lowpass["sensor"] not in (0.0, 1.0, 2.0):
        raise ParameterError(
            f"effect parameter 'sensor_lowpass.sensor' must be 0, 1 or 2 ({', '.join(SENSOR_NAMES)}). "
            f"Got {lowpass['sensor']!r}."
        )
    return {effect_id: resolved[effect_id] for effect_id in EFFECT_IDS if effect_id in resolved}


def parse_effects(text: str) -> dict[str, dict[str, float]]:
    """Parse the command-line form ``"id[:k=v,...];id2"`` and resolve it (defaults filled, ranges checked).

    ``sensor_lowpass:sensor=torque`` accepts a sensor name for ``sensor``. An empty text is no effect.

    Raises
    ------
    ParameterError
        Malformed text, unknown id or parameter, or a value that is not a number or out of range.
    """
    effects: dict[str, dict[str, float]] = {}
    for item in (part.strip() for part in text.split(";")):
        if not item:
            continue
        effect_id, _, rest = item.partition(":")
        effect_id = effect_id.strip()
        values: dict[str, float] = {}
        for pair in (p.strip() for p in rest.split(",")):
            if not pair:
                continue
            name, sep, raw = pair.partition("=")
            name, raw = name.strip(), raw.strip()
            if not sep or not name:
                raise ParameterError(
                    f"effect settings must look like 'id:k=v,k2=v2'. Got '{pair}' in '{item}'."
                )
            if effect_id == "sensor_lowpass" and name == "sensor" and raw in SENSOR_NAMES:
                values[name] = float(SENSOR_NAMES.index(raw))
                continue
            try:
                values[name] = float(raw)
            except ValueError:
                raise ParameterError(f"effect parameter '{effect_id}.{name}' must be a number. Got '{raw}'.") from None
        effects[effect_id] = values
    return resolve_effects(effects)


def effect_row(effects: Effects | None) -> np.ndarray:
    """One machine's effects as the kernel's row, shape (EFFECT_WIDTH,), float64 (switch 1.0 when on)."""
    row = np.zeros(EFFECT_WIDTH, dtype=np.float64)
    for effect_id, values in resolve_effects(effects).items():
        offset = EFFECT_OFFSET[effect_id]
        row[offset] = 1.0
        row[offset + 1 : offset + 1 + len(values)] = list(values.values())
    return row
