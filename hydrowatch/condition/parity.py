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
- **valve and supply** (Eqs. 1, 2, 4, 5; study Eqs. 2.1, 2.2, 2.5): the spool follows
  x̂ = Kc·u/umax through its second-order lag; the supply line is integrated from the command side
  (pump, relief valve open or closed, and the valve's own flow QL = Kq·x̂·√(Ps − P̂L) drawing on
  it), and the flow sensor should read QL − Cvx·P̂L. Output error, not equation error: with the
  relief closed the line turns 0.006 L/min of flow into 1 bar of Ps, so feeding the measured flow
  back would amplify its noise and bias. Each valve-side fault moves this relation differently
  with the operating point: ``pump_leak`` (Cpl) sags Ps with flow demand, ``relief_spring`` (Pc)
  lowers it at every level, ``valve_coil`` (Kc) scales the flow uniformly, ``valve_leak`` (Cvx)
  removes a flow ∝ P̂L. One severity per hypothesis is fitted (grids, then Gauss-Newton;
  ``valve_leak``, linear, by exact least squares) on the residual averaged over 40 ms blocks, and
  the fit's RMS residual says how well that hypothesis alone explains the window. The loops are
  compiled kernels (:mod:`hydrowatch.condition.supply`).

Cref = Dp·ωp/Pc as in :mod:`hydrowatch.plant.faults`.

**Oil temperature.** Every laminar leakage scales with 1/viscosity, viscosity ∝ exp(−k·(T − 40 °C))
(the thermal_drift effect, plant-model.md), and viscous damping with viscosity. Given a window's
leakage factor exp(k·(T − 40 °C)) (:func:`leakage_factor`), the relations use the leakages at the
window's temperature and report leakage severities referred to 40 °C, the temperature at which
the nominal parameters and the health-state scale hold.
"""

from __future__ import annotations

import functools
from typing import cast

import numpy as np

# the kernels' modules, not the package (its __init__ imports features, which imports this: tests/test_layers.py)
import hydrowatch.condition.severity_search as severity_search
import hydrowatch.condition.supply as supply
from hydrowatch.channels import M3S_TO_LPM
from hydrowatch.errors import ParameterError
from hydrowatch.plant.effects import REFERENCE_TEMPERATURE_C
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SAMPLE_RATE_HZ

VALVE_HYPOTHESES: tuple[str, ...] = ("pump_leak", "relief_spring", "valve_coil", "valve_leak")
"""Valve/supply-side faults, each fitted as a one-parameter hypothesis of the valve relation."""
SEVERITY_LIMITS: dict[str, tuple[float, float]] = {
    "pump_leak": (-0.05, 3.0), "relief_spring": (-0.5, 0.95), "valve_coil": (-0.5, 0.95), "valve_leak": (-0.2, 3.0),
}
"""Range searched for each valve-side severity (negative: better than nominal; a pump leak above -Cp/Cref)."""
LINEAR_HYPOTHESES: tuple[str, ...] = ("valve_leak",)
"""Valve-side hypotheses whose residual is linear in the severity (fitted exactly, held fits in closed form)."""


def reference_conductance(p: PlantParameters) -> float:
    """Cref = Dp·ωp/Pc, m³/(s·Pa): the leak that passes the pump's geometric flow at cracking pressure."""
    return p.Dp * p.omega_p / p.Pc


def leakage_factor(temperature: np.ndarray | None, m: int, viscosity_coefficient: float) -> np.ndarray:
    """Leakage factor exp(k·(T̄ − 40 °C)) per window, shape (m, 1); 1 where no temperature is known.

    Parameters
    ----------
    temperature : ndarray, shape (m, n), or None
        Oil temperature per sample, °C (the window mean is used: the oil warms over minutes).
    viscosity_coefficient : float
        k, 1/K: viscosity ∝ exp(−k·(T − 40 °C)).
    """
    if temperature is None:
        return np.ones((m, 1))
    return np.exp(viscosity_coefficient * (np.mean(temperature, axis=1, keepdims=True) - REFERENCE_TEMPERATURE_C))


