"""The compiled, batched simulation kernel: fixed-step RK4 between samples, over M machines.

Per sample k of one machine (time t_k = t0 + k/fs):

1. the sensors are read from the state at t_k (plus filter state and scaled white noise), so the
   sample never sees its own command (a sampler reads, then the output stage updates);
2. the command u[k] passes the valve_hysteresis play operator and the transport_delay line;
3. the state is integrated over [t_k, t_k+1) with the command held (zero-order hold). With a dead
   time that is not a whole number of samples the held command switches once inside the
   interval; the interval is split there so the integrator never steps across a switch.

Each segment uses ceil(length / h) equal RK4 steps with h = 1 / (fs · substeps). After every step
the pressures are projected onto Ps >= 0, |PL| <= Ps. Everything the next sample needs is in the
state row, so chunked calls equal one long call bit for bit.

Full state row of one machine (``state_width(ring)`` entries): the ODE state (``N_ODE``, see
:mod:`hydrowatch.plant.dynamics`), then the play operator's output [V], the sample counter k, the
delay line's write index and the delay line itself (``ring`` past commands, V).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hydrowatch.plant.dynamics import (
    C_INV_N,
    C_PC,
    N_COEF,
    N_LOAD,
    N_ODE,
    PL,
    PS,
    TEMP,
    TH,
    WL,
    WM,
    YF,
    X,
    coefficients,
    rates,
    shaft_torque,
)
from hydrowatch.plant.effects import EFFECT_OFFSET, REFERENCE_TEMPERATURE_C
from hydrowatch.plant.parameters import PARAMETER_INDEX

HYST = N_ODE
"""State column: output of the valve_hysteresis play operator, V."""
COUNT = N_ODE + 1
"""State column: samples since t0 (an exact integer held as float64)."""
WRITE = N_ODE + 2
"""State column: write index of the delay line."""
RING = N_ODE + 3
"""First state column of the delay line."""

CHANNELS_OUT = 6
"""Kernel output columns: flow, speed, torque, supply_pressure, load_pressure, temperature."""

_HYSTERESIS = EFFECT_OFFSET["valve_hysteresis"]
_DELAY = EFFECT_OFFSET["transport_delay"]
_THERMAL = EFFECT_OFFSET["thermal_drift"]
_LOWPASS = EFFECT_OFFSET["sensor_lowpass"]
_NOISE = PARAMETER_INDEX["noise_flow"]  # noise_speed, noise_torque follow (checked in tests)
_SATURATION = EFFECT_OFFSET["valve_saturation"]
_DEADBAND = EFFECT_OFFSET["valve_deadband"]
_BACKLASH = EFFECT_OFFSET["gear_backlash"]
_BISECTIONS = 12
_SPLITS = 4
_T_NOMINAL = REFERENCE_TEMPERATURE_C


def state_width(ring: int) -> int:
    """Length of one machine's state row for a delay line of ``ring`` samples."""
    return RING + ring


@njit(cache=True, error_model="numpy")
def _region(c, e, y):  # noqa: ANN001
    """Code of the smooth piece of the right-hand side that y lies in (relief open, spool sign, stops...)."""
    x = y[X]
    code = 1 if y[PS] > c[C_PC] else 0
    if x >= 0.0:
        code += 2
    if e[_SATURATION] > 0.5 and abs(x) > e[_SATURATION + 1]:
        code += 4
    if e[_DEADBAND] > 0.5 and abs(x) > e[_DEADBAND + 1]:
        code += 8
    if e[_BACKLASH] > 0.5:
        if abs(y[TH]) > e[_BACKLASH + 1]:
            code += 16 if y[TH] > 0.0 else 32
            # Teeth in contact whose force would pull: the clamp in shaft_torque.
            if shaft_torque(e, y[TH], y[WM] * c[C_INV_N] - y[WL]) == 0.0:
                code += 64
    return code


