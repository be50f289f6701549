"""Health states of the plant: faults as parameter changes, calibrated on the steady speed at 2 V.

A fault is a parameter change (plant-model.md, "Health states"). Each fault has a severity ``s``,
a dimensionless number on its own documented scale (0 = healthy):

============== ======================================================================
fault          parameter change (``nominal`` values marked 0)
============== ======================================================================
load           TL = TL0·(1 + s)               (brake torque rises by the fraction s)
pump_leak      Cpl = Cpl0 + s·Cref            (extra leak pump outlet → tank)
motor_leak     Ctm = Ctm0 + s·Cref            (motor internal/external leakage rises)
valve_leak     Cvx = Cvx0 + s·Cref            (cross-port leakage across the spool lands)
valve_coil     Kc = Kc0·(1 − s)               (solenoid field decays by the fraction s, s < 1)
relief_spring  Pc = Pc0·(1 − s)               (cracking pressure falls by the fraction s, s < 1)
============== ======================================================================

``Cref = Dp·ωp / Pc`` (of the nominal parameters) is the leak conductance that passes the pump's
whole geometric flow at the cracking pressure, so a leak severity of 0.1 passes 10 % of the pump's
geometric flow at 70 bar (≈ 0.61 L/min nominal).

The named levels follow the study (Sections 5.3 and 6.1): **warning** is the severity at which the
steady gearbox speed at 2 V falls 15 % below the nominal machine's, **alert** 30 %. They are found
by Brent's root finding on the algebraic steady state (:mod:`hydrowatch.plant.steady`) and cached
per (fault, drop, nominal parameters). State names are ``healthy``, ``<fault>_warning`` and
``<fault>_alert``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from hydrowatch.errors import ParameterError
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.steady import steady_speed

FAULTS: tuple[str, ...] = ("load", "pump_leak", "motor_leak", "valve_leak", "valve_coil", "relief_spring")
"""Fault identifiers, in the order of plant-model.md's health-state table."""

LEVELS: dict[str, float] = {"warning": 0.15, "alert": 0.30}
"""Named severity levels: the fractional drop of the steady gearbox speed at 2 V they stand for."""

LEVEL_BANDS: dict[str, tuple[float, float]] = {"warning": (0.12, 0.18), "alert": (0.26, 0.34)}
"""Speed-drop bands around each named level (for severities spread inside a level)."""

REFERENCE_VOLTAGE = 2.0
"""Command at which severities are calibrated, V (the study's definition)."""

HEALTHY = "healthy"

STUDY_STATES: tuple[str, ...] = (
    HEALTHY, "load_warning", "load_alert", "pump_leak_warning", "pump_leak_alert",
    "motor_leak_warning", "motor_leak_alert",
)
"""The seven health states of the study (Section 6.1)."""

EXTENDED_STATES: tuple[str, ...] = (HEALTHY,) + tuple(f"{f}_{lvl}" for f in FAULTS for lvl in LEVELS)
"""Healthy plus warning and alert of every fault (13 states)."""

# Largest severity searched for each fault (beyond it the scale is meaningless or the plant stalls).
_MAX_SEVERITY: dict[str, float] = {
    "load": 1000.0, "pump_leak": 100.0, "motor_leak": 100.0, "valve_leak": 100.0,
    "valve_coil": 1.0 - 1e-9, "relief_spring": 1.0 - 1e-9,
}
_SCALE_TEXT: dict[str, str] = {
    "load": "TL·(1 + s)", "pump_leak": "Cpl + s·Dp·ωp/Pc", "motor_leak": "Ctm + s·Dp·ωp/Pc",
    "valve_leak": "Cvx + s·Dp·ωp/Pc", "valve_coil": "Kc·(1 − s)", "relief_spring": "Pc·(1 − s)",
}


def _check_fault(fault: str) -> None:
    if fault not in FAULTS:
        raise ParameterError(f"fault must be one of {list(FAULTS)}. Got {fault!r}. Check the spelling.")


def _check_severity(fault: str, severity: float) -> float:
    s = float(severity)
    upper = _MAX_SEVERITY[fault]
    if not (np.isfinite(s) and 0.0 <= s <= upper):
        raise ParameterError(
            f"severity of fault '{fault}' must be in [0, {upper:g}] (scale {_SCALE_TEXT[fault]}). Got {severity!r}. "
            "Give a smaller severity."
        )
    return s


