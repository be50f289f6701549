"""The compiled, batched simulation kernel: fixed-step RK4 between samples, over M machines.

Per sample k of one machine (time t_k = t0 + k/fs):

1. the sensors are read from the state at t_k (plus filter state and scaled white noise), so the
   sample never sees its own command (a sampler reads, then the output stage updates);
2. the command u[k] passes the valve_hysteresis play operator and the transport_delay line;
3. the state is integrated over [t_k, t_k+1) with the command held (zero-order hold). With a dead
   time that is not a whole number of samples the held command switches once inside the
   interval; the interval is split there so the integrator never steps across a switch.

Each segment uses ceil(length / h) equal RK4 steps with h = 1 / (fs · substeps), or shorter for a machine whose
fastest mode would leave RK4's stability region (h·|λ| > ``STABLE_STEP``; a stiff relief or shaft, issue 12 item 5).
After every step the pressures are projected onto Ps >= 0, |PL| <= Ps. Everything the next sample needs is in the
state row, so chunked calls equal one long call bit for bit.

Speed: inside a segment the ODE state is a tuple of floats, and the right-hand side
(:func:`~hydrowatch.plant.dynamics.derivatives`) and the RK4 step are inlined into the step loop,
so a step runs in registers without calls or array traffic. The rare kink bisection calls an
outlined copy of the step, which keeps the compiled code (and the compile time) small. The sensors of
sample k come from the same evaluation of the right-hand side as the first RK4 stage of the interval
that follows (they do not depend on the command): 40 evaluations per sample at 10 substeps, not 41
(issue 12, item 5; every output the same bit for bit). The kink bisection steps from the state's first RK4 stage,
evaluated once, and keeps its last trial that left the region as the state past the kink (13 evaluations and one step
fewer per kink; a backlash model meets about one kink every 4 samples). Settling (:meth:`PlantSimulator.settle`: the
clock stopped, a constant command, no noise, no dead time) ends as soon as one sample leaves the state
unchanged bit for bit, since every later sample would apply the same map to the same state (about half
of the 3 s settle of a 120 s simulation; the same state and outputs).

Full state row of one machine (``state_width(ring)`` entries): the ODE state (``N_ODE``, see
:mod:`hydrowatch.plant.dynamics`), then the play operator's output [V], the sample counter k, the
delay line's write index and the delay line itself (``ring`` past commands, V).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hydrowatch.channels import PA_PER_BAR, PLANT
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
    State,
    X,
    coefficients,
    derivatives,
    fastest_rate,
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

CHANNELS_OUT = len(PLANT.measured)
"""Kernel output columns: the plant's measured channels (flow, speed, torque, supply_pressure,
load_pressure, temperature), in :attr:`hydrowatch.channels.ChannelSet.measured` order."""
N_SENSORS = len(PLANT.sensors)
"""Output columns 0 … N_SENSORS − 1: the noisy health sensors, in the order the dynamics return them."""
_SUPPLY, _LOAD, _TEMPERATURE = (PLANT.column(c) for c in ("supply_pressure", "load_pressure", "temperature"))

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
STABLE_STEP = 2.0
"""Largest h·|λ| a machine's RK4 step may take (its fastest mode, :func:`~hydrowatch.plant.dynamics.fastest_rate`);
RK4's stability edge is 2.79 on the negative real axis and 2.83 on the imaginary one. Beyond it the machine's step
shrinks below 1 / (fs · substeps)."""
_T_NOMINAL = REFERENCE_TEMPERATURE_C


def state_width(ring: int) -> int:
    """Length of one machine's state row for a delay line of ``ring`` samples."""
    return RING + ring


@njit(cache=True, error_model="numpy", inline="always")
def _region(c: np.ndarray, e: np.ndarray, y: State) -> int:
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


@njit(cache=True, error_model="numpy", inline="always")
def _shifted(y: State, a: float, k: State) -> State:
    """y + a·k, element by element."""
    return (y[0] + a * k[0], y[1] + a * k[1], y[2] + a * k[2], y[3] + a * k[3], y[4] + a * k[4],
            y[5] + a * k[5], y[6] + a * k[6], y[7] + a * k[7], y[8] + a * k[8])


