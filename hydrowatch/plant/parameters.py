"""Physical parameters of the servo-valve controlled hydrostatic transmission.

One frozen, typed object holds every coefficient of the nominal model in SI units
(../shared/docs/plant-model.md, "Nominal parameters"; sub-component equations 2.1–2.5 of the
study). Defaults are the nominal values of that table. A fault is a parameter change
(:meth:`PlantParameters.replace`); invalid values are refused when the object is built.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError

_TWO_PI = 2.0 * math.pi

# Which constraint each field obeys: "positive" (> 0), "nonnegative" (>= 0) or "fraction" (0 < v <= 1).
_CONSTRAINTS: dict[str, str] = {
    "Dp": "positive", "omega_p": "positive", "Cp": "nonnegative", "Pc": "positive", "Kr": "positive",
    "Vs": "positive", "beta_e": "positive", "Kq": "positive", "u_max": "positive", "omega_v": "positive",
    "zeta_v": "positive", "Kc": "nonnegative", "Cvl": "nonnegative", "Cvx": "nonnegative", "Vt": "positive",
    "Dm": "positive", "Ctm": "nonnegative", "Jm": "positive", "Bm": "nonnegative", "N": "positive",
    "eta": "fraction", "JL": "positive", "BL": "nonnegative", "TL": "nonnegative", "omega_s": "positive",
    "noise_flow": "nonnegative", "noise_speed": "nonnegative", "noise_torque": "nonnegative",
    "Cpl": "nonnegative",
}
_CONSTRAINT_TEXT = {"positive": "> 0", "nonnegative": ">= 0", "fraction": "in (0, 1]"}


@dataclass(frozen=True)
class PlantParameters:
    """Coefficients of the nominal plant model, SI units (plant-model.md, equations 1–8).

    Attributes
    ----------
    Dp : float
        Pump displacement, m³/rad (3.5 cm³/rev). Pump flow Qp = Dp·ωp − (Cp + Cpl)·Ps (study Eq. 2.1).
    omega_p : float
        Pump shaft speed ωp, rad/s (1750 rpm).
    Cp : float
        Pump leakage coefficient, m³/(s·Pa).
    Pc : float
        Relief valve cracking pressure, Pa (70 bar). Must be > 0 (study Eq. 2.5).
    Kr : float
        Relief valve flow gain above cracking, m³/(s·Pa): Qr = Kr·max(0, Ps − Pc).
    Vs : float
        Supply line volume between pump and valve, m³.
    beta_e : float
        Effective bulk modulus of the oil βe, Pa.
    Kq : float
        Valve flow gain, m³/(s·√Pa): QL = Kq·x·√(Ps − PL) (study Eq. 2.2); 10 L/min at 70 bar, full stroke.
    u_max : float
        Command for full spool stroke, V.
    omega_v : float
        Spool natural frequency ωv, rad/s.
    zeta_v : float
        Spool damping ratio ζv, dimensionless.
    Kc : float
        Coil (electromagnetic) gain, dimensionless; the valve_coil fault lowers it.
    Cvl : float
        Valve leakage supply → tank, m³/(s·Pa).
    Cvx : float
        Valve cross-port leakage, m³/(s·Pa); the valve_leak fault raises it.
    Vt : float
        Total motor chamber volume, m³ (study Eq. 2.3, V0).
    Dm : float
        Motor displacement, m³/rad (8 cm³/rev).
    Ctm : float
        Total motor leakage Cim + Cem/2, m³/(s·Pa); the motor_leak fault raises it.
    Jm : float
        Motor-side inertia, kg·m².
    Bm : float
        Motor viscous damping, N·m·s/rad.
    N : float
        Gearbox ratio (motor speed / output speed), dimensionless.
    eta : float
        Gearbox efficiency, in (0, 1].
    JL : float
        Load inertia at the gearbox output, kg·m².
    BL : float
        Viscous load coefficient at the gearbox output, N·m·s/rad.
    TL : float
        Brake torque of the passive load, N·m; the load fault raises it.
    omega_s : float
        Speed that smooths the brake torque's sign, TL·tanh(ωg/ωs), rad/s.
    noise_flow : float
        Standard deviation of the flow sensor's white noise, L/min.
    noise_speed : float
        Standard deviation of the speed sensor's white noise, rad/s.
    noise_torque : float
        Standard deviation of the torque sensor's white noise, N·m.
    Cpl : float
        Extra leakage path pump outlet → tank, m³/(s·Pa), adds to Cp (the pump_leak fault). Default 0.
    """

    Dp: float = 3.5e-6 / _TWO_PI
    omega_p: float = 1750.0 * _TWO_PI / 60.0
    Cp: float = 8e-13
    Pc: float = 70e5
    Kr: float = 2.5e-10
    Vs: float = 2e-4
    beta_e: float = 1.0e9
    Kq: float = 1.667e-4 / math.sqrt(70e5)
    u_max: float = 5.0
    omega_v: float = _TWO_PI * 60.0
    zeta_v: float = 0.7
    Kc: float = 1.0
    Cvl: float = 2e-13
    Cvx: float = 0.0
    Vt: float = 1e-4
    Dm: float = 8e-6 / _TWO_PI
    Ctm: float = 5e-13
    Jm: float = 1e-4
    Bm: float = 1e-3
    N: float = 5.0
    eta: float = 0.95
    JL: float = 0.05
    BL: float = 0.2
    TL: float = 10.0
    omega_s: float = 0.2
    noise_flow: float = 0.03
    noise_speed: float = 0.03
    noise_torque: float = 0.15
    Cpl: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise ParameterError(
                    f"plant parameter '{f.name}' must be a real number. Got {value!r}. Give a float in SI units."
                )
            object.__setattr__(self, f.name, float(value))
        self.validate()

    def validate(self) -> None:
        """Refuse NaN, infinite and physically impossible values.

        Raises
        ------
        ParameterError
            Naming the first offending field, its constraint and its value.
        """
        for name, kind in _CONSTRAINTS.items():
            value = getattr(self, name)
            ok = math.isfinite(value) and (
                value > 0.0 if kind == "positive" else value >= 0.0 if kind == "nonnegative" else 0.0 < value <= 1.0
            )
            if not ok:
                raise ParameterError(
                    f"plant parameter '{name}' must be finite and {_CONSTRAINT_TEXT[kind]}. Got {value!r}. "
                    "Fix the value (SI units, see PlantParameters' docstring)."
                )

    def replace(self, **changes: float) -> PlantParameters:
        """A copy with some fields changed (validated); unknown names raise ParameterError."""
        _check_names(changes)
        return PlantParameters(**{**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, float]:
        """Every field as ``{name: value}``, SI units."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}  # flat floats: no deep copy (asdict)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PlantParameters:
        """Build from a (possibly partial) mapping; missing fields keep their nominal value."""
        _check_names(d)
        return cls(**d)

    def to_json(self, path: str | Path | None = None) -> str:
        """The parameters as JSON text; also written to ``path`` when given."""
        text = json.dumps(self.to_dict(), indent=2)
        if path is not None:
            Path(path).write_text(text + "\n", encoding="utf-8")
        return text

    @classmethod
    def from_json(cls, path_or_text: str | Path) -> PlantParameters:
        """Read from a JSON file path or from JSON text (an object of field names to numbers)."""
        text = str(path_or_text)
        source = "JSON text"
        if not text.lstrip().startswith("{"):
            path = Path(text)
            if not path.is_file():
                raise ParameterError(f"parameter file must exist. Got '{path}'. Give a JSON file or JSON text.")
            text, source = path.read_text(encoding="utf-8"), str(path)
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ParameterError(f"{source} must be valid JSON. Got an error: {exc}.") from None
        if not isinstance(data, dict):
            raise ParameterError(f"{source} must hold a JSON object of parameter names. Got {type(data).__name__}.")
        return cls.from_dict(data)

    def as_array(self) -> np.ndarray:
        """Values in :data:`PARAMETER_NAMES` order, shape (P,), float64 (the kernel's layout)."""
        return np.array([getattr(self, name) for name in PARAMETER_NAMES], dtype=np.float64)


PARAMETER_NAMES: tuple[str, ...] = tuple(f.name for f in fields(PlantParameters))
"""Field names in the order of :meth:`PlantParameters.as_array`."""

PARAMETER_INDEX: dict[str, int] = {name: i for i, name in enumerate(PARAMETER_NAMES)}
"""Column of each field in the kernel's parameter array."""


def _check_names(d: dict[str, Any]) -> None:
    unknown = sorted(set(d) - set(PARAMETER_NAMES))
    if unknown:
        raise ParameterError(
            f"plant parameter names must be among {list(PARAMETER_NAMES)}. Got unknown {unknown}. "
            "Check the spelling (names are case-sensitive)."
        )