def fault_parameters(nominal: PlantParameters | None, fault: str, severity: float) -> PlantParameters:
    """Parameters of a machine with one fault at a given severity (scales in the module docstring).

    Parameters
    ----------
    nominal : PlantParameters or None
        The healthy machine; None means the nominal parameters.
    fault : str
        One of :data:`FAULTS`.
    severity : float
        Dimensionless severity s ≥ 0 on the fault's scale (< 1 for valve_coil and relief_spring).

    Returns
    -------
    PlantParameters
    """
    p = nominal if nominal is not None else PlantParameters()
    _check_fault(fault)
    s = _check_severity(fault, severity)
    c_ref = p.Dp * p.omega_p / p.Pc
    if fault == "load":
        return p.replace(TL=p.TL * (1.0 + s))
    if fault == "pump_leak":
        return p.replace(Cpl=p.Cpl + s * c_ref)
    if fault == "motor_leak":
        return p.replace(Ctm=p.Ctm + s * c_ref)
    if fault == "valve_leak":
        return p.replace(Cvx=p.Cvx + s * c_ref)
    if fault == "valve_coil":
        return p.replace(Kc=p.Kc * (1.0 - s))
    return p.replace(Pc=p.Pc * (1.0 - s))


def speed_drop(fault: str, severity: float, nominal: PlantParameters | None = None,
               voltage: float = REFERENCE_VOLTAGE) -> float:
    """Fractional fall of the steady gearbox speed caused by a fault, 1 − ωg(fault)/ωg(nominal).

    Parameters
    ----------
    fault : str
        One of :data:`FAULTS`.
    severity : float
        Severity on the fault's scale.
    nominal : PlantParameters, optional
        The healthy machine (default nominal).
    voltage : float
        Constant command, V (default 2 V, the study's calibration point).
    """
    p = nominal if nominal is not None else PlantParameters()
    return 1.0 - steady_speed(voltage, fault_parameters(p, fault, severity)) / steady_speed(voltage, p)


@lru_cache(maxsize=1024)
def _severity_for_drop(fault: str, drop: float, nominal: PlantParameters) -> float:
    base = steady_speed(REFERENCE_VOLTAGE, nominal)
    upper = _MAX_SEVERITY[fault]

    def excess(s: float) -> float:
        return 1.0 - steady_speed(REFERENCE_VOLTAGE, fault_parameters(nominal, fault, s)) / base - drop

    reachable = excess(upper) + drop
    if reachable < drop:
        raise ParameterError(
            f"speed drop of fault '{fault}' must be at most {reachable:.4f} (the physics reaches no more at "
            f"{REFERENCE_VOLTAGE:g} V). Got {drop:.4f}. Choose a smaller drop or another fault."
        )
    return float(brentq(excess, 0.0, upper, xtol=1e-12, rtol=1e-12, maxiter=300))


def severity_for_speed_drop(fault: str, drop: float, nominal: PlantParameters | None = None) -> float:
    """Severity at which a fault lowers the steady gearbox speed at 2 V by a given fraction.

    Brent's root finding on :func:`speed_drop`; results are cached per (fault, drop, nominal).

    Parameters
    ----------
    fault : str
        One of :data:`FAULTS`.
    drop : float
        Fractional speed drop in (0, 1), e.g. 0.15 for the study's warning.
    nominal : PlantParameters, optional
        The healthy machine (default nominal); the drop is relative to its own speed.

    Returns
    -------
    float
        Severity on the fault's scale (module docstring).

    Raises
    ------
    ParameterError
        For an unknown fault, a drop outside (0, 1), or a drop the fault cannot physically cause.
    """
    _check_fault(fault)
    d = float(drop)
    if not (np.isfinite(d) and 0.0 < d < 1.0):
        raise ParameterError(f"speed drop must be a fraction in (0, 1). Got {drop!r}. Give e.g. 0.15 for 15 %.")
    return _severity_for_drop(fault, d, nominal if nominal is not None else PlantParameters())


TABLE_POINTS = 101
"""Points of a :func:`speed_drop_table`."""


