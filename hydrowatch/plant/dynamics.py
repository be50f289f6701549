"""Right-hand side of the plant's differential equations (plant-model.md, equations 1–8), compiled.

:func:`derivatives` evaluates the state derivative and the three raw sensors of one machine for a
given spool command, including every switched-on effect of the catalog. It works on the state as a
tuple of floats and is inlined into the integrator (:mod:`hydrowatch.plant.kernel`), so the whole
RK4 step runs in registers. Only the nominal equations are written out in it; each effect is one
branch to a small function of its own, so an effect that is off costs one comparison and the
inlined body stays small. :func:`rates` is the same on arrays, for callers outside the kernel.

ODE state of one machine (``N_ODE`` entries, SI units)::

    0 x      spool position, normalised (-1…1)       5 wL   load speed (flexible driveline), rad/s
    1 v      spool rate, 1/s                          6 th   twist gearbox output - load, rad
    2 Ps     supply pressure, Pa                      7 T    oil temperature, °C (thermal_drift)
    3 PL     load pressure PA - PB, Pa                8 yf   filtered sensor (sensor_lowpass)
    4 wm     motor speed, rad/s

Without gear_backlash and shaft_compliance the driveline is rigid (Eq. 7) and ``wL``, ``th`` stay 0.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hydrowatch.channels import M3S_TO_LPM
from hydrowatch.plant.effects import EFFECT_OFFSET, REFERENCE_TEMPERATURE_C
from hydrowatch.plant.parameters import PARAMETER_INDEX

N_ODE = 9
X, V, PS, PL, WM, WL, TH, TEMP, YF = range(N_ODE)

P_ATM = 101325.0
"""Atmospheric pressure, Pa (entrained_air works with absolute pressure)."""
CONTACT_DEPTH = 1e-3
"""Penetration at which gear_backlash's contact damping is fully engaged, rad."""

# Parameter columns (numba freezes module-level ints as constants).
_DP, _WP, _CP, _PC, _KR = (PARAMETER_INDEX[k] for k in ("Dp", "omega_p", "Cp", "Pc", "Kr"))
_VS, _BE, _KQ, _UMAX = (PARAMETER_INDEX[k] for k in ("Vs", "beta_e", "Kq", "u_max"))
_WV, _ZV, _KC, _CVL, _CVX = (PARAMETER_INDEX[k] for k in ("omega_v", "zeta_v", "Kc", "Cvl", "Cvx"))
_VT, _DM, _CTM, _JM, _BM = (PARAMETER_INDEX[k] for k in ("Vt", "Dm", "Ctm", "Jm", "Bm"))
_N, _ETA, _JL, _BL, _TL, _WS = (PARAMETER_INDEX[k] for k in ("N", "eta", "JL", "BL", "TL", "omega_s"))
_CPL = PARAMETER_INDEX["Cpl"]

# Coefficient columns: the parameters combined once per machine and chunk (products, reciprocals).
N_COEF = 24
(C_QGEO, C_WP, C_CPUMP, C_KR, C_PC, C_SPOOL, C_WV2, C_DAMP, C_KQ, C_BE, C_BE_VS, C_INV_VS, C_4_VT, C_CVL, C_CVX,
 C_DM, C_CTM, C_BM, C_INV_N, C_INV_NETA, C_INV_JT, C_INV_JM, C_INV_JL, C_JL_N) = range(N_COEF)
N_LOAD = 3
C_TL, C_INV_WS, C_BL = range(N_COEF, N_COEF + N_LOAD)


@njit(cache=True, error_model="numpy")
def coefficients(p: np.ndarray, c: np.ndarray) -> None:
    """Fill c (shape (N_COEF + 3,)) from one parameter row p: the products and reciprocals rates() uses."""
    c[C_QGEO] = p[_DP] * p[_WP]
    c[C_WP] = p[_WP]
    c[C_CPUMP] = p[_CP] + p[_CPL]
    c[C_KR] = p[_KR]
    c[C_PC] = p[_PC]
    c[C_SPOOL] = p[_WV] * p[_WV] * p[_KC] / p[_UMAX]
    c[C_WV2] = p[_WV] * p[_WV]
    c[C_DAMP] = 2.0 * p[_ZV] * p[_WV]
    c[C_KQ] = p[_KQ]
    c[C_BE] = p[_BE]
    c[C_BE_VS] = p[_BE] / p[_VS]
    c[C_INV_VS] = 1.0 / p[_VS]
    c[C_4_VT] = 4.0 / p[_VT]
    c[C_CVL] = p[_CVL]
    c[C_CVX] = p[_CVX]
    c[C_DM] = p[_DM]
    c[C_CTM] = p[_CTM]
    c[C_BM] = p[_BM]
    c[C_INV_N] = 1.0 / p[_N]
    c[C_INV_NETA] = 1.0 / (p[_N] * p[_ETA])
    c[C_INV_JT] = 1.0 / (p[_JM] + p[_JL] / (p[_N] * p[_N] * p[_ETA]))
    c[C_INV_JM] = 1.0 / p[_JM]
    c[C_INV_JL] = 1.0 / p[_JL]
    c[C_JL_N] = p[_JL] / p[_N]
    c[C_TL] = p[_TL]
    c[C_INV_WS] = 1.0 / p[_WS]
    c[C_BL] = p[_BL]


