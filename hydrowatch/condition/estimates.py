"""Per-window parity estimates from raw windows, and the residual of each relation inside a parameter box.

:func:`window_signals` converts windows of (voltage, flow, speed, torque[, temperature]) into SI
signals (with the oil's leakage factor when the temperature channel is there) and
fills the sensors a sparse configuration lacks from the nominal relations of
:mod:`hydrowatch.condition.parity` (a relation used to fill a channel can then no longer test
anything, so it is dropped). :func:`parity_estimates` fits every relation once per window;
:func:`relation_mse` gives each relation's mean squared residual when the parameters are held
inside a box (a health state's severity band), which is what the health-state scores compare.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hydrowatch.condition import parity
from hydrowatch.errors import DataError
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SENSORS

RELATIONS: tuple[str, ...] = ("load", "motor", "valve")
"""Component relations, in feature order."""
CHANNELS: tuple[str, ...] = ("voltage", *SENSORS)
"""Channel order of a window's last axis (4 channels)."""
TEMPERATURE = "temperature"
"""Optional 5th channel of a window: oil temperature, °C (40 °C assumed when absent)."""
LPM_TO_M3S = 1.0 / parity.M3S_TO_LPM


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


def check_windows(windows: np.ndarray, window: int) -> np.ndarray:
    """Validate raw windows, shape (m, window, 4) in :data:`CHANNELS` order, or 5 with the oil temperature [°C]."""
    w = np.asarray(windows, dtype=np.float64)
    if w.ndim == 2 and w.shape[0] == window and w.shape[1] in (4, 5):
        w = w[None]
    if w.ndim != 3 or w.shape[1] != window or w.shape[2] not in (4, 5):
        raise DataError(
            f"windows must have shape (n_windows, {window}, 4 or 5) with channels {list(CHANNELS)} "
            f"[+ {TEMPERATURE}]. Got {w.shape}. Cut recordings with windows_from_recording."
        )
    return w


def window_signals(windows: np.ndarray, sensors: Sequence[str], p: PlantParameters,
                   viscosity_coefficient: float = 0.0) -> WindowSignals:
    """SI signals of valid windows (m, n, 4 or 5), missing sensors filled from the nominal relations.

    With a 5th (temperature) channel the leakage factor exp(k·(T̄ − 40 °C)), k =
    ``viscosity_coefficient`` [1/K], enters every relation (:mod:`hydrowatch.condition.parity`).

    Filling rules (``p`` nominal): torque from the load relation (Eq. 7) given speed; speed from the
    motor relation (Eq. 6) given flow, or from the load relation inverted given torque only; flow
    from the motor relation given speed. The relations used to fill are not tested.
    """
    have = set(sensors)
    u = windows[:, :, 0]
    flow = windows[:, :, 1] * LPM_TO_M3S
    speed = windows[:, :, 2]
    torque = windows[:, :, 3]
    relations = set(RELATIONS)
    leak = parity.leakage_factor(windows[:, :, 4] if windows.shape[2] > 4 else None, u.shape[0],
                                 viscosity_coefficient)
    if "speed" not in have:
        if "flow" in have:
            pl_guess = (torque if "torque" in have else np.full_like(u, p.TL)) / (p.N * p.eta * p.Dm)
            speed = (flow - p.Ctm * leak * pl_guess) / (p.N * p.Dm)
            relations.discard("motor")
        else:
            speed = np.maximum(torque - p.TL, 0.0) / max(p.BL, 1e-9)
            relations.discard("load")
    if "torque" not in have:
        torque = (p.JL * parity.derivative(speed) + p.BL * speed + p.TL * np.tanh(speed / p.omega_s))
        relations.discard("load")
    pl = parity.load_pressure(speed, torque, p, leak=leak)
    if "flow" not in have:
        flow = p.N * p.Dm * speed + p.Ctm * leak * pl + p.Vt / (4.0 * p.beta_e) * parity.derivative(pl)
        relations.discard("motor")
    return WindowSignals(u, flow, speed, torque, pl, parity.spool_position(u, p),
                         tuple(r for r in RELATIONS if r in relations), leak)


@dataclass(frozen=True)
class ParityEstimates:
    """Unconstrained per-window estimates, each shape (m,).

    Attributes
    ----------
    severity : dict of str to ndarray
        Severity of every fault on its :mod:`hydrowatch.plant.faults` scale (load and motor_leak
        from their own relations, the valve-side faults from one-hypothesis fits of the valve relation).
    mse : dict of str to ndarray
        Minimum mean squared residual: ``load`` (N·m)², ``motor`` and each valve hypothesis (L/min)².
    curvature : dict of str to ndarray
        For the linear relations (load, motor_leak): d(MSE)/d(severity²), so that
        MSE(s) = mse + curvature·(s − ŝ)².
    """

    severity: Mapping[str, np.ndarray]
    mse: Mapping[str, np.ndarray]
    curvature: Mapping[str, np.ndarray]


def parity_estimates(sig: WindowSignals, p: PlantParameters) -> ParityEstimates:
    """Fit every relation once per window (:mod:`hydrowatch.condition.parity`)."""
    severity: dict[str, np.ndarray] = {}
    mse: dict[str, np.ndarray] = {}
    curvature: dict[str, np.ndarray] = {}
    severity["load"], rms, phi = parity.load_relation(sig.speed, sig.torque, p)
    mse["load"] = rms**2
    curvature["load"] = np.mean(phi**2, axis=1)
    severity["motor_leak"], rms, phi = parity.motor_relation(sig.flow, sig.speed, sig.load_pressure, p,
                                                             leak=sig.leak)
    mse["motor"] = rms**2
    curvature["motor_leak"] = np.mean(phi**2, axis=1)
    for fault in parity.VALVE_HYPOTHESES:
        severity[fault], rms = parity.valve_relation(sig.flow, sig.spool, sig.load_pressure, p, fault,
                                                     leak=sig.leak)
        mse[fault] = rms**2
    return ParityEstimates(severity, mse, curvature)


def relation_mse(sig: WindowSignals, est: ParityEstimates, p: PlantParameters,
                 box: Mapping[str, tuple[float, float]],
                 cache: dict[tuple[str, float, float], np.ndarray] | None = None) -> dict[str, np.ndarray]:
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
    """
    cache = {} if cache is None else cache
    out: dict[str, np.ndarray] = {}
    for relation, fault in (("load", "load"), ("motor", "motor_leak")):
        s = est.severity[fault]
        out[relation] = est.mse[relation] + est.curvature[fault] * (np.clip(s, *box[fault]) - s) ** 2
    best = np.full(sig.flow.shape[0], np.inf)
    for fault in parity.VALVE_HYPOTHESES:
        key = (fault, *box[fault])
        if key not in cache:
            s = est.severity[fault]
            held = np.clip(s, *box[fault])
            mse = est.mse[fault].copy()
            moved = held != s
            if np.any(moved):
                r = parity.valve_residual(sig.flow[moved], sig.spool[moved], sig.load_pressure[moved], p, fault,
                                          held[moved], sig.leak[moved])
                mse[moved] = np.mean(r**2, axis=1)
            cache[key] = mse
        best = np.minimum(best, cache[key])
    out["valve"] = best
    return out
