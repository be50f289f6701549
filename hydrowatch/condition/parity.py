"""Component relations (parity equations) of the nominal plant and per-window parameter estimates.

Every fault is a parameter change (plant-model.md, "Health states"), so a window of the four raw
signals can be asked directly how much each parameter has moved. Each relation below holds if one
component behaves as modelled; regressing its residual on the regressor a fault scales gives that
fault's severity on the scale of :mod:`hydrowatch.plant.faults`, whatever the command did, as long
as the window excites the regressor. All arrays are ``(n_windows, n)`` in SI units (flow in m³/s,
pressure in Pa, speed in rad/s, torque in N·m); estimates are ``(n_windows,)``.

- **load pressure** (plant-model.md Eq. 7; study Eq. 2.4), from the torque transducer:
  Dm·P̂L = Jm·N·ω̇ + Bm·N·ω + T/(N·η)  (no load parameter enters).
- **load** (Eq. 7): T − JL·ω̇ − BL·ω = TL·(1 + s)·tanh(ω/ωs); s by least squares.
- **motor** (Eqs. 6, 8; study Eq. 2.3): Q − N·Dm·ω − (Vt/4βe)·dP̂L/dt = (Ctm + s·Cref)·P̂L.
- **valve and supply** (Eqs. 1, 2, 4, 5 quasi-static; study Eqs. 2.1, 2.2, 2.5): the spool follows
  x̂ = Kc·u/umax through its second-order lag; the supply pressure that the pump and relief valve
  hold for a valve flow demand QL = Q + Cvx·P̂L is Ps(QL) (relief open or closed, closed form); the
  flow sensor should read Q = Kq·x̂·√(Ps − P̂L) − Cvx·P̂L. Each valve-side fault moves this relation
  differently with the operating point: ``pump_leak`` (Cpl) sags Ps with flow demand,
  ``relief_spring`` (Pc) lowers it at every level, ``valve_coil`` (Kc) scales the flow uniformly,
  ``valve_leak`` (Cvx) removes a flow ∝ P̂L. One severity per hypothesis is fitted by
  Gauss-Newton (a coarse grid first), and the fit's RMS residual says how well that hypothesis
  alone explains the window.

Cref = Dp·ωp/Pc as in :mod:`hydrowatch.plant.faults`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SAMPLE_RATE_HZ

M3S_TO_LPM = 60000.0
"""m³/s → L/min."""
VALVE_HYPOTHESES: tuple[str, ...] = ("pump_leak", "relief_spring", "valve_coil", "valve_leak")
"""Valve/supply-side faults, each fitted as a one-parameter hypothesis of the valve relation."""
SEVERITY_LIMITS: dict[str, tuple[float, float]] = {
    "pump_leak": (-0.05, 3.0), "relief_spring": (-0.5, 0.95), "valve_coil": (-0.5, 0.95), "valve_leak": (-0.2, 3.0),
}
"""Range searched for each valve-side severity (negative: better than nominal; a pump leak above -Cp/Cref)."""


def reference_conductance(p: PlantParameters) -> float:
    """Cref = Dp·ωp/Pc, m³/(s·Pa): the leak that passes the pump's geometric flow at cracking pressure."""
    return p.Dp * p.omega_p / p.Pc