# Effect columns: switch, then parameters in catalog order.
_FRICTION = EFFECT_OFFSET["stribeck_friction"]
_DRAG = EFFECT_OFFSET["quadratic_drag"]
_DEADBAND = EFFECT_OFFSET["valve_deadband"]
_SATURATION = EFFECT_OFFSET["valve_saturation"]
_AIR = EFFECT_OFFSET["entrained_air"]
_RIPPLE = EFFECT_OFFSET["pump_ripple"]
_THERMAL = EFFECT_OFFSET["thermal_drift"]
_BACKLASH = EFFECT_OFFSET["gear_backlash"]
_SHAFT = EFFECT_OFFSET["shaft_compliance"]
_LOWPASS = EFFECT_OFFSET["sensor_lowpass"]
_T_REF = REFERENCE_TEMPERATURE_C

TANH_ONE = 22.0
"""|x| from which tanh(x) is ±1 in double precision: libm's tanh returns ±1 there without computing (it rounds to
±1 from |x| ≈ 19.06 on), so :func:`_tanh` skips the call (issue 12, item 5; the same bits)."""
EXP_ZERO = -746.0
"""x below which exp(x) underflows to 0.0 in double precision (below the smallest subnormal from x ≈ −745.13)."""


@njit(cache=True, error_model="numpy", inline="always")
def _tanh(x: float) -> float:
    """math.tanh(x), bit for bit, without the libm call where it is ±1 (|x| ≥ TANH_ONE)."""
    return math.copysign(1.0, x) if abs(x) >= TANH_ONE else math.tanh(x)


@njit(cache=True, error_model="numpy")
def _air_bulk_modulus(beta_oil: float, p_gauge: float, alpha: float, n: float) -> float:
    """Effective bulk modulus of oil with free air, Pa (mixture rule, air compressed polytropically).

    With the air volume fraction at absolute pressure p, ε = α·r / (1 − α + α·r), r = (p_atm/p)^(1/n):
    1/β = (1 − ε)/β_oil + ε/(n·p).
    """
    p_abs = max(p_gauge, 0.0) + P_ATM
    r = (P_ATM / p_abs) ** (1.0 / n)
    eps = alpha * r / (1.0 - alpha + alpha * r)
    return 1.0 / ((1.0 - eps) / beta_oil + eps / (n * p_abs))


@njit(cache=True, error_model="numpy")
def _load_torque(c: np.ndarray, e: np.ndarray, w: float) -> float:
    """TL_total at gearbox output speed w (Eq. 7: brake TL·tanh(w/ωs) + BL·w), plus quadratic_drag, N·m."""
    torque = c[C_TL] * _tanh(w * c[C_INV_WS]) + c[C_BL] * w
    if e[_DRAG] > 0.5:
        torque += e[_DRAG + 1] * w * abs(w)
    return torque


@njit(cache=True, error_model="numpy", inline="always")
def driveline_spring(e: np.ndarray) -> tuple[float, float]:
    """Stiffness [N·m/rad] and damping [N·m·s/rad] of a flexible driveline: shaft_compliance's G and c, gear_backlash's
    contact K and c, or with both the two springs in series and the shaft's damping."""
    if e[_SHAFT] <= 0.5:
        return e[_BACKLASH + 2], e[_BACKLASH + 3]
    if e[_BACKLASH] <= 0.5:
        return e[_SHAFT + 1], e[_SHAFT + 2]
    return 1.0 / (1.0 / e[_SHAFT + 1] + 1.0 / e[_BACKLASH + 2]), e[_SHAFT + 2]


