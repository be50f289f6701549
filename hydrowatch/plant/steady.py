"""Steady state of the nominal plant at a constant valve command, solved algebraically.

With every time derivative of plant-model.md equations 1–7 set to zero (study Eq. 2.1–2.5 at
rest) the spool sits at x = Kc·u/umax and three equations remain for Ps, PL and ωm:

- supply line (Eq. 5):  Dp·ωp − (Cp + Cpl)·Ps − Kr·max(0, Ps − Pc) − |QL| − Cvl·Ps = 0, Ps ≥ 0
- motor chambers (Eq. 6): QL − (Cvx + Ctm)·PL − Dm·ωm = 0
- shaft (Eq. 7): Dm·PL − Bm·ωm − (TL·tanh(ωg/ωs) + BL·ωg)/(N·η) = 0, ωg = ωm/N

with QL = Kq·x·√(Ps − PL) (Eq. 4). For a trial motor speed ωm the shaft gives PL, the motor
chambers give QL and the supply line (piecewise linear in Ps: relief closed or open) gives Ps in
closed form. What is left is one residual of ωm, the valve's flow minus the flow the motor takes,
which falls strictly with ωm between ωm = 0 (residual Kq·x·√Ps > 0) and the speed at which the
motor would swallow the pump's whole geometric flow (residual < 0). Brent's method on that
bracket always converges, on either relief branch and through the supply sag above ~3.5 V. The
equations are odd in (x, PL, ωm), so a negative command is solved as the mirror of a positive one.
Effects of the catalog are not part of this nominal solution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from hydrowatch.channels import M3S_TO_LPM, PA_TO_BAR, PLANT
from hydrowatch.plant.parameters import PlantParameters


@dataclass(frozen=True)
class SteadyState:
    """The plant at rest under a constant command (SI units unless named otherwise).

    Attributes
    ----------
    voltage : float
        Valve command u, V.
    spool : float
        Spool position x = Kc·u/umax, normalised.
    supply_pressure_pa : float
        Ps, Pa.
    load_pressure_pa : float
        PL = PA − PB, Pa.
    motor_speed : float
        ωm, rad/s.
    valve_flow : float
        QL, m³/s.
    relief_open : bool
        True when Ps exceeds the cracking pressure Pc (the relief valve passes flow).
    parameters : PlantParameters
        The parameters solved for.
    """

    voltage: float
    spool: float
    supply_pressure_pa: float
    load_pressure_pa: float
    motor_speed: float
    valve_flow: float
    relief_open: bool
    parameters: PlantParameters

    @property
    def speed(self) -> float:
        """Gearbox output speed ωg = ωm/N, rad/s (the speed sensor, Eq. 8)."""
        return self.motor_speed / self.parameters.N

    @property
    def flow(self) -> float:
        """Flow sensor QL − Cvx·PL, L/min (Eq. 8)."""
        return (self.valve_flow - self.parameters.Cvx * self.load_pressure_pa) * M3S_TO_LPM

    @property
    def torque(self) -> float:
        """Torque sensor at rest, TL·tanh(ωg/ωs) + BL·ωg, N·m (Eq. 7–8)."""
        return _load_torque(self.parameters, self.speed)

    def sensors(self) -> dict[str, float]:
        """The channels a recording would hold at rest, contract units (L/min, rad/s, N·m, bar)."""
        return {
            "voltage": self.voltage,
            "flow": self.flow,
            "speed": self.speed,
            "torque": self.torque,
            "supply_pressure": self.supply_pressure_pa * PA_TO_BAR,
            "load_pressure": self.load_pressure_pa * PA_TO_BAR,
        }


def _load_torque(p: PlantParameters, speed: float) -> float:
    """TL_total at gearbox output speed ωg (Eq. 7), N·m."""
    return p.TL * math.tanh(speed / p.omega_s) + p.BL * speed


def _load_pressure(p: PlantParameters, wm: float) -> float:
    """PL that holds the shaft at motor speed ωm ≥ 0 (Eq. 7 at rest), Pa."""
    return (p.Bm * wm + _load_torque(p, wm / p.N) / (p.N * p.eta)) / p.Dm


def _supply_pressure(p: PlantParameters, q_valve: float) -> tuple[float, bool]:
    """Ps that balances the supply line (Eq. 5 at rest) when the valve takes |QL| = q_valve, Pa."""
    q_geo = p.Dp * p.omega_p
    conductance = p.Cp + p.Cpl + p.Cvl
    surplus = q_geo - q_valve
    if surplus - conductance * p.Pc > 0.0:  # relief open: the linear branch above cracking
        return (surplus + p.Kr * p.Pc) / (conductance + p.Kr), True
    if conductance == 0.0:
        return (p.Pc if surplus > 0.0 else 0.0), False
    return max(surplus / conductance, 0.0), False


def _residual(wm: float, p: PlantParameters, spool: float) -> float:
    """Valve flow minus the flow the motor takes at motor speed ωm, m³/s (decreasing in ωm)."""
    pl = _load_pressure(p, wm)
    q_motor = (p.Cvx + p.Ctm) * pl + p.Dm * wm
    ps, _ = _supply_pressure(p, q_motor)
    return p.Kq * spool * math.sqrt(max(ps - pl, 0.0)) - q_motor


def steady_state(voltage: float, parameters: PlantParameters | None = None) -> SteadyState:
    """Solve the nominal model at rest under a constant command (plant-model.md Eq. 1–7).

    Parameters
    ----------
    voltage : float
        Valve command u, V (any sign).
    parameters : PlantParameters, optional
        Default: the nominal parameters.

    Returns
    -------
    SteadyState
        Pressures, speeds and flows; ``.speed`` is the gearbox speed, rad/s (≈ 8.85 at 2 V nominal).
    """
    p = parameters if parameters is not None else PlantParameters()
    u = float(voltage)
    spool = p.Kc * u / p.u_max
    sign = 1.0 if spool >= 0.0 else -1.0
    x = abs(spool)
    if x == 0.0:
        ps, relief = _supply_pressure(p, 0.0)
        return SteadyState(u, spool, ps, 0.0, 0.0, 0.0, relief, p)
    # Above this speed the motor alone would take the pump's whole geometric flow.
    w_hi = p.Dp * p.omega_p / p.Dm
    wm = brentq(_residual, 0.0, w_hi, args=(p, x), xtol=1e-12, rtol=1e-13, maxiter=200)
    pl = _load_pressure(p, wm)
    q_valve = (p.Cvx + p.Ctm) * pl + p.Dm * wm
    ps, relief = _supply_pressure(p, q_valve)
    return SteadyState(u, spool, ps, sign * pl, sign * wm, sign * q_valve, relief, p)


def steady_speed(voltage: float, parameters: PlantParameters | None = None) -> float:
    """Steady gearbox speed ωg under a constant command, rad/s (see :func:`steady_state`)."""
    return steady_state(voltage, parameters).speed


def steady_curve(voltages: np.ndarray, parameters: PlantParameters | None = None) -> dict[str, np.ndarray]:
    """Steady sensors over a set of commands (the static characteristic of the plant).

    Parameters
    ----------
    voltages : array_like, shape (n,)
        Commands, V.
    parameters : PlantParameters, optional
        Default: the nominal parameters.

    Returns
    -------
    dict of str to ndarray, shape (n,)
        ``voltage`` [V], ``flow`` [L/min], ``speed`` [rad/s], ``torque`` [N·m],
        ``supply_pressure``, ``load_pressure`` [bar].
    """
    rows = [steady_state(float(u), parameters).sensors() for u in np.atleast_1d(np.asarray(voltages, dtype=float))]
    names = [c for c in PLANT.names if c != "temperature"]  # the nominal steady state holds no oil temperature
    return {name: np.array([row[name] for row in rows]) for name in names}
