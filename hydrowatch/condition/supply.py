"""Compiled kernels of the valve relation: the supply line, block residuals and one-hypothesis fits.

The valve relation (plant-model.md Eqs. 1, 2, 4, 5; study Eqs. 2.1, 2.2, 2.5) integrates the
supply line from the command side, (Vs/βe)·dPs/dt = Dp·ωp − C·Ps − Kr·max(0, Ps − Pc) − |QL|,
QL = g·√(Ps ∓ P̂L), and compares QL − Cvx·P̂L with the flow sensor over blocks of ``block``
samples (trapezoidal means, L/min). :mod:`hydrowatch.condition.parity` explains the model; this
module holds the loops, fused so that a severity search touches each sample once per trial and
allocates nothing per trial; the search itself is :mod:`hydrowatch.condition.severity_search`.

A valve-side hypothesis (code: 0 pump_leak, 1 relief_spring, 2 valve_coil, 3 valve_leak, −1
nominal) with severity s sets, for a window whose oil has leakage factor f:

- C = (Cp + Cpl + Cvl + [s·Cref if pump_leak])·f, supply-side leakage, m³/(s·Pa);
- Pc·(1 − s) if relief_spring, cracking pressure, Pa;
- Kc·(1 − s) if valve_coil, the spool gain's factor;
- Cvx = (Cvx + [s·Cref if valve_leak])·f, cross-port leakage, m³/(s·Pa).

``valve_leak`` leaves the supply line alone (it only draws QL − Cvx·P̂L), so its residual is
linear in s and its fit is exact least squares on one integration
(:func:`hydrowatch.condition.severity_search.fit_windows`).

The kernels are compiled with NumPy's error model (no zero-division check per division in the
inner loops, ~6 % faster; every divisor is a positive conductance, a block count or guarded by
``max``), which changes no result (tested against the kernels' Python source).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hydrowatch.channels import M3S_TO_LPM
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SAMPLE_RATE_HZ

HYPOTHESIS_CODES: dict[str | None, int] = {None: -1, "pump_leak": 0, "relief_spring": 1, "valve_coil": 2,
                                           "valve_leak": 3}
"""Kernel code of each valve-side hypothesis (None: the nominal relation)."""
LINEAR = 3
"""Code of the hypothesis whose residual is linear in its severity (valve_leak)."""
NOISE_STEP = 10.0
"""Step of Ps and P̂L, Pa (0.1 mbar), of the forward differences that linearise the supply line
(:func:`noise_variance`)."""


@njit(cache=True, error_model="numpy")
def _valve_flow(g: float, pl: float, ps: float) -> tuple[float, float]:
    """QL = g·√(Ps ∓ PL) and d|QL|/dPs."""
    drop = ps - pl if g >= 0.0 else ps + pl
    if drop <= 0.0:
        return 0.0, 0.0
    root = np.sqrt(drop)
    return g * root, abs(g) / (2.0 * max(root, 30.0))  # slope capped below ~10 mbar of drop


@njit(cache=True, error_model="numpy")
def _equilibrium(g: float, pl: float, c: float, pc: float, q_geo: float, kr: float) -> float:
    """Supply pressure at which pump, leakage, relief and valve balance, Pa (bisection: the balance falls with Ps)."""
    lo, hi = 0.0, q_geo / c
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if q_geo - c * mid - kr * max(0.0, mid - pc) - abs(_valve_flow(g, pl, mid)[0]) > 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@njit(cache=True, error_model="numpy")
def _step(ps: float, g: float, pl: float, c: float, pc: float, q_geo: float, kr: float, stiffness: float,
          dt: float) -> float:
    """One exact exponential step of the supply line over dt with QL linearised about ``ps``, Pa."""
    q, slope = _valve_flow(g, pl, ps)
    q_net = q_geo - abs(q) + slope * ps  # pump flow less the linearised valve demand
    c_eff = c + slope
    if ps > pc:
        target = (q_net + kr * pc) / (kr + c_eff)
        rate = stiffness * (c_eff + kr) * dt
        ps = target + (ps - target) * np.exp(-rate) if rate < 50.0 else target
    else:
        target = q_net / c_eff
        ps = target + (ps - target) * np.exp(-stiffness * c_eff * dt)
        if ps > pc:  # crossed the cracking pressure within the step: the relief holds it
            ps = max((q_net + kr * pc) / (kr + c_eff), pc)
    return max(ps, 0.0)


@njit(cache=True, error_model="numpy")
def track_supply(gain: np.ndarray, pl: np.ndarray, leakage: np.ndarray, pc: np.ndarray, q_geo: float, kr: float,
                 stiffness: float, dt: float, ps_out: np.ndarray, ql_out: np.ndarray) -> None:
    """Ps [Pa] and QL [m³/s] of windows (m, n) into ``ps_out``, ``ql_out``; see :func:`parity.supply_and_valve_flow`."""
    m, n = gain.shape
    for i in range(m):
        ps = _equilibrium(gain[i, 0], pl[i, 0], leakage[i], pc[i], q_geo, kr)
        ps_out[i, 0] = ps
        ql_out[i, 0] = _valve_flow(gain[i, 0], pl[i, 0], ps)[0]
        for k in range(1, n):
            ps = _step(ps, 0.5 * (gain[i, k - 1] + gain[i, k]), 0.5 * (pl[i, k - 1] + pl[i, k]), leakage[i], pc[i],
                       q_geo, kr, stiffness, dt)
            ps_out[i, k] = ps
            ql_out[i, k] = _valve_flow(gain[i, k], pl[i, k], ps)[0]


@njit(cache=True, error_model="numpy")
def sweep(code: int, sev: np.ndarray, g: np.ndarray, pl: np.ndarray, q: np.ndarray, f: float, base: np.ndarray,
           block: int, r: np.ndarray, sse: np.ndarray) -> None:
    """Block-mean residuals (measured − predicted flow), L/min, of one window under hypothesis ``code`` at J severities.

    ``sev`` (J,), ``r`` (≥ J, nb) and ``sse`` (≥ J,) receive the residuals and Σ r² per severity;
    ``base`` is :func:`constants`. The J supply lines are integrated side by side in one pass over
    the samples: each is a chain of dependent divisions, roots and exponentials, so several in
    flight at once run nearly as fast as one.
    """
    n = g.shape[0]
    nb = r.shape[1]
    nj = sev.shape[0]
    q_geo, kr, stiffness, dt = base[4], base[5], base[6], base[7]
    c = np.empty(nj)
    pc = np.empty(nj)
    kc = np.empty(nj)
    cvx = np.empty(nj)
    ps = np.empty(nj)
    e_prev = np.empty(nj)
    for j in range(nj):
        s = sev[j]
        c[j] = (base[0] + (s * base[3] if code == 0 else 0.0)) * f
        pc[j] = base[1] * (1.0 - s) if code == 1 else base[1]
        kc[j] = 1.0 - s if code == 2 else 1.0
        cvx[j] = (base[2] + (s * base[3] if code == 3 else 0.0)) * f
        ps[j] = _equilibrium(kc[j] * g[0], pl[0], c[j], pc[j], q_geo, kr)
        e_prev[j] = (q[0] - _valve_flow(kc[j] * g[0], pl[0], ps[j])[0] + cvx[j] * pl[0]) * M3S_TO_LPM
        r[j, :] = 0.0
    for k in range(1, n):
        b = (k - 1) // block
        g_mid = 0.5 * (g[k - 1] + g[k])
        pl_mid = 0.5 * (pl[k - 1] + pl[k])
        for j in range(nj):
            ps[j] = _step(ps[j], kc[j] * g_mid, pl_mid, c[j], pc[j], q_geo, kr, stiffness, dt)
            e = (q[k] - _valve_flow(kc[j] * g[k], pl[k], ps[j])[0] + cvx[j] * pl[k]) * M3S_TO_LPM
            if b < nb:
                r[j, b] += 0.5 * (e_prev[j] + e)
            e_prev[j] = e
    for j in range(nj):
        total = 0.0
        for i in range(nb):
            r[j, i] /= block
            total += r[j, i] * r[j, i]
        sse[j] = total


@njit(cache=True, error_model="numpy")
def residual_mse(code: int, severity: np.ndarray, g: np.ndarray, pl: np.ndarray, q: np.ndarray, f: np.ndarray,
                 base: np.ndarray, block: int) -> np.ndarray:
    """Mean squared block residual, (L/min)², of windows (m, n) each at its own severity (m,)."""
    m, n = g.shape
    nb = (n - 1) // block
    r = np.empty((1, nb))
    sse = np.empty(1)
    out = np.empty(m)
    for i in range(m):
        sweep(code, severity[i:i + 1], g[i], pl[i], q[i], f[i], base, block, r, sse)
        out[i] = sse[0] / nb
    return out


@njit(cache=True, error_model="numpy")
def noise_variance(code: int, severity: np.ndarray, g: np.ndarray, pl: np.ndarray, f: np.ndarray, base: np.ndarray,
                   block: int) -> np.ndarray:
    """Variance of each block residual, (L/min)² per Pa², that white noise of unit variance on P̂L adds, windows
    (m, n) each under hypothesis ``code`` at its own severity (m,): shape (m, (n − 1) // block).

    The noise reaches the predicted flow twice: at once through the orifice (∂QL/∂P̂L) and through the supply
    pressure, which integrates it (each step's P̂L is the mean of two samples). The supply line is linearised along
    its trajectory (forward differences of one step, :data:`NOISE_STEP`), δPs_k = A_k·δPs_{k−1} + ½B_k·(u_{k−1} +
    u_k), δQ̂_k = c_k·δPs_k + D_k·u_k, and the variance of each trapezoidal block mean is propagated exactly through
    that linear system (the state ψ_k = δPs_k − ½B_k·u_k is independent of u_k). A step of P̂L common to every
    sample, which moves the supply pressure with it, is not that noise: where the relief is closed the line lags by
    tens of ms and follows a step but not the noise (development unit: 1.4 against 7.7 mL/min in a 2.5–3 V band).
    """
    m, n = g.shape
    nb = (n - 1) // block
    out = np.zeros((m, nb))
    q_geo, kr, stiffness, dt = base[4], base[5], base[6], base[7]
    h = NOISE_STEP
    for i in range(m):
        s = severity[i]
        c = (base[0] + (s * base[3] if code == 0 else 0.0)) * f[i]
        pc = base[1] * (1.0 - s) if code == 1 else base[1]
        kc = 1.0 - s if code == 2 else 1.0
        cvx = (base[2] + (s * base[3] if code == 3 else 0.0)) * f[i]
        ps = _equilibrium(kc * g[i, 0], pl[i, 0], c, pc, q_geo, kr)
        var_p, cov, var_s, b_prev = 0.0, 0.0, 0.0, 0.0  # Var ψ, Cov(ψ, block sum), Var block sum, B of the last step
        c_out, d_out = _output_slopes(kc * g[i, 0], pl[i, 0], ps, cvx, 0.0, h)
        for k in range(1, n + 1):
            if k < n:  # the step to sample k and its slopes
                g_mid, pl_mid = 0.5 * kc * (g[i, k - 1] + g[i, k]), 0.5 * (pl[i, k - 1] + pl[i, k])
                nxt = _step(ps, g_mid, pl_mid, c, pc, q_geo, kr, stiffness, dt)
                a = (_step(ps + h, g_mid, pl_mid, c, pc, q_geo, kr, stiffness, dt) - nxt) / h
                b_k = (_step(ps, g_mid, pl_mid + h, c, pc, q_geo, kr, stiffness, dt) - nxt) / h
                b = 0.5 * (a * b_prev + b_k)
            else:
                a, b, b_k, nxt = 0.0, 0.0, 0.0, ps
            j = k - 1  # sample j joins the blocks of its two intervals, (j − 1, j) and (j, j + 1), with ½ each
            lo, hi = (j - 1) // block, j // block
            w_lo = 0.5 / block if j >= 1 and lo < nb else 0.0
            w_hi = 0.5 / block if j <= n - 2 and hi < nb else 0.0
            if lo == hi or w_lo == 0.0:
                w = w_lo + w_hi
                var_s += 2.0 * w * c_out * cov + w * w * (c_out * c_out * var_p + d_out * d_out)
                cov = a * cov + w * (a * c_out * var_p + b * d_out)
            else:  # a block boundary: the ending block is complete, the next starts with this sample
                var_s += 2.0 * w_lo * c_out * cov + w_lo * w_lo * (c_out * c_out * var_p + d_out * d_out)
                out[i, lo] = var_s
                var_s = w_hi * w_hi * (c_out * c_out * var_p + d_out * d_out)
                cov = w_hi * (a * c_out * var_p + b * d_out)
            if hi < nb:
                out[i, hi] = var_s
            var_p = a * a * var_p + b * b
            if k < n:
                ps, b_prev = nxt, b_k
                c_out, d_out = _output_slopes(kc * g[i, k], pl[i, k], ps, cvx, b_k, h)
    return out * M3S_TO_LPM**2


@njit(cache=True, error_model="numpy")
def _output_slopes(g: float, pl: float, ps: float, cvx: float, b: float, h: float) -> tuple[float, float]:
    """(c, d) of the predicted flow QL − Cvx·P̂L at one sample: ∂/∂Ps, and the sample's own noise's total slope
    ½c·B + ∂/∂P̂L (module :func:`noise_variance`)."""
    q = _valve_flow(g, pl, ps)[0]
    c = (_valve_flow(g, pl, ps + h)[0] - q) / h
    d = (_valve_flow(g, pl + h, ps)[0] - q) / h - cvx
    return c, 0.5 * c * b + d


def block_noise_variance(spool: np.ndarray, pl: np.ndarray, p: PlantParameters, fault: str | None,
                         severity: np.ndarray, leak: float | np.ndarray, block: int,
                         sample_rate: float = SAMPLE_RATE_HZ) -> np.ndarray:
    """Variance that white noise of unit variance on P̂L adds to each block residual of the valve relation under one
    hypothesis, (L/min)² per Pa², shape (m, (n − 1) // block) (:func:`noise_variance`; ``spool`` x̂, ``pl`` P̂L [Pa],
    (m, n) each). The unit's identification weights its blocks by it (:mod:`hydrowatch.condition.unit`); the health
    relation takes out only the relief-open share (:func:`hydrowatch.condition.parity.noise_share`).

    Not the slope of the prediction to a step of P̂L common to every sample: the supply pressure follows such a step
    and not the noise where the relief is closed (the pump at its limit, a leaking pump, a weak spring); that slope
    read the noise's share 5–35 × too small there, and identification preferred supply pressures far above the load's,
    where the flow barely follows P̂L (seed 2049, unit 13, torque noise 2.9 × the default: the relief's cracking
    pressure 2.1 × the unit's; docs/unseen-units.md).
    """
    m = spool.shape[0]
    s = np.ascontiguousarray(np.broadcast_to(np.asarray(severity, dtype=np.float64).reshape(-1), (m,)))
    f = np.ascontiguousarray(np.broadcast_to(np.asarray(leak, dtype=np.float64).reshape(-1), (m,)))
    g = np.ascontiguousarray(p.Kq * spool, dtype=np.float64)
    return noise_variance(HYPOTHESIS_CODES[fault], s, g, np.ascontiguousarray(pl, dtype=np.float64), f,
                          constants(p, sample_rate), block)


def constants(p: PlantParameters, sample_rate: float) -> np.ndarray:
    """Nominal constants of the kernels, shape (8,).

    [Cp + Cpl + Cvl (m³/(s·Pa)), Pc (Pa), Cvx (m³/(s·Pa)), Cref = Dp·ωp/Pc (m³/(s·Pa)),
    Dp·ωp (m³/s), Kr (m³/(s·Pa)), βe/Vs (Pa/m³), dt (s)].
    """
    return np.array([p.Cp + p.Cpl + p.Cvl, p.Pc, p.Cvx, p.Dp * p.omega_p / p.Pc, p.Dp * p.omega_p, p.Kr,
                     p.beta_e / p.Vs, 1.0 / sample_rate])