@njit(cache=True, error_model="numpy")
def shaft_torque(e: np.ndarray, theta: float, slip: float) -> float:
    """Torque through a flexible driveline (gear_backlash and/or shaft_compliance), N·m.

    Parameters
    ----------
    e : ndarray, shape (EFFECT_WIDTH,)
        Effect row.
    theta : float
        Twist, gearbox output angle minus load angle, rad.
    slip : float
        d(theta)/dt, rad/s.

    Notes
    -----
    shaft_compliance alone: G·θ + c·θ' (the G·θ term of study Eq. 2.4). With gear_backlash the
    spring acts on the twist beyond the play b, δ = sign(θ)·max(|θ| − b, 0), its damping grows
    with penetration (c·min(|δ|/δ0, 1), δ0 = 1 mrad, so contact starts without a force jump)
    and teeth in contact never pull. Backlash and shaft springs in series when both are on.
    """
    stiffness, damping = driveline_spring(e)
    if e[_BACKLASH] <= 0.5:
        return stiffness * theta + damping * slip
    penetration = math.copysign(max(abs(theta) - e[_BACKLASH + 1], 0.0), theta)
    torque = stiffness * penetration + damping * min(abs(penetration) / CONTACT_DEPTH, 1.0) * slip
    return torque if torque * penetration > 0.0 else 0.0


State = tuple[float, float, float, float, float, float, float, float, float]
"""ODE state of one machine as a tuple (module docstring order); the kernel keeps it in registers."""


@njit(cache=True, error_model="numpy")
def _thermal(e: np.ndarray, temperature: float, clock: bool) -> tuple[float, float]:
    """thermal_drift: leakage factor exp(k·(T − 40 °C)) and dT/dt [K/s] (0 when the clock is stopped)."""
    leak = math.exp(e[_THERMAL + 4] * (temperature - _T_REF))
    warming = (e[_THERMAL + 2] - temperature) / e[_THERMAL + 3] if clock else 0.0
    return leak, warming


@njit(cache=True, error_model="numpy")
def _air_moduli(c: np.ndarray, e: np.ndarray, ps: float, pl: float) -> tuple[float, float]:
    """entrained_air: βe/Vs of the supply line [Pa/m³] and the chambers' mean bulk modulus [Pa].

    Chamber pressures of a symmetric valve: PA = (Ps + PL)/2, PB = (Ps − PL)/2.
    """
    alpha, n_poly = e[_AIR + 1], e[_AIR + 2]
    beta_s = _air_bulk_modulus(c[C_BE], ps, alpha, n_poly) * c[C_INV_VS]
    beta_l = 0.5 * (_air_bulk_modulus(c[C_BE], 0.5 * (ps + pl), alpha, n_poly)
                    + _air_bulk_modulus(c[C_BE], 0.5 * (ps - pl), alpha, n_poly))
    return beta_s, beta_l


@njit(cache=True, error_model="numpy")
def _rippled_flow(c: np.ndarray, e: np.ndarray, t: float) -> float:
    """pump_ripple: geometric pump flow Dp·ωp·(1 + a1·sin ωp·t + a2·sin 2ωp·t) at time t [s], m³/s."""
    phase = c[C_WP] * t
    return c[C_QGEO] * (1.0 + e[_RIPPLE + 1] * math.sin(phase) + e[_RIPPLE + 2] * math.sin(2.0 * phase))


@njit(cache=True, error_model="numpy")
def _metering_opening(e: np.ndarray, x: float) -> float:
    """valve_saturation (travel clipped at ±x_max), then valve_deadband (overlap d, rated flow at full stroke)."""
    if e[_SATURATION] > 0.5:
        x = min(max(x, -e[_SATURATION + 1]), e[_SATURATION + 1])
    if e[_DEADBAND] > 0.5:
        d = e[_DEADBAND + 1]
        x = math.copysign(max(abs(x) - d, 0.0) / (1.0 - d), x)
    return x


@njit(cache=True, error_model="numpy")
def _stribeck(e: np.ndarray, wm: float) -> float:
    """stribeck_friction at motor speed wm [rad/s]: (Tc + (Ts − Tc)·exp(−(ωm/ωst)²))·tanh(ωm/ωε), N·m."""
    tc, ts, w_st, w_eps = e[_FRICTION + 1], e[_FRICTION + 2], e[_FRICTION + 3], e[_FRICTION + 4]
    exponent = -((wm / w_st) ** 2)
    fade = 0.0 if exponent < EXP_ZERO else math.exp(exponent)
    return (tc + (ts - tc) * fade) * _tanh(wm / w_eps)