@lru_cache(maxsize=256)
def speed_drop_table(fault: str, top_drop: float, nominal: PlantParameters) -> tuple[np.ndarray, np.ndarray]:
    """(speed drops, severities), shape (:data:`TABLE_POINTS`,) each: one fault on one machine, severity 0 to the
    severity of ``top_drop``, evenly spaced in severity; drops made monotone (running maximum) so that either
    column can be interpolated in the other. Cached per (fault, top_drop, nominal).

    Parameters
    ----------
    fault : str
        One of :data:`FAULTS`.
    top_drop : float
        Largest fractional speed drop at 2 V in the table, in (0, 1).
    nominal : PlantParameters
        The healthy machine.
    """
    top = severity_for_speed_drop(fault, top_drop, nominal)
    severity = np.linspace(0.0, top, TABLE_POINTS)
    drop = np.maximum.accumulate([speed_drop(fault, s, nominal) for s in severity])
    return drop, severity


def level_severity(fault: str, level: str, nominal: PlantParameters | None = None) -> float:
    """Severity of a named level: warning (15 % speed drop at 2 V) or alert (30 %).

    Parameters
    ----------
    fault : str
        One of :data:`FAULTS`.
    level : str
        ``"warning"`` or ``"alert"``.
    nominal : PlantParameters, optional
        The healthy machine (default nominal).
    """
    if level not in LEVELS:
        raise ParameterError(f"level must be one of {list(LEVELS)}. Got {level!r}.")
    return severity_for_speed_drop(fault, LEVELS[level], nominal)


def parse_state(name: str) -> tuple[str | None, str | None]:
    """Split a health-state name into (fault, level); ``healthy`` gives (None, None).

    Raises
    ------
    ParameterError
        Listing the valid names when ``name`` is not one.
    """
    if name == HEALTHY:
        return None, None
    for fault in FAULTS:
        for level in LEVELS:
            if name == f"{fault}_{level}":
                return fault, level
    raise ParameterError(
        f"health state must be one of {list(EXTENDED_STATES)}. Got {name!r}. Check the spelling."
    )


def state_parameters(state: str, nominal: PlantParameters | None = None) -> PlantParameters:
    """Parameters of a machine in a named health state (its level's calibrated severity).

    Parameters
    ----------
    state : str
        ``healthy``, ``<fault>_warning`` or ``<fault>_alert``.
    nominal : PlantParameters, optional
        The healthy machine (default nominal).
    """
    p = nominal if nominal is not None else PlantParameters()
    fault, level = parse_state(state)
    if fault is None or level is None:
        return p
    return fault_parameters(p, fault, level_severity(fault, level, p))


def random_state_parameters(state: str, rng: np.random.Generator,
                            nominal: PlantParameters | None = None) -> tuple[PlantParameters, float]:
    """Parameters of a machine in a health state with a severity drawn inside the level's band.

    The speed drop is drawn uniformly from :data:`LEVEL_BANDS` (warning 12–18 %, alert 26–34 %) and
    turned into a severity by :func:`severity_for_speed_drop`; ``healthy`` gives the nominal machine.

    Returns
    -------
    (PlantParameters, float)
        The parameters and the drawn speed drop (0.0 for healthy).
    """
    p = nominal if nominal is not None else PlantParameters()
    fault, level = parse_state(state)
    if fault is None or level is None:
        return p, 0.0
    lo, hi = LEVEL_BANDS[level]
    drop = float(rng.uniform(lo, hi))
    return fault_parameters(p, fault, severity_for_speed_drop(fault, drop, p)), drop


def level_for_speed_drop(drop: float) -> str | None:
    """The named level nearest to a speed drop: None (healthy) below 7.5 %, warning below 22.5 %, else alert."""
    if drop < 0.5 * LEVELS["warning"]:
        return None
    if drop < 0.5 * (LEVELS["warning"] + LEVELS["alert"]):
        return "warning"
    return "alert"


def state_name(fault: str | None, level: str | None) -> str:
    """The health-state name of a (fault, level) pair; the inverse of :func:`parse_state`."""
    if fault is None or level is None:
        return HEALTHY
    name = f"{fault}_{level}"
    parse_state(name)
    return name