@njit(cache=True, error_model="numpy", inline="always")
def _rk4_from(c: np.ndarray, e: np.ndarray, y: State, k1: State, u: float, t: float, h: float, clock: bool) -> State:
    """One classical RK4 step of length h [s] from (t, y) with the command u [V] held, given its first stage
    k1 = the derivative at (t, y); pressures projected."""
    k2 = derivatives(c, e, _shifted(y, 0.5 * h, k1), u, t + 0.5 * h, clock)[0]
    k3 = derivatives(c, e, _shifted(y, 0.5 * h, k2), u, t + 0.5 * h, clock)[0]
    k4 = derivatives(c, e, _shifted(y, h, k3), u, t + h, clock)[0]
    g = h / 6.0
    step = (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0], k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1],
            k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2], k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3],
            k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4], k1[5] + 2.0 * k2[5] + 2.0 * k3[5] + k4[5],
            k1[6] + 2.0 * k2[6] + 2.0 * k3[6] + k4[6], k1[7] + 2.0 * k2[7] + 2.0 * k3[7] + k4[7],
            k1[8] + 2.0 * k2[8] + 2.0 * k3[8] + k4[8])
    y_new = _shifted(y, g, step)
    ps = max(y_new[PS], 0.0)
    pl = min(max(y_new[PL], -ps), ps)
    return (y_new[0], y_new[1], ps, pl, y_new[4], y_new[5], y_new[6], y_new[7], y_new[8])


@njit(cache=True, error_model="numpy")
def _rk4_from_outlined(c: np.ndarray, e: np.ndarray, y: State, k1: State, u: float, t: float, h: float,
                       clock: bool) -> State:
    """:func:`_rk4_from` as a called function, for the rare kink bisection (small compiled code)."""
    return _rk4_from(c, e, y, k1, u, t, h, clock)


@njit(cache=True, error_model="numpy")
def _step_past_kink(c: np.ndarray, e: np.ndarray, y: State, k1: State, whole: State, u: float, t: float, h: float,
                    clock: bool, code: int) -> tuple[float, State]:
    """Where a step of length h [s] from (t, y) leaves region ``code``: bisection to 2**-12 of h.

    ``k1`` is the derivative at (t, y) with u: every trial step's first stage, evaluated once; ``whole`` is the
    step of the full length h, made already. Returns the length stepped [s] and the state just past the kink: the
    last trial that left the region (issue 12, item 5: 13 right-hand sides and one RK4 step fewer per kink than
    evaluating k1 in every trial and stepping to the kink again; the same numbers).
    """
    lo, hi = 0.0, 1.0
    past = whole
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        trial = _rk4_from_outlined(c, e, y, k1, u, t, mid * h, clock)
        if _region(c, e, trial) == code:
            lo = mid
        else:
            hi = mid
            past = trial
    return hi * h, past