@njit(cache=True, error_model="numpy")
def _flexible_driveline(c: np.ndarray, e: np.ndarray, motor_torque: float, wg: float, wl: float,
                        theta: float) -> tuple[float, float, float, float]:
    """gear_backlash / shaft_compliance: motor side Jm, load JL, a (possibly backlashed) spring between.

    Returns dωm/dt [rad/s²], dωL/dt [rad/s²], dθ/dt [rad/s] and the shaft torque [N·m].
    """
    slip = wg - wl
    shaft = shaft_torque(e, theta, slip)
    dwm = (motor_torque - shaft * c[C_INV_NETA]) * c[C_INV_JM]
    dwl = (shaft - _load_torque(c, e, wl)) * c[C_INV_JL]
    return dwm, dwl, slip, shaft


@njit(cache=True, error_model="numpy", inline="always")
def derivatives(c: np.ndarray, e: np.ndarray, s: State, u: float, t: float,
                clock: bool) -> tuple[State, tuple[float, float, float]]:
    """State derivative and raw sensors of one machine, on a state tuple (compiled into the integrator).

    Parameters
    ----------
    c : ndarray, shape (N_COEF + 3,)
        Coefficients of the machine's parameters (:func:`coefficients`).
    e : ndarray, shape (EFFECT_WIDTH,)
        Effect row (see :data:`hydrowatch.plant.effects.EFFECT_OFFSET`).
    s : tuple of N_ODE floats
        ODE state (module docstring).
    u : float
        Command reaching the spool, V (after hysteresis and dead time).
    t : float
        Time, s (pump_ripple's phase).
    clock : bool
        False freezes the oil temperature (settling).

    Returns
    -------
    ds : tuple of N_ODE floats
        d(state)/dt.
    sensors : tuple of 3 floats
        Flow [L/min], gearbox speed [rad/s], shaft torque [N·m] before filter and noise (Eq. 8).

    """
    x, v, ps, pl, wm, wl, th, temp, yf = s
    ps = max(ps, 0.0)
    pl = min(max(pl, -ps), ps)

    # thermal_drift: laminar leakages ∝ 1/viscosity, viscous damping ∝ viscosity.
    leak, dtemp = _thermal(e, temp, clock) if e[_THERMAL] > 0.5 else (1.0, 0.0)
    beta_s, beta_l = _air_moduli(c, e, ps, pl) if e[_AIR] > 0.5 else (c[C_BE_VS], c[C_BE])

    # Eq. 1 pump and Eq. 2 relief valve (study Eq. 2.1, 2.5).
    q_geo = _rippled_flow(c, e, t) if e[_RIPPLE] > 0.5 else c[C_QGEO]
    qp = q_geo - c[C_CPUMP] * leak * ps
    qr = c[C_KR] * max(0.0, ps - c[C_PC])

    # Eq. 3 spool.
    dv = c[C_SPOOL] * u - c[C_WV2] * x - c[C_DAMP] * v

    # Eq. 4 valve flow (study Eq. 2.2) through the metering opening.
    xo = _metering_opening(e, x) if e[_SATURATION] > 0.5 or e[_DEADBAND] > 0.5 else x
    drop = ps - pl if xo >= 0.0 else ps + pl
    ql = c[C_KQ] * xo * math.sqrt(max(drop, 0.0))

    # Eq. 5 supply line, Eq. 6 motor chambers (study Eq. 2.3).
    dps = beta_s * (qp - qr - abs(ql) - c[C_CVL] * leak * ps)
    cvx = c[C_CVX] * leak
    dpl = c[C_4_VT] * beta_l * (ql - cvx * pl - c[C_DM] * wm - c[C_CTM] * leak * pl)

    # Eq. 7 shaft (study Eq. 2.4), reflected to the motor; stribeck_friction acts on the motor.
    friction = _stribeck(e, wm) if e[_FRICTION] > 0.5 else 0.0
    wg = wm * c[C_INV_N]
    motor_torque = c[C_DM] * pl - c[C_BM] / leak * wm - friction
    if e[_BACKLASH] > 0.5 or e[_SHAFT] > 0.5:
        dwm, dwl, dth, torque = _flexible_driveline(c, e, motor_torque, wg, wl, th)
    else:
        load = _load_torque(c, e, wg)
        dwm = (motor_torque - load * c[C_INV_NETA]) * c[C_INV_JT]
        dwl, dth = 0.0, 0.0
        torque = load + c[C_JL_N] * dwm

    # Eq. 8 sensors; sensor_lowpass filters one of them.
    flow = (ql - cvx * pl) * M3S_TO_LPM
    dyf = 0.0
    if e[_LOWPASS] > 0.5:
        sensor = int(e[_LOWPASS + 1])
        raw = flow if sensor == 0 else (wg if sensor == 1 else torque)
        dyf = (raw - yf) / e[_LOWPASS + 2]
    return (v, dv, dps, dpl, dwm, dwl, dth, dtemp, dyf), (flow, wg, torque)


