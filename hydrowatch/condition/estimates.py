"""Per-window parity estimates from raw windows, and the residual of each relation inside a parameter box.

:func:`window_signals` converts windows of (voltage, flow, speed, torque[, temperature]) into SI
signals (with the oil's leakage factor when the temperature channel is there) and
fills the sensors a sparse configuration lacks from the nominal relations of
:mod:`hydrowatch.condition.parity` (a relation used to fill a channel can then no longer test
anything, so it is dropped). :func:`parity_estimates` fits every relation once per window;
:func:`relation_mse` gives each relation's mean squared residual when the parameters are held
inside a box (a health state's severity band), which is what the health-state scores compare
(:mod:`hydrowatch.condition.ratios` turns them into the states' ratios).
The raw windows' layout (channels, checks, cutting a recording) is :mod:`hydrowatch.condition.layout`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hydrowatch.channels import M3S_TO_LPM
from hydrowatch.condition import load_fill, parity
from hydrowatch.condition.attribution import NOMINAL_VALVE
from hydrowatch.condition.capacity import PUMP_LIMIT, PUMP_LIMITED, limit_ratio, limited_share
from hydrowatch.condition.determinacy import STANDSTILL
from hydrowatch.condition.held import window_noise
from hydrowatch.condition.layout import CHANNELS, WIDTH
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import INPUT

RELATIONS: tuple[str, ...] = ("load", "motor", "valve")
"""Component relations, in feature order."""
LPM_TO_M3S = 1.0 / M3S_TO_LPM
REFIT_GRID = 19
"""Coarse-grid points of the second valve search for fits that end on a search limit (:func:`parity_estimates`)."""
REFIT_EXCESS = 1.1
"""A fit on a search limit is searched again only when its MSE exceeds the best valve hypothesis's by this factor
(on a plateau every hypothesis that explains the window is as good: nothing to find)."""

MOVING_LOAD = "load_moving"
"""Key, in :class:`ParityEstimates`, of the load relation fitted away from standstill (:func:`moving_load_fit`): what
the load's degradation index reads (:mod:`hydrowatch.condition.degradation`)."""

FILL_ITERATIONS = 3
"""Fixed-point passes of the speed fill from flow (P̂L depends on ω through Eq. 7; converges in 2)."""


@dataclass(frozen=True)
class WindowSignals:
    """SI signals of a batch of windows, shape (m, n) each, and the relations they can test."""

    voltage: np.ndarray
    flow: np.ndarray
    speed: np.ndarray
    torque: np.ndarray
    load_pressure: np.ndarray
    spool: np.ndarray
    relations: tuple[str, ...]
    leak: np.ndarray
    """Leakage factor of the oil per window, shape (m, 1) (1 at 40 °C or without temperature)."""
    pl_noise: np.ndarray | None = None
    """White noise of P̂L per window, Pa, shape (m,), 0 where the window cannot tell it
    (:func:`~hydrowatch.condition.held.window_noise`); the valve relation takes its share out."""


def fill_faults(sensors: Sequence[str]) -> tuple[str, ...]:
    """Faults whose parameter the filling of the missing sensors uses (:func:`window_signals`): TL, Ctm."""
    have = set(sensors)
    used = set()
    if "torque" not in have or ("speed" not in have and "flow" not in have):
        used.add("load")
    if "flow" not in have or ("speed" not in have and "flow" in have):
        used.add("motor_leak")
    return tuple(f for f in ("load", "motor_leak") if f in used)