@njit(cache=True, error_model="numpy")
def _rk4_step(c, e, y, u, t, h, clock, k1, k2, k3, k4, tmp, sens, y_new):  # noqa: ANN001
    """One classical RK4 step of length h from (t, y) with the command u held; result in y_new."""
    rates(c, e, y, u, t, clock, k1, sens)
    for i in range(N_ODE):
        tmp[i] = y[i] + 0.5 * h * k1[i]
    rates(c, e, tmp, u, t + 0.5 * h, clock, k2, sens)
    for i in range(N_ODE):
        tmp[i] = y[i] + 0.5 * h * k2[i]
    rates(c, e, tmp, u, t + 0.5 * h, clock, k3, sens)
    for i in range(N_ODE):
        tmp[i] = y[i] + h * k3[i]
    rates(c, e, tmp, u, t + h, clock, k4, sens)
    for i in range(N_ODE):
        y_new[i] = y[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    y_new[PS] = max(y_new[PS], 0.0)
    y_new[PL] = min(max(y_new[PL], -y_new[PS]), y_new[PS])


@njit(cache=True, error_model="numpy")
def _rk4_segment(c, e, y, u, t, length, h_max, clock, work, sens):  # noqa: ANN001
    """Integrate y over ``length`` seconds from t with the command u held; y is updated in place.

    A step that leaves the smooth piece it started in (a kink of the right-hand side: relief valve
    cracking, spool through zero, stops, backlash contact) is split where it crosses, found by
    bisection to 2**-12 of a step (at most 4 splits per step), so RK4 keeps its order across kinks.
    """
    k1, k2, k3, k4, tmp, y_new = work[0], work[1], work[2], work[3], work[4], work[5]
    n_steps = max(1, int(math.ceil(length / h_max - 1e-9)))
    h = length / n_steps
    code = _region(c, e, y)
    for j in range(n_steps):
        tj = t + j * h
        left = h
        for split in range(_SPLITS):
            _rk4_step(c, e, y, u, tj, left, clock, k1, k2, k3, k4, tmp, sens, y_new)
            new_code = _region(c, e, y_new)
            if split == _SPLITS - 1 or new_code == code:
                break
            lo, hi = 0.0, 1.0
            for _ in range(_BISECTIONS):
                mid = 0.5 * (lo + hi)
                _rk4_step(c, e, y, u, tj, mid * left, clock, k1, k2, k3, k4, tmp, sens, y_new)
                if _region(c, e, y_new) == code:
                    lo = mid
                else:
                    hi = mid
            _rk4_step(c, e, y, u, tj, hi * left, clock, k1, k2, k3, k4, tmp, sens, y)
            code = _region(c, e, y)
            tj += hi * left
            left -= hi * left
        code = new_code
        for i in range(N_ODE):
            y[i] = y_new[i]


@njit(cache=True, error_model="numpy")
def advance(params: np.ndarray, effects: np.ndarray, state: np.ndarray, command: np.ndarray,
            noise: np.ndarray, out: np.ndarray, fs: float, t0: float, substeps: int, clock: bool) -> None:
    """Advance M machines by n samples each; ``state`` is updated in place.

    Parameters
    ----------
    params : ndarray, shape (M, P)
        Parameter rows (PARAMETER_NAMES order, SI units).
    effects : ndarray, shape (M, EFFECT_WIDTH)
        Effect rows.
    state : ndarray, shape (M, S)
        Full state rows (module docstring); updated in place.
    command : ndarray, shape (M, n)
        Valve command, V.
    noise : ndarray, shape (M, n, 3) or (0, 0, 3)
        Standard normal draws for flow, speed, torque; an empty array means no noise.
    out : ndarray, shape (M, n, CHANNELS_OUT)
        Output: flow [L/min], speed [rad/s], torque [N·m], supply and load pressure [bar], temperature [°C].
    fs : float
        Sample rate, Hz.
    t0 : float
        Time of sample count 0, s.
    substeps : int
        RK4 steps per sample interval (h = 1 / (fs · substeps)).
    clock : bool
        False: settle mode, the sample counter and the oil temperature do not advance.
    """
    n_machines, n_samples = command.shape
    ring = state.shape[1] - RING
    h_max = 1.0 / (fs * substeps)
    dt = 1.0 / fs
    noisy = noise.shape[0] > 0
    y = np.empty(N_ODE)
    work = np.empty((6, N_ODE))
    k1 = work[0]
    sens = np.empty(3)
    coef = np.empty(N_COEF + N_LOAD)
    for m in range(n_machines):
        p = params[m]
        coefficients(p, coef)
        e = effects[m]
        s = state[m]
        for i in range(N_ODE):
            y[i] = s[i]
        hysteresis = e[_HYSTERESIS] > 0.5
        delay = e[_DELAY] > 0.5
        lag = 0
        frac = 0.0
        if delay:
            lag_samples = e[_DELAY + 1] * fs
            lag = int(math.floor(lag_samples + 1e-9))
            frac = lag_samples - lag
            if frac < 1e-9:
                frac = 0.0
        lowpass = int(e[_LOWPASS + 1]) if e[_LOWPASS] > 0.5 else -1
        for k in range(n_samples):
            t = t0 + s[COUNT] / fs
            # 1. sensors at t_k
            rates(coef, e, y, 0.0, t, clock, k1, sens)
            if lowpass >= 0:
                sens[lowpass] = y[YF]
            for c in range(3):
                out[m, k, c] = sens[c] + (p[_NOISE + c] * noise[m, k, c] if noisy else 0.0)
            out[m, k, 3] = max(y[PS], 0.0) / 1e5
            out[m, k, 4] = y[PL] / 1e5
            out[m, k, 5] = y[TEMP] if e[_THERMAL] > 0.5 else _T_NOMINAL
            # 2. command through the play operator and the delay line
            u = command[m, k]
            if hysteresis:
                r = e[_HYSTERESIS + 1]
                u = min(max(s[HYST], u - r), u + r)
                s[HYST] = u
            # 3. integrate over the sample interval
            if delay:
                w = int(s[WRITE])
                s[RING + w] = u
                s[WRITE] = (w + 1) % ring
                u_now = s[RING + (w - lag) % ring]
                if frac > 0.0:
                    u_before = s[RING + (w - lag - 1) % ring]
                    _rk4_segment(coef, e, y, u_before, t, frac * dt, h_max, clock, work, sens)
                    _rk4_segment(coef, e, y, u_now, t + frac * dt, (1.0 - frac) * dt, h_max, clock, work, sens)
                else:
                    _rk4_segment(coef, e, y, u_now, t, dt, h_max, clock, work, sens)
            else:
                _rk4_segment(coef, e, y, u, t, dt, h_max, clock, work, sens)
            if clock:
                s[COUNT] += 1.0
        for i in range(N_ODE):
            s[i] = y[i]