def derivative(x: np.ndarray, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """Time derivative along the last axis by central differences (one-sided at the ends), unit/s."""
    return np.gradient(x, axis=-1) * sample_rate


def spool_position(voltage: np.ndarray, p: PlantParameters, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """Nominal spool position x̂ (normalised) seen by each sample, shape like ``voltage`` (Eq. 3).

    The spool ẍ = ωv²·(Kc·u/umax − x) − 2ζv·ωv·ẋ is discretised exactly for a command held over
    each sample interval (zero-order hold); sample k is read before u[k] acts, so x̂[k] depends on
    u[k−1], u[k−2], … Every window starts at rest at its first command.
    """
    from scipy.signal import cont2discrete, lfilter, lfilter_zi

    wv, zv = p.omega_v, p.zeta_v
    a = np.array([[0.0, 1.0], [-wv * wv, -2.0 * zv * wv]])
    b = np.array([[0.0], [wv * wv]])
    ad, bd, _, _, _ = cont2discrete((a, b, np.array([[1.0, 0.0]]), np.zeros((1, 1))), 1.0 / sample_rate, "zoh")
    # Transfer function x[k]/u[k] from the state-space pair (one-sample delay included by the ZOH).
    den = np.array([1.0, -np.trace(ad), np.linalg.det(ad)])
    c = np.array([1.0, 0.0])
    num = np.array([0.0, c @ bd[:, 0], c @ (ad @ bd[:, 0]) - np.trace(ad) * (c @ bd[:, 0])])
    u = np.atleast_2d(np.asarray(voltage, dtype=np.float64)) * (p.Kc / p.u_max)
    zi = lfilter_zi(num, den)  # the filter's state at rest under a unit command
    x = lfilter(num, den, u, axis=-1, zi=zi[None, :] * u[:, :1])[0]
    return x.reshape(np.shape(voltage))


def load_pressure(speed: np.ndarray, torque: np.ndarray, p: PlantParameters,
                  sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """P̂L from the shaft balance, Pa: (Jm·N·ω̇ + Bm·N·ω + T/(N·η))/Dm (Eq. 7, rigid gearbox)."""
    return (p.Jm * p.N * derivative(speed, sample_rate) + p.Bm * p.N * speed + torque / (p.N * p.eta)) / p.Dm


BLOCK = 8
"""Samples per block over which the load and motor relations are integrated (40 ms at 200 Hz)."""


def block_means(x: np.ndarray, block: int = BLOCK) -> np.ndarray:
    """Trapezoidal mean of x over consecutive blocks of ``block`` intervals, shape (m, (n − 1) // block)."""
    cum = np.concatenate([np.zeros((x.shape[0], 1)), np.cumsum(0.5 * (x[:, 1:] + x[:, :-1]), axis=1)], axis=1)
    edges = cum[:, ::block]
    return np.diff(edges, axis=1) / block


def block_rates(x: np.ndarray, block: int = BLOCK, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """Mean rate of change of x over the same blocks as :func:`block_means`, (x_end − x_start)/(block·dt)."""
    edges = x[:, ::block]
    return np.diff(edges, axis=1) * sample_rate / block


def _one_parameter_fit(y: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of y ≈ θ·phi per row: (θ, RMS residual)."""
    theta = np.einsum("ij,ij->i", y, phi) / np.maximum(np.einsum("ij,ij->i", phi, phi), 1e-300)
    residual = y - theta[:, None] * phi
    return theta, np.sqrt(np.mean(residual * residual, axis=1))


def load_relation(speed: np.ndarray, torque: np.ndarray, p: PlantParameters,
                  sample_rate: float = SAMPLE_RATE_HZ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Load severity s (TL·(1 + s)), the relation's RMS residual, N·m, and its regressor (Eq. 7).

    T − JL·ω̇ − BL·ω = TL·(1 + s)·tanh(ω/ωs), integrated over blocks of :data:`BLOCK` samples
    (the derivative then integrates exactly to a difference, so the 28 Hz resonance leaves no
    differentiation error), least squares for TL·(1 + s) per window.
    """
    y = block_means(torque - p.BL * speed) - p.JL * block_rates(speed, sample_rate=sample_rate)
    phi = block_means(np.tanh(speed / p.omega_s))
    tl, rms = _one_parameter_fit(y, phi)
    return tl / p.TL - 1.0, rms, phi * p.TL


def motor_relation(flow: np.ndarray, speed: np.ndarray, pl: np.ndarray, p: PlantParameters,
                   sample_rate: float = SAMPLE_RATE_HZ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Motor-leak severity s (Ctm + s·Cref), the relation's RMS residual, L/min, and its regressor (Eqs. 6, 8).

    Q − N·Dm·ω − (Vt/4βe)·dP̂L/dt = Ctm·P̂L with Q the flow sensor, m³/s, integrated over blocks.
    """
    y = block_means(flow - p.N * p.Dm * speed) - p.Vt / (4.0 * p.beta_e) * block_rates(pl, sample_rate=sample_rate)
    phi = block_means(pl)
    ctm, rms = _one_parameter_fit(y, phi)
    c_ref = reference_conductance(p)
    return (ctm - p.Ctm) / c_ref, rms * M3S_TO_LPM, phi * c_ref * M3S_TO_LPM


def supply_pressure(valve_flow: np.ndarray, p: PlantParameters, cpl: float | np.ndarray,
                    pc: float | np.ndarray, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """Supply pressure Ps, Pa, that the pump and relief valve hold for a valve flow demand (Eqs. 1, 2, 5).

    (Vs/βe)·dPs/dt = Dp·ωp − (Cp + Cpl + Cvl)·Ps − Kr·max(0, Ps − Pc) − |QL| is integrated
    through each window, one exact exponential step per sample on the branch (relief open or
    closed) the pressure is on, with the demand averaged over the interval. With the relief open
    the line settles in < 1 ms, so Ps follows the demand; with it closed (pump limit above
    ~3.5 V, a leaking pump, a weak relief spring) the line's volume makes Ps lag by
    Vs/(βe·C) ≈ 0.2 s, which a quasi-static Ps would miss. Starts at the quasi-static value.

    Parameters
    ----------
    valve_flow : ndarray, shape (m, n)
        Valve flow demand QL, m³/s.
    cpl, pc : float or ndarray, shape (m, 1)
        Extra pump leakage, m³/(s·Pa), and cracking pressure, Pa, per window.
    """
    m, n = valve_flow.shape
    cpl_row = np.broadcast_to(np.asarray(cpl, dtype=np.float64).reshape(-1), (m,)).copy()
    pc_row = np.broadcast_to(np.asarray(pc, dtype=np.float64).reshape(-1), (m,)).copy()
    out = np.empty((m, n))
    _track_supply(np.ascontiguousarray(np.abs(valve_flow)), cpl_row, pc_row, p.Dp * p.omega_p, p.Cp + p.Cvl, p.Kr,
                  p.beta_e / p.Vs, 1.0 / sample_rate, out)
    return out


@njit(cache=True)
def _track_supply(demand: np.ndarray, cpl: np.ndarray, pc: np.ndarray, q_geo: float, c_base: float, kr: float,
                  stiffness: float, dt: float, out: np.ndarray) -> None:
    m, n = demand.shape
    for i in range(m):
        c = c_base + cpl[i]
        decay_closed = np.exp(-stiffness * c * dt)
        decay_open = np.exp(-stiffness * (c + kr) * dt)
        q = q_geo - demand[i, 0]
        ps = q / c
        if ps > pc[i]:
            ps = (q + kr * pc[i]) / (kr + c)
        ps = max(ps, 0.0)
        out[i, 0] = ps
        for k in range(1, n):
            q = q_geo - 0.5 * (demand[i, k - 1] + demand[i, k])
            if ps > pc[i]:
                target = (q + kr * pc[i]) / (kr + c)
                ps = target + (ps - target) * decay_open
            else:
                target = q / c
                ps = target + (ps - target) * decay_closed
                if ps > pc[i]:  # crossed the cracking pressure within the step: the relief holds it
                    ps = max((q + kr * pc[i]) / (kr + c), pc[i])
            ps = max(ps, 0.0)
            out[i, k] = ps


def valve_flow_prediction(flow: np.ndarray, spool: np.ndarray, pl: np.ndarray, p: PlantParameters,
                          fault: str | None, severity: np.ndarray) -> np.ndarray:
    """Flow the valve relation predicts for the sensor, m³/s, under one valve-side fault hypothesis (Eq. 4).

    Parameters
    ----------
    flow : ndarray, shape (m, n)
        Measured flow Q, m³/s (sets the flow demand on the supply).
    spool : ndarray, shape (m, n)
        Nominal spool position x̂ (Kc = nominal).
    pl : ndarray, shape (m, n)
        Load pressure P̂L, Pa.
    fault : str or None
        One of :data:`VALVE_HYPOTHESES`, or None for the nominal relation.
    severity : ndarray, shape (m,)
        Severity per window on the fault's scale (ignored for None).
    """
    s = np.asarray(severity, dtype=np.float64)[:, None]
    c_ref = reference_conductance(p)
    cpl = s * c_ref + p.Cpl if fault == "pump_leak" else p.Cpl
    pc = p.Pc * (1.0 - s) if fault == "relief_spring" else p.Pc
    kc = 1.0 - s if fault == "valve_coil" else 1.0
    cvx = s * c_ref + p.Cvx if fault == "valve_leak" else p.Cvx
    ps = supply_pressure(flow + cvx * pl, p, cpl, pc)
    drop = np.where(spool >= 0.0, ps - pl, ps + pl)
    return p.Kq * kc * spool * np.sqrt(np.maximum(drop, 0.0)) - cvx * pl


def valve_relation(flow: np.ndarray, spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str,
                   grid: int = 7, iterations: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Severity of one valve-side fault hypothesis and its RMS residual, L/min (Eqs. 1, 2, 4, 5).

    The severity minimising the flow residual is found per window by a coarse grid over
    :data:`SEVERITY_LIMITS` followed by damped Gauss-Newton steps (numerical derivative).
    """
    lo, hi = SEVERITY_LIMITS[fault]
    m = flow.shape[0]

    def sse(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = (flow - valve_flow_prediction(flow, spool, pl, p, fault, s)) * M3S_TO_LPM
        return r, np.einsum("ij,ij->i", r, r)

    candidates = np.linspace(lo, hi, grid)
    costs = np.stack([sse(np.full(m, c))[1] for c in candidates], axis=1)
    s = candidates[np.argmin(costs, axis=1)]
    span = (hi - lo) / (grid - 1)
    delta = 1e-4 * (hi - lo)
    for _ in range(iterations):
        r, cost = sse(s)
        jac = (sse(s + delta)[0] - r) / delta
        step = -np.einsum("ij,ij->i", jac, r) / np.maximum(np.einsum("ij,ij->i", jac, jac), 1e-300)
        trial = np.clip(s + np.clip(step, -span, span), lo, hi)
        better = sse(trial)[1] < cost
        s = np.where(better, trial, s)
    r, cost = sse(s)
    return s, np.sqrt(cost / flow.shape[1])