def window_signals(windows: np.ndarray, sensors: Sequence[str], p: PlantParameters,
                   viscosity_coefficient: float = 0.0, fill: PlantParameters | None = None) -> WindowSignals:
    """SI signals of valid windows (m, n, 4 or 5), missing sensors filled from the relations of ``fill``.

    With a 5th (temperature) channel the leakage factor exp(k·(T̄ − 40 °C)), k =
    ``viscosity_coefficient`` [1/K], enters every relation (:mod:`hydrowatch.condition.parity`).

    Filling rules (parameters ``fill``, default ``p``; only TL and Ctm enter, :func:`fill_faults`):
    torque from the load relation (Eq. 7) given speed; speed from the motor relation (Eq. 6) given
    flow, or integrated through the load relation given torque only
    (:func:`~hydrowatch.condition.load_fill.speed_from_torque`); flow from the motor relation given
    speed. The relations used to fill are not tested. Filling with a health state's own
    parameters (per-state hypotheses, :func:`~hydrowatch.condition.ratios.state_ratios`) keeps a load or motor
    fault visible to the relations left: a nominal fill would hide it.
    """
    q = p if fill is None else fill
    have = set(sensors)
    u = windows[:, :, CHANNELS.index(INPUT)]
    flow = windows[:, :, CHANNELS.index("flow")] * LPM_TO_M3S
    speed = windows[:, :, CHANNELS.index("speed")]
    torque = windows[:, :, CHANNELS.index("torque")]
    relations = set(RELATIONS)
    leak = parity.leakage_factor(windows[:, :, WIDTH] if windows.shape[2] > WIDTH else None, u.shape[0],
                                 viscosity_coefficient)
    if "speed" not in have:
        if "flow" in have:  # the motor relation solved for ω, P̂L (Eq. 7) refined by fixed-point iteration
            speed = flow / (p.N * p.Dm)
            for _ in range(FILL_ITERATIONS):
                pl = parity.load_pressure(speed, torque if "torque" in have else load_fill.load_torque(speed, q), p,
                                          leak=leak)
                moving = (flow - q.Ctm * leak * pl) / (p.N * p.Dm)
                # The leak can take all the flow (a stalled motor) but cannot turn the motor backwards.
                speed = np.where(flow >= 0.0, np.maximum(moving, 0.0), np.minimum(moving, 0.0))
            relations.discard("motor")
        else:
            speed = load_fill.speed_from_torque(torque, q)
            relations.discard("load")
    if "torque" not in have:
        torque = load_fill.load_torque(speed, q)
        relations.discard("load")
    pl = parity.load_pressure(speed, torque, p, leak=leak)
    if "flow" not in have:
        flow = p.N * p.Dm * speed + q.Ctm * leak * pl + p.Vt / (4.0 * p.beta_e) * parity.derivative(pl)
        relations.discard("motor")
    measured = window_noise(pl) if {"speed", "torque"} <= have else np.zeros(pl.shape[0])
    return WindowSignals(u, flow, speed, torque, pl, parity.spool_position(u, p),
                         tuple(r for r in RELATIONS if r in relations), leak, measured)


SE_INFLATION = 2.0
"""Factor on the least-squares standard error for the block residuals' correlation (docs/degradation.md)."""


@dataclass(frozen=True)
class ParityEstimates:
    """Unconstrained per-window estimates, each shape (m,).

    Attributes
    ----------
    severity : dict of str to ndarray
        Severity of every fault on its :mod:`hydrowatch.plant.faults` scale (load and motor_leak
        from their own relations, the valve-side faults from one-hypothesis fits of the valve relation).
    mse : dict of str to ndarray
        Minimum mean squared residual: ``load`` (N·m)², ``motor`` and each valve hypothesis (L/min)²; also the valve
        relation's at nominal, :data:`~hydrowatch.condition.attribution.NOMINAL_VALVE` (every valve-side part at 0).
    curvature : dict of str to ndarray
        d(MSE)/d(severity²) of every fault, so that MSE(s) = mse + curvature·(s − ŝ)² (exact for
        the linear relations load, motor_leak and valve_leak; Gauss-Newton's near the fit for the others).
    """

    severity: Mapping[str, np.ndarray]
    mse: Mapping[str, np.ndarray]
    curvature: Mapping[str, np.ndarray]