def derivative(x: np.ndarray, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """Time derivative along the last axis by central differences (one-sided at the ends), unit/s."""
    return np.gradient(x, axis=-1) * sample_rate


def spool_position(voltage: np.ndarray, p: PlantParameters, sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """Nominal spool position x̂ (normalised) seen by each sample, shape like ``voltage`` (Eq. 3).

    The spool ẍ = ωv²·(Kc·u/umax − x) − 2ζv·ωv·ẋ is discretised exactly for a command held over
    each sample interval (zero-order hold); sample k is read before u[k] acts, so x̂[k] depends on
    u[k−1], u[k−2], … Every window starts at rest at its first command.
    """
    from scipy.signal import lfilter

    num, den, zi = (np.array(c) for c in _spool_filter(p.omega_v, p.zeta_v, sample_rate))
    u = np.atleast_2d(np.asarray(voltage, dtype=np.float64)) * (p.Kc / p.u_max)
    x = lfilter(num, den, u, axis=-1, zi=zi[None, :] * u[:, :1])[0]
    return x.reshape(np.shape(voltage))


@functools.lru_cache(maxsize=16)
def _spool_filter(wv: float, zv: float, sample_rate: float) -> tuple[tuple[float, ...], ...]:
    """Numerator, denominator and rest state under a unit command of :func:`spool_position`'s filter.

    Discretising (a matrix exponential) costs ~1 ms, more than filtering a few windows: a scorer
    judging windows as they close calls this with the same spool on every batch, hence the cache.
    """
    from scipy.signal import cont2discrete, lfilter_zi

    a = np.array([[0.0, 1.0], [-wv * wv, -2.0 * zv * wv]])
    b = np.array([[0.0], [wv * wv]])
    ad, bd, _, _, _ = cont2discrete((a, b, np.array([[1.0, 0.0]]), np.zeros((1, 1))), 1.0 / sample_rate, "zoh")
    # Transfer function x[k]/u[k] from the state-space pair (one-sample delay included by the ZOH).
    den = np.array([1.0, -np.trace(ad), np.linalg.det(ad)])
    c = np.array([1.0, 0.0])
    num = np.array([0.0, c @ bd[:, 0], c @ (ad @ bd[:, 0]) - np.trace(ad) * (c @ bd[:, 0])])
    zi = lfilter_zi(num, den)  # the filter's state at rest under a unit command
    return tuple(num.tolist()), tuple(den.tolist()), tuple(zi.tolist())


def load_pressure(speed: np.ndarray, torque: np.ndarray, p: PlantParameters,
                  sample_rate: float = SAMPLE_RATE_HZ, leak: float | np.ndarray = 1.0) -> np.ndarray:
    """P̂L from the shaft balance, Pa: (Jm·N·ω̇ + Bm·N·ω + T/(N·η))/Dm (Eq. 7, rigid gearbox).

    ``leak`` is the oil's leakage factor per window, shape (m, 1) or scalar (:func:`leakage_factor`):
    viscous damping Bm scales with viscosity, i.e. with 1/leak.
    """
    return (p.Jm * p.N * derivative(speed, sample_rate) + p.Bm / leak * p.N * speed
            + torque / (p.N * p.eta)) / p.Dm


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


def load_terms(speed: np.ndarray, torque: np.ndarray, p: PlantParameters,
               sample_rate: float = SAMPLE_RATE_HZ) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 7 over blocks of :data:`BLOCK` samples: T − JL·ω̇ − BL·ω, N·m, and the brake's shape tanh(ω/ωs), each
    (m, blocks); the derivative integrates exactly to a difference, so the 28 Hz resonance leaves no error."""
    return (block_means(torque - p.BL * speed) - p.JL * block_rates(speed, sample_rate=sample_rate),
            block_means(np.tanh(speed / p.omega_s)))


def load_relation(speed: np.ndarray, torque: np.ndarray, p: PlantParameters,
                  sample_rate: float = SAMPLE_RATE_HZ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Load severity s (TL·(1 + s)), the relation's RMS residual, N·m, and its regressor (Eq. 7): least squares of
    :func:`load_terms`' T − JL·ω̇ − BL·ω = TL·(1 + s)·tanh(ω/ωs) per window."""
    y, phi = load_terms(speed, torque, p, sample_rate)
    tl, rms = _one_parameter_fit(y, phi)
    return tl / p.TL - 1.0, rms, phi * p.TL


def motor_relation(flow: np.ndarray, speed: np.ndarray, pl: np.ndarray, p: PlantParameters,
                   sample_rate: float = SAMPLE_RATE_HZ,
                   leak: float | np.ndarray = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Motor-leak severity s (Ctm + s·Cref), the relation's RMS residual, L/min, and its regressor (Eqs. 6, 8).

    Q − N·Dm·ω − (Vt/4βe)·dP̂L/dt = Ctm·P̂L with Q the flow sensor, m³/s, integrated over blocks.
    With a leakage factor ``leak`` (m, 1) the fitted conductance is (Ctm + s·Cref)·leak, so s is
    referred to the reference temperature.
    """
    y = block_means(flow - p.N * p.Dm * speed) - p.Vt / (4.0 * p.beta_e) * block_rates(pl, sample_rate=sample_rate)
    phi = block_means(pl)
    ctm, rms = _one_parameter_fit(y, phi)
    c_ref = reference_conductance(p)
    factor = np.broadcast_to(np.asarray(leak, dtype=np.float64).reshape(-1, 1), (y.shape[0], 1))
    return (ctm / factor[:, 0] - p.Ctm) / c_ref, rms * M3S_TO_LPM, phi * factor * c_ref * M3S_TO_LPM


def supply_and_valve_flow(spool_gain: np.ndarray, pl: np.ndarray, p: PlantParameters, leakage: np.ndarray,
                          pc: np.ndarray, sample_rate: float = SAMPLE_RATE_HZ) -> tuple[np.ndarray, np.ndarray]:
    """Supply pressure Ps, Pa, and valve flow QL, m³/s, that the pump, relief and valve settle to (Eqs. 1, 2, 4, 5).

    (Vs/βe)·dPs/dt = Dp·ωp − C·Ps − Kr·max(0, Ps − Pc) − |QL(Ps)|, QL = g·√(Ps ∓ P̂L), is
    integrated through each window from the command side (output error: the measured flow does
    not enter, so flow noise cannot be amplified by the supply line's 1/C ≈ 1 bar per 0.006 L/min
    when the relief is closed). One exact exponential step per sample with QL linearised about the
    previous pressure, on the branch (relief open or closed) the pressure is on. With the relief
    open the line settles in < 1 ms; closed (pump limit above ~3.5 V, a leaking pump, a weak
    relief spring) it lags by tens of ms, which a quasi-static Ps would miss. Starts at the
    equilibrium of the first sample.

    Parameters
    ----------
    spool_gain : ndarray, shape (m, n)
        g = Kq·Kc·x̂, m³/(s·√Pa).
    pl : ndarray, shape (m, n)
        Load pressure P̂L, Pa.
    leakage : ndarray, shape (m,)
        Total supply-side leakage C = Cp + Cpl + Cvl per window (at the oil's temperature), m³/(s·Pa).
    pc : ndarray, shape (m,)
        Cracking pressure per window, Pa.

    Returns
    -------
    (ndarray, ndarray), each shape (m, n)
        Ps [Pa] and QL [m³/s].
    """
    ps = np.empty(spool_gain.shape)
    ql = np.empty(spool_gain.shape)
    supply.track_supply(np.ascontiguousarray(spool_gain, dtype=np.float64), np.ascontiguousarray(pl, dtype=np.float64),
                        np.ascontiguousarray(leakage, dtype=np.float64), np.ascontiguousarray(pc, dtype=np.float64),
                        p.Dp * p.omega_p, p.Kr, p.beta_e / p.Vs, 1.0 / sample_rate, ps, ql)
    return ps, ql


def valve_flow_prediction(spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str | None,
                          severity: np.ndarray, leak: float | np.ndarray = 1.0) -> np.ndarray:
    """Flow the valve relation predicts for the sensor, QL − Cvx·P̂L, m³/s, under one valve-side fault (Eqs. 4, 8).

    Parameters
    ----------
    spool : ndarray, shape (m, n)
        Nominal spool position x̂ (Kc = nominal).
    pl : ndarray, shape (m, n)
        Load pressure P̂L, Pa.
    fault : str or None
        One of :data:`VALVE_HYPOTHESES`, or None for the nominal relation.
    severity : ndarray, shape (m,)
        Severity per window on the fault's scale (ignored for None), referred to the reference temperature.
    leak : float or ndarray, shape (m, 1)
        Leakage factor of the oil per window: every laminar leakage (Cp, Cpl, Cvl, Cvx) is scaled by it.
    """
    return supply_under(spool, pl, p, fault, severity, leak)[1]


def supply_under(spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str | None, severity: np.ndarray,
                 leak: float | np.ndarray = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Supply pressure Ps [Pa] and :func:`valve_flow_prediction`'s flow [m³/s], each (m, n), under one valve-side
    fault (same arguments)."""
    m = spool.shape[0]
    s = np.asarray(severity, dtype=np.float64).reshape(m)
    factor = np.broadcast_to(np.asarray(leak, dtype=np.float64).reshape(-1), (m,))
    c_ref = reference_conductance(p)
    cpl = s * c_ref + p.Cpl if fault == "pump_leak" else np.full(m, p.Cpl)
    pc = p.Pc * (1.0 - s) if fault == "relief_spring" else np.full(m, p.Pc)
    kc = 1.0 - s if fault == "valve_coil" else np.ones(m)
    cvx = (s * c_ref + p.Cvx if fault == "valve_leak" else np.full(m, p.Cvx)) * factor
    ps, ql = supply_and_valve_flow(p.Kq * kc[:, None] * spool, pl, p, (cpl + p.Cp + p.Cvl) * factor, pc)
    return ps, ql - cvx[:, None] * pl


def valve_residual(flow: np.ndarray, spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str | None,
                   severity: np.ndarray, leak: float | np.ndarray = 1.0) -> np.ndarray:
    """Valve-relation residual (measured − predicted flow), L/min, averaged over blocks of :data:`BLOCK` samples.

    Shape (m, (n − 1) // BLOCK). Block averaging leaves the sensor noise (and the load-pressure
    noise each hypothesis propagates differently) √BLOCK times smaller while keeping every
    structural misfit, so hypotheses are compared on how they explain the flow, not the noise.
    """
    return block_means((flow - valve_flow_prediction(spool, pl, p, fault, severity, leak)) * M3S_TO_LPM)


def _kernel_inputs(flow: np.ndarray, spool: np.ndarray, pl: np.ndarray, p: PlantParameters,
                   leak: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Contiguous float64 inputs of :mod:`hydrowatch.condition.supply`: g = Kq·x̂, P̂L, Q, leakage factor (m,)."""
    m = flow.shape[0]
    f = np.ascontiguousarray(np.broadcast_to(np.asarray(leak, dtype=np.float64).reshape(-1), (m,)))
    return (np.ascontiguousarray(p.Kq * spool, dtype=np.float64), np.ascontiguousarray(pl, dtype=np.float64),
            np.ascontiguousarray(flow, dtype=np.float64), f)


PRESSURE_STEP = 1e4
"""Step of P̂L, Pa (0.1 bar), for the predicted flow's slope ∂Q̂/∂P̂L (:func:`noise_share`)."""
BLOCK_NOISE = (0.5 + (BLOCK - 1)) / BLOCK**2
"""Variance of a trapezoid block mean of :data:`BLOCK` intervals of white noise, over the noise's variance."""
KEPT_SHARE = 0.05
"""The least share of a valve MSE kept after its noise share is taken out (:func:`without_noise`)."""


def noise_share(spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str | None, severity: np.ndarray,
                leak: float | np.ndarray, pl_noise: np.ndarray) -> np.ndarray:
    """What white noise of σ ``pl_noise`` (m,), Pa, on P̂L adds to a hypothesis' :func:`valve_mse` where the relief
    holds the supply pressure, (L/min)², (m,).

    The predicted flow follows P̂L's noise with slope ∂Q̂/∂P̂L, which differs between hypotheses: a weaker relief
    spring lowers Ps − P̂L and steepens it (∂Q̂/∂P̂L ∝ 1/√(Ps − P̂L)), a weaker coil flattens it. P̂L comes from the
    torque transducer, so on a noisy DAQ the relief hypothesis paid 2–7 % of its MSE for the noise and the coil 1–2 %,
    and a worn relief spring read as a weak coil (errors in variables; ``benchmarks/bench_valve_eiv.py``). The share is
    mean_b (∂Q̂/∂P̂L)_b² · σ² · :data:`BLOCK_NOISE` over the relation's blocks, the slope to a step of P̂L common to
    every sample (:data:`PRESSURE_STEP`). With the relief open that is the noise's share (the supply pressure settles
    within a sample); where the pump is at its limit the line follows a step and not the noise, and the slope leaves
    out most of the share there (exact in :func:`supply.block_noise_variance`, which read healthy windows as a leak).
    """
    m = spool.shape[0]
    s = np.broadcast_to(np.asarray(severity, dtype=np.float64).reshape(-1), (m,))
    base = valve_flow_prediction(spool, pl, p, fault, s, leak)
    moved = valve_flow_prediction(spool, pl + PRESSURE_STEP, p, fault, s, leak)
    slope = block_means((moved - base) / PRESSURE_STEP * M3S_TO_LPM)
    return cast(np.ndarray, np.mean(slope**2, axis=1) * np.asarray(pl_noise, dtype=np.float64) ** 2 * BLOCK_NOISE)


def without_noise(mse: np.ndarray, spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str | None,
                  severity: np.ndarray, leak: float | np.ndarray, pl_noise: np.ndarray | None) -> np.ndarray:
    """``mse`` (m,) less its :func:`noise_share` in the windows whose P̂L noise is measured (> 0), at least
    :data:`KEPT_SHARE` of it."""
    if pl_noise is None:
        return mse
    sigma = np.asarray(pl_noise, dtype=np.float64).reshape(-1)
    rows = np.flatnonzero(sigma > 0.0)
    if rows.size == 0:
        return mse
    s = np.broadcast_to(np.asarray(severity, dtype=np.float64).reshape(-1), (mse.shape[0],))
    lk = leak if np.ndim(leak) == 0 else np.asarray(leak).reshape(-1, 1)[rows]
    share = noise_share(spool[rows], pl[rows], p, fault, s[rows], lk, sigma[rows])
    out = np.array(mse, dtype=np.float64, copy=True)
    out[rows] = np.maximum(out[rows] - share, KEPT_SHARE * out[rows])
    return out


def valve_mse(flow: np.ndarray, spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str | None,
              severity: np.ndarray, leak: float | np.ndarray = 1.0, sample_rate: float = SAMPLE_RATE_HZ,
              pl_noise: np.ndarray | None = None) -> np.ndarray:
    """Mean squared :func:`valve_residual`, (L/min)², shape (m,), computed without storing the signals; with
    ``pl_noise`` (m,), P̂L's measured noise per window, Pa, less what that noise adds (:func:`without_noise`)."""
    g, pl_c, q, f = _kernel_inputs(flow, spool, pl, p, leak)
    s = np.ascontiguousarray(np.broadcast_to(np.asarray(severity, dtype=np.float64).reshape(-1), (flow.shape[0],)))
    mse = supply.residual_mse(supply.HYPOTHESIS_CODES[fault], s, g, pl_c, q, f, supply.constants(p, sample_rate),
                              BLOCK)
    return without_noise(mse, spool, pl, p, fault, s, leak, pl_noise)


def valve_relation(flow: np.ndarray, spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str,
                   grid: int = 7, iterations: int = 4, leak: float | np.ndarray = 1.0,
                   sample_rate: float = SAMPLE_RATE_HZ) -> tuple[np.ndarray, np.ndarray]:
    """Severity of one valve-side fault hypothesis and its RMS residual, L/min (Eqs. 1, 2, 4, 5).

    :func:`valve_fit` also returns the fit's curvature.

    The severity minimising the block-averaged flow residual over :data:`SEVERITY_LIMITS` is found
    per window by :func:`hydrowatch.condition.severity_search.fit_windows`: a coarse grid, a local grid
    around its best point, then damped Gauss-Newton steps; ``valve_leak`` (linear in its
    severity) by exact least squares.
    """
    s, mse, _ = valve_fit(flow, spool, pl, p, fault, grid, iterations, leak, sample_rate)
    return s, np.sqrt(mse)


def valve_fit(flow: np.ndarray, spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str,
              grid: int = 7, iterations: int = 4, leak: float | np.ndarray = 1.0,
              sample_rate: float = SAMPLE_RATE_HZ, pl_noise: np.ndarray | None = None,
              flat_search: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`valve_relation`'s severity, mean squared residual, (L/min)², and curvature d(MSE)/d(s²), each (m,);
    with ``pl_noise`` less P̂L's noise share (:func:`without_noise`); ``flat_search`` False leaves a fit on a flat
    stretch (curvature 0) for :func:`~hydrowatch.condition.estimates.parity_estimates` to search again if poor."""
    if grid < 3 or iterations < 0:
        raise ParameterError(f"grid must be >= 3 and iterations >= 0. Got {grid}, {iterations}; defaults 7, 4.")
    lo, hi = SEVERITY_LIMITS[fault]
    g, pl_c, q, f = _kernel_inputs(flow, spool, pl, p, leak)
    s, mse, curvature = (np.empty(flow.shape[0]) for _ in range(3))
    severity_search.fit_windows(supply.HYPOTHESIS_CODES[fault], lo, hi, grid, iterations, flat_search, g, pl_c, q,
                                f, supply.constants(p, sample_rate), BLOCK, s, mse, curvature)
    return s, without_noise(mse, spool, pl, p, fault, s, leak, pl_noise), curvature