@njit(cache=True, error_model="numpy")
def rates(c: np.ndarray, e: np.ndarray, s: np.ndarray, u: float, t: float, clock: bool,
          ds: np.ndarray, sensors: np.ndarray) -> None:
    """:func:`derivatives` on arrays: state s (N_ODE,) in, ds (N_ODE,) and sensors (3,) written (Eqs. 1–8)."""
    d, raw = derivatives(c, e, (s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8]), u, t, clock)
    for i in range(N_ODE):
        ds[i] = d[i]
    for i in range(3):
        sensors[i] = raw[i]


@njit(cache=True, error_model="numpy")
def fastest_rate(c: np.ndarray, e: np.ndarray) -> float:
    """Upper estimate of the largest eigenvalue magnitude of the right-hand side's Jacobian, 1/s.

    The fixed-step integrator is stable only while h·|λ| stays inside RK4's region (2.79 on the negative real
    axis): a model whose fastest mode is beyond it does not settle, it rings in a limit cycle that the kink
    bisection then chases every step (issue 12, item 5: a calibration that visited relief gain ×3 and supply volume
    ×0.5 put h·λ at 3.7 and ran 20–30× slower, on a trajectory that is not the model's). Terms, each a mode's rate
    from the parameters alone (the larger of each mode's real rate and its natural frequency):

    - supply line with the relief open (Eqs. 1, 2, 5): βe/Vs·(Kr + (Cp + Cvl)·leak);
    - motor chambers (Eq. 6): 4βe/Vt·(Cvx + Ctm)·leak, and the hydraulic resonance √(4βe·Dm²/(Vt·Jm)) (motor
      inertia alone: an upper bound for the rigid and the flexible driveline);
    - spool (Eq. 3): ωv·(ζv + √max(ζv² − 1, 0));
    - flexible driveline (:func:`driveline_spring`):
      √(ωh² + K·a) (the oil's and the shaft's springs both act on the motor: ωh the hydraulic resonance) and c·a,
      with a = 1/(N²·η·Jm) + 1/JL; motor damping Bm/Jm·thick;
    - sensor_lowpass: 1/τ.

    ``leak`` and ``thick`` are thermal_drift's largest leakage and viscosity factors over the warm-up (1 without
    it). Entrained air only softens the oil (a lower modulus), so βe bounds it. Left out, as they depend on the state
    and not only on the parameters: the valve's flow conductance (Eq. 4) and gear_backlash's contact-damping ramp
    (c·|θ'|/δ0 while entering contact).
    """
    leak, thick = 1.0, 1.0
    if e[_THERMAL] > 0.5:
        leak = _thermal(e, max(e[_THERMAL + 1], e[_THERMAL + 2]), False)[0]
        thick = 1.0 / _thermal(e, min(e[_THERMAL + 1], e[_THERMAL + 2]), False)[0]
    rate = c[C_BE_VS] * (c[C_KR] + (c[C_CPUMP] + c[C_CVL]) * leak)
    rate = max(rate, c[C_4_VT] * c[C_BE] * (c[C_CVX] + c[C_CTM]) * leak)
    hydraulic = c[C_4_VT] * c[C_BE] * c[C_DM] * c[C_DM] * c[C_INV_JM]  # resonance², 1/s²
    rate = max(rate, math.sqrt(hydraulic))
    wv = math.sqrt(c[C_WV2])
    zeta = c[C_DAMP] / (2.0 * wv)
    rate = max(rate, wv * (zeta + math.sqrt(max(zeta * zeta - 1.0, 0.0))))
    rate = max(rate, c[C_BM] * c[C_INV_JM] * thick)
    if e[_BACKLASH] > 0.5 or e[_SHAFT] > 0.5:
        mobility = c[C_INV_NETA] * c[C_INV_N] * c[C_INV_JM] + c[C_INV_JL]
        stiffness, damping = driveline_spring(e)
        rate = max(rate, math.sqrt(hydraulic + stiffness * mobility), damping * mobility)
    if e[_LOWPASS] > 0.5:
        rate = max(rate, 1.0 / e[_LOWPASS + 2])
    return rate