def severity_standard_error(mse: np.ndarray, curvature: np.ndarray, blocks: int,
                            inflation: float = SE_INFLATION) -> np.ndarray:
    """Standard error of a one-parameter fit's severity, shape (m,): inflation·√(MSE_min / ((N − 1)·c)).

    Parameters
    ----------
    mse : ndarray, shape (m,)
        Minimum mean squared block residual of the fit (its relation's unit squared).
    curvature : ndarray, shape (m,)
        d(MSE)/d(s²) at the fit (same unit per severity²); 0 or negative gives an infinite error.
    blocks : int
        Residual blocks N per window ((window − 1) // :data:`hydrowatch.condition.parity.BLOCK`).
    inflation : float, default :data:`SE_INFLATION`
        Factor for correlated residuals.
    """
    c = np.asarray(curvature, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        se = inflation * np.sqrt(np.asarray(mse, dtype=np.float64) / (max(blocks - 1, 1) * c))
    return np.where(c > 0.0, se, np.inf)


def merged_estimates(found: list[tuple[np.ndarray, ParityEstimates]], valid: np.ndarray) -> ParityEstimates | None:
    """One :class:`~hydrowatch.condition.estimates.ParityEstimates` of the ``valid`` windows (mask over all) from
    those of the oil parts, each with a mask of its windows' positions among all; None when there are none."""
    if len(found) <= 1:
        return found[0][1] if found else None
    fields = []
    for name in ("severity", "mse", "curvature"):
        merged = {}
        for key in getattr(found[0][1], name):
            full = np.full(valid.size, np.nan)
            for at, estimates in found:
                full[at] = getattr(estimates, name)[key]
            merged[key] = full[valid]
        fields.append(merged)
    return ParityEstimates(*fields)


def moving_load_fit(speed: np.ndarray, torque: np.ndarray, p: PlantParameters
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The load relation (Eq. 7, :func:`parity.load_relation`) fitted on the blocks whose every sample is at least
    :data:`~hydrowatch.condition.determinacy.STANDSTILL` × ωs from standstill: (severity, MSE (N·m)², curvature) per
    window, NaN, NaN, 0 where no block is.

    There tanh(ω/ωs) ≥ 0.995 and the brake's torque is TL·(1 + s) within 1.5 % for an ωs up to 1.25 × the identified
    one; nearer standstill it depends on ωs, which a commissioning recording gives to ±25 % (fresh seed 2072, unit 6:
    identified at 1.235 × the unit's, from filtered noise 0–4 V). A worn machine that stalls in the duty cycle's low
    holds then read its brake 15–28 % heavier in those windows: the load's index up to 0.22 on a healthy load while a
    leak wore past its alert, 1.9–2.5 % of the path's windows (docs/degradation.md).
    """
    y, shape = parity.load_terms(speed, torque, p)
    phi = shape * p.TL
    away = (parity.block_means((np.abs(speed) < STANDSTILL * p.omega_s).astype(np.float64)) == 0.0).astype(np.float64)
    blocks = away.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        tl = np.einsum("ij,ij->i", away * y, phi) / np.einsum("ij,ij->i", away * phi, phi)
        residual = away * (y - tl[:, None] * phi)
        mse = np.einsum("ij,ij->i", residual, residual) / blocks
        curvature = np.einsum("ij,ij->i", away * phi, phi) / blocks
    none = blocks == 0
    return np.where(none, np.nan, tl - 1.0), np.where(none, np.nan, mse), np.where(none, 0.0, curvature)


def parity_estimates(sig: WindowSignals, p: PlantParameters, valve_search: bool = True) -> ParityEstimates:
    """Fit every relation once per window (:mod:`hydrowatch.condition.parity`).

    With ``valve_search`` False the valve-side faults are not searched but held at nominal (one
    integration for all four): enough for windows filled with a load or motor state's own
    parameters, whose box keeps every valve-side fault near nominal (:func:`~hydrowatch.condition.ratios.state_ratios`).
    """
    severity: dict[str, np.ndarray] = {}
    mse: dict[str, np.ndarray] = {}
    curvature: dict[str, np.ndarray] = {}
    severity["load"], rms, phi = parity.load_relation(sig.speed, sig.torque, p)
    mse["load"] = rms**2
    curvature["load"] = np.mean(phi**2, axis=1)
    severity[MOVING_LOAD], mse[MOVING_LOAD], curvature[MOVING_LOAD] = moving_load_fit(sig.speed, sig.torque, p)
    severity["motor_leak"], rms, phi = parity.motor_relation(sig.flow, sig.speed, sig.load_pressure, p,
                                                             leak=sig.leak)
    mse["motor"] = rms**2
    curvature["motor_leak"] = np.mean(phi**2, axis=1)
    nominal = parity.valve_mse(sig.flow, sig.spool, sig.load_pressure, p, None, np.zeros(sig.flow.shape[0]),
                               sig.leak, pl_noise=sig.pl_noise)
    mse[NOMINAL_VALVE] = nominal  # every valve-side part at nominal: what a pool's misfit is bounded by (attribution)
    for fault in parity.VALVE_HYPOTHESES:
        if valve_search:
            severity[fault], mse[fault], curvature[fault] = parity.valve_fit(sig.flow, sig.spool, sig.load_pressure,
                                                                             p, fault, leak=sig.leak,
                                                                             pl_noise=sig.pl_noise, flat_search=False)
        else:
            severity[fault], mse[fault], curvature[fault] = np.zeros(nominal.size), nominal, np.zeros(nominal.size)
    if valve_search:
        best = np.min([mse[f] for f in parity.VALVE_HYPOTHESES], axis=0)
        for fault in parity.VALVE_HYPOTHESES:
            severity[fault], mse[fault], curvature[fault] = _refit_poor_fits(sig, p, fault, severity[fault],
                                                                             mse[fault], curvature[fault], best)
        severity[PUMP_LIMIT] = limit_ratio(sig.spool, sig.load_pressure, p, severity["pump_leak"], sig.leak)
        severity[PUMP_LIMITED] = limited_share(sig.spool, sig.load_pressure, p, sig.leak)  # attribution's say
    return ParityEstimates(severity, mse, curvature)


def _refit_poor_fits(sig: WindowSignals, p: PlantParameters, fault: str, severity: np.ndarray, mse: np.ndarray,
                     curvature: np.ndarray, best: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Search again, on a :data:`REFIT_GRID`-point coarse grid and past flat stretches, the windows whose fit ended
    on a search limit or on a flat stretch (curvature 0: the first search leaves flat stretches alone) more than
    :data:`REFIT_EXCESS` × worse than the best valve hypothesis ``best`` (m,).

    Near pump saturation the relief barely cracks: a relief_spring (or valve_coil) residual is
    flat over every severity that keeps the relief shut and has a narrow valley at the true one, about twice as wide
    as the true severity's distance from the stretch's end, which the default 7-point coarse grid (0.24 apart) and
    its local grid (0.08) step over; the fit then stops on the plateau, and the true state's own box
    looks 10–100× worse than a look-alike's. The finer grid (0.08 apart for relief_spring: 13
    points still missed the valley of a spring fault at a 12.5 % drop held at 3.9 V) and the search past the
    plateau's ends (:func:`hydrowatch.condition.severity_search.fit_windows`) find it; the
    better of the two fits is kept. A fit on a limit or a plateau that explains the window about as well as
    the best hypothesis is a plateau with nothing to find and is left alone; so 26 of 260 windows
    of a 0–4 V duty cycle (13 states) were searched again for one hypothesis, 21 of them pump_leak
    fits that end 2× better, and none of filtered noise: +0–5 % CPU with three sensors, +5–15 %
    with torque only (its filled flow leaves more fits on a limit). Until 2026-12-01 only fits on a limit were
    searched again, and of equal costs the search kept the first (the lower limit); a relief whose plateau did not
    reach the limit (a valley missed from −0.26 or −0.02) stayed on it, 417× the coil's MSE in one window of a
    tuning relief path (seed 2054 unit 2), and the pool blamed the coil for the next 60 windows
    (docs/degradation.md). Searching past every plateau in the first search cost +27–55 % CPU per window.
    """
    if fault in parity.LINEAR_HYPOTHESES:
        return severity, mse, curvature
    lo, hi = parity.SEVERITY_LIMITS[fault]
    edge = 1e-9 * (hi - lo)
    stuck = (severity <= lo + edge) | (severity >= hi - edge) | (curvature <= 0.0)
    again = np.flatnonzero(stuck & (mse > REFIT_EXCESS * best))
    if again.size:
        noise = None if sig.pl_noise is None else sig.pl_noise[again]
        s2, m2, c2 = parity.valve_fit(sig.flow[again], sig.spool[again], sig.load_pressure[again], p, fault,
                                      grid=REFIT_GRID, leak=sig.leak[again], pl_noise=noise)
        better = m2 < mse[again]
        idx = again[better]
        severity, mse, curvature = severity.copy(), mse.copy(), curvature.copy()
        severity[idx], mse[idx], curvature[idx] = s2[better], m2[better], c2[better]
    return severity, mse, curvature


def relation_mse(sig: WindowSignals, est: ParityEstimates, p: PlantParameters,
                 box: Mapping[str, tuple[float, float]],
                 cache: dict[tuple[object, ...], np.ndarray] | None = None,
                 own: str | None = None) -> dict[str, np.ndarray]:
    """Mean squared residual of each relation with every severity held inside ``box``.

    Parameters
    ----------
    box : mapping of fault to (low, high)
        Allowed severity of every fault (a health state's band for its own fault, a small
        tolerance around 0 for the others).

    Returns
    -------
    dict of relation to ndarray, shape (m,)
        ``load`` (N·m)², ``motor`` and ``valve`` (L/min)². The valve relation takes the valve-side
        fault whose box lets it explain the window best (one valve-side fault at a time).
    cache : dict, optional
        Valve residuals already computed for a (fault, low, high), shared between calls on the
        same windows (health states share their tolerance boxes).
    own : str, optional
        A state's own valve-side fault: then also ``valve_others``, the valve relation explained by the *other*
        valve-side faults in their boxes alone, shape (m,): what the relation would read if ``own`` were held where
        it explains nothing, so that a pool holding ``own`` at a common severity costs a window no more than that
        (:mod:`hydrowatch.condition.evidence`).
    """
    cache = {} if cache is None else cache
    out: dict[str, np.ndarray] = {}
    for relation, fault in (("load", "load"), ("motor", "motor_leak")):
        s = est.severity[fault]
        out[relation] = est.mse[relation] + est.curvature[fault] * (np.clip(s, *box[fault]) - s) ** 2
    best = np.full(sig.flow.shape[0], np.inf)
    others = best.copy()
    for fault in parity.VALVE_HYPOTHESES:
        key = _box_key(fault, box[fault])
        if key not in cache:
            s = est.severity[fault]
            held = np.clip(s, *box[fault])
            mse = est.mse[fault].copy()
            moved = held != s
            if fault in parity.LINEAR_HYPOTHESES:  # exact where the free fit is the unconstrained minimum
                inside = moved & (s > parity.SEVERITY_LIMITS[fault][0]) & (s < parity.SEVERITY_LIMITS[fault][1])
                mse[inside] += est.curvature[fault][inside] * (held[inside] - s[inside]) ** 2
                moved &= ~inside
            if np.any(moved):
                noise = None if sig.pl_noise is None else sig.pl_noise[moved]
                mse[moved] = parity.valve_mse(sig.flow[moved], sig.spool[moved], sig.load_pressure[moved], p, fault,
                                              held[moved], sig.leak[moved], pl_noise=noise)
            cache[key] = mse
        best = np.minimum(best, cache[key])
        if fault != own:
            others = np.minimum(others, cache[key])
    out["valve"] = best
    if own in parity.VALVE_HYPOTHESES:
        out["valve_others"] = others
    return out


def _box_key(fault: str, bounds: tuple[float, float] | tuple[np.ndarray, np.ndarray]) -> tuple[object, ...]:
    """Cache key of a fault's (low, high): the floats, or the bytes of per-window bounds."""
    return (fault, *(b.tobytes() if isinstance(b, np.ndarray) else float(b) for b in bounds))