@njit(cache=True, error_model="numpy")
def _rk4_segment(c: np.ndarray, e: np.ndarray, y: State, k1: State, u: float, t: float, length: float, h_max: float,
                 clock: bool) -> State:
    """Integrate y over ``length`` seconds from t with the command u held; returns the new state.

    ``k1`` is the derivative at (t, y) with u (the sample's sensors came from the same evaluation): the first
    step's first stage, not evaluated again. A step that leaves the smooth piece it started in (a kink of the
    right-hand side: relief valve cracking, spool through zero, stops, backlash contact) is split where it
    crosses, found by bisection to 2**-12 of a step (at most 4 splits per step), so RK4 keeps its order across kinks.
    """
    n_steps = max(1, int(math.ceil(length / h_max - 1e-9)))
    h = length / n_steps
    code = _region(c, e, y)
    first = k1
    for j in range(n_steps):
        tj = t + j * h
        left = h
        for split in range(_SPLITS):
            if j > 0 or split > 0:
                first = derivatives(c, e, y, u, tj, clock)[0]
            y_new = _rk4_from(c, e, y, first, u, tj, left, clock)
            new_code = _region(c, e, y_new)
            if split == _SPLITS - 1 or new_code == code:
                break
            done, y = _step_past_kink(c, e, y, first, y_new, u, tj, left, clock, code)
            code = _region(c, e, y)
            tj += done
            left -= done
        code = new_code
        y = y_new
    return y


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
    noise : ndarray, shape (M, n, N_SENSORS) or (0, 0, N_SENSORS)
        Standard normal draws for flow, speed, torque; an empty array means no noise.
    out : ndarray, shape (M, n, CHANNELS_OUT)
        Output: flow [L/min], speed [rad/s], torque [N·m], supply and load pressure [bar], temperature [°C].
    fs : float
        Sample rate, Hz.
    t0 : float
        Time of sample count 0, s.
    substeps : int
        RK4 steps per sample interval (h = 1 / (fs · substeps); more for a stiff machine, see ``STABLE_STEP``).
    clock : bool
        False: settle mode, the sample counter and the oil temperature do not advance.

    Notes
    -----
    The compiled loop releases the GIL. A read-only command (a broadcast view) is copied first,
    so every caller shares one compiled specialisation instead of compiling a second one.
    """
    if not command.flags.writeable:
        command = command.copy()
    _advance_compiled(params, effects, state, command, noise, out, float(fs), float(t0), int(substeps), bool(clock))


@njit(cache=True, error_model="numpy", inline="always")
def _same_bits(a: State, b: State) -> bool:
    """Whether two states are the same floats bit for bit (equal, and the same sign of zero; NaN never)."""
    for i in range(N_ODE):
        if a[i] != b[i] or math.copysign(1.0, a[i]) != math.copysign(1.0, b[i]):
            return False
    return True


@njit(cache=True, error_model="numpy", nogil=True)
def _advance_compiled(params, effects, state, command, noise, out, fs, t0, substeps, clock):  # noqa: ANN001
    """:func:`advance`, compiled (same arguments)."""
    n_machines, n_samples = command.shape
    ring = state.shape[1] - RING
    h_max = 1.0 / (fs * substeps)
    dt = 1.0 / fs
    noisy = noise.shape[0] > 0
    coef = np.empty(N_COEF + N_LOAD)
    for m in range(n_machines):
        p = params[m]
        coefficients(p, coef)
        e = effects[m]
        h_m = min(h_max, STABLE_STEP / fastest_rate(coef, e))
        s = state[m]
        y = (s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8])
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
        # Settling (clock stopped, no noise, no delay line, one command throughout): every sample applies the same
        # map to the state, so once a sample leaves it unchanged bit for bit, so does every later one.
        steady = not clock and not noisy and not delay
        if steady:
            for k in range(1, n_samples):
                if command[m, k] != command[m, 0]:
                    steady = False
                    break
        for k in range(n_samples):
            t = t0 + s[COUNT] / fs
            y_before = y
            hyst_before = s[HYST]
            # 2. command through the play operator and the delay line (what the spool gets from t_k on)
            u = command[m, k]
            if hysteresis:
                r = e[_HYSTERESIS + 1]
                u = min(max(s[HYST], u - r), u + r)
                s[HYST] = u
            u_first = u
            u_now = u
            if delay:
                w = int(s[WRITE])
                s[RING + w] = u
                s[WRITE] = (w + 1) % ring
                u_now = s[RING + (w - lag) % ring]
                u_first = s[RING + (w - lag - 1) % ring] if frac > 0.0 else u_now
            # 1. sensors at t_k: the state's derivative there (the first RK4 stage of the interval) gives them
            # too; they do not depend on the command (it moves only the spool's acceleration).
            k1, sens = derivatives(coef, e, y, u_first, t, clock)
            for c in range(N_SENSORS):
                value = y[YF] if c == lowpass else sens[c]
                out[m, k, c] = value + (p[_NOISE + c] * noise[m, k, c] if noisy else 0.0)
            out[m, k, _SUPPLY] = max(y[PS], 0.0) / PA_PER_BAR
            out[m, k, _LOAD] = y[PL] / PA_PER_BAR
            out[m, k, _TEMPERATURE] = y[TEMP] if e[_THERMAL] > 0.5 else _T_NOMINAL
            # 3. integrate over the sample interval
            if delay and frac > 0.0:
                y = _rk4_segment(coef, e, y, k1, u_first, t, frac * dt, h_m, clock)
                t_switch = t + frac * dt
                k1 = derivatives(coef, e, y, u_now, t_switch, clock)[0]
                y = _rk4_segment(coef, e, y, k1, u_now, t_switch, (1.0 - frac) * dt, h_m, clock)
            else:
                y = _rk4_segment(coef, e, y, k1, u_now, t, dt, h_m, clock)
            if clock:
                s[COUNT] += 1.0
            elif steady and s[HYST] == hyst_before and _same_bits(y, y_before):
                for later in range(k + 1, n_samples):
                    for c in range(CHANNELS_OUT):
                        out[m, later, c] = out[m, k, c]
                break
        for i in range(N_ODE):
            s[i] = y[i]
