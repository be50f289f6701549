"""Grey-box output-error estimation: bounded least squares on the simulation error.

The cost is the sum over the three sensors of the squared simulation error divided by each
sensor's standard deviation, on the fitting blocks (gap-method.md, step 1; Ljung 1999, ch. 7 and
Bohlin 2006 on grey-box estimation). Plant parameters are estimated as log-scale factors of their
starting value; effect parameters as multiples of their catalog default. The Jacobian is a forward
finite difference computed by ONE batched simulator call over the perturbed models.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy import signal
from scipy.optimize import least_squares

from hydrowatch.gap.align import AlignedRecording, simulate_sensors
from hydrowatch.log import event, get_logger
from hydrowatch.plant.effects import EFFECTS
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SAMPLE_RATE_HZ

log = get_logger(__name__)

CALIBRATED: tuple[str, ...] = ("Kq", "TL", "BL", "JL", "Ctm", "beta_e", "omega_v", "Cp", "Pc")
"""Identifiable plant parameters refitted before any effect is blamed (flow gain, load, leakage,
stiffness, spool bandwidth, pump leakage, relief setting)."""

STATIC: tuple[str, ...] = ("Kq", "TL", "BL", "Ctm", "Cp", "Pc")
"""Parameters that set the slow (below a few Hz) response; fitted first on low-passed errors."""

SLOW_BAND_HZ = 2.0
"""Corner of the zero-phase low-pass applied to the errors in the first calibration stage, Hz."""

SCALE_BOUND = 3.0
"""Plant parameters may move by a factor 1/SCALE_BOUND … SCALE_BOUND from their starting value."""

_STEP = 1e-2
"""Finite-difference step in the scaled coordinates (1 % of the value or of the catalog default)."""


@dataclass(frozen=True)
class ModelSpace:
    """Which numbers of a model (plant parameters + effects) are free, and their scaled coordinates.

    Attributes
    ----------
    base : PlantParameters
        Starting (and fixed) plant parameters.
    effects : dict
        Effects switched on, ``{id: {param: value}}`` (fixed values and starting values).
    plant_free : tuple of str
        Plant parameters to estimate; coordinate = ln(value / base value).
    effect_free : tuple of (str, str)
        ``(effect id, parameter)`` pairs to estimate; coordinate = value / catalog default.
    """

    base: PlantParameters
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    plant_free: tuple[str, ...] = CALIBRATED
    effect_free: tuple[tuple[str, str], ...] = ()

    @property
    def names(self) -> list[str]:
        """Coordinate names: plant names, then ``id.param``."""
        return [*self.plant_free, *(f"{e}.{p}" for e, p in self.effect_free)]

    def start(self) -> np.ndarray:
        """Scaled coordinates of the starting model, shape (P,)."""
        eff = [self.effects[e][p] / EFFECTS[e].parameters[p][0] for e, p in self.effect_free]
        return np.array([0.0] * len(self.plant_free) + eff)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the scaled coordinates, shape (P,) each."""
        lo = [-math.log(SCALE_BOUND)] * len(self.plant_free)
        hi = [math.log(SCALE_BOUND)] * len(self.plant_free)
        for e, p in self.effect_free:
            default, _, _, lower, upper = EFFECTS[e].parameters[p]
            lo.append(lower / default)
            hi.append(upper / default)
        return np.array(lo), np.array(hi)

    def model(self, z: np.ndarray) -> tuple[PlantParameters, dict[str, dict[str, float]]]:
        """Plant parameters and effects at scaled coordinates ``z``."""
        k = len(self.plant_free)
        params = self.base.replace(**{n: getattr(self.base, n) * math.exp(v) for n, v in zip(self.plant_free, z[:k])})
        effects = {e: dict(v) for e, v in self.effects.items()}
        for (e, p), v in zip(self.effect_free, z[k:]):
            default, _, _, lower, upper = EFFECTS[e].parameters[p]
            effects[e][p] = float(min(max(v * default, lower), upper))
        friction = effects.get("stribeck_friction")
        if friction is not None:
            friction["Ts"] = max(friction["Ts"], friction["Tc"])
        return params, effects

    def values(self, z: np.ndarray) -> dict[str, float]:
        """Physical value of every free coordinate, ``{name: value}`` (SI / catalog units)."""
        params, effects = self.model(z)
        out = {n: getattr(params, n) for n in self.plant_free}
        out.update({f"{e}.{p}": effects[e][p] for e, p in self.effect_free})
        return out


@dataclass(frozen=True)
class OutputErrorFit:
    """Result of :func:`fit_output_error`.

    Attributes
    ----------
    space : ModelSpace
    z : ndarray, shape (P,)
        Estimated scaled coordinates.
    parameters : PlantParameters
    effects : dict
    values : dict of str to float
        Estimated physical value of each free coordinate.
    ci95 : dict of str to (float, float)
        95 % confidence interval of each value (Gauss–Newton covariance, inflated for correlated residuals).
    prediction : ndarray, shape (3, n)
        Simulated sensors of the estimated model.
    fit_cost : float
        Mean over fitting samples of the summed squared normalised errors of the three sensors.
    n_fit : int
        Number of fitting samples per sensor.
    """

    space: ModelSpace
    z: np.ndarray
    parameters: PlantParameters
    effects: dict[str, dict[str, float]]
    values: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    prediction: np.ndarray
    fit_cost: float
    n_fit: int


class _Objective:
    """Normalised residuals and their batched finite-difference Jacobian, sharing simulations."""

    def __init__(self, aligned: AlignedRecording, space: ModelSpace, band_hz: float | None = None) -> None:
        self.aligned, self.space = aligned, space
        self.sos = None if band_hz is None else signal.butter(2, band_hz, fs=SAMPLE_RATE_HZ, output="sos")
        self.cache: dict[bytes, np.ndarray] = {}
        self.n_sim = 0

    def _residuals(self, prediction: np.ndarray) -> np.ndarray:
        a = self.aligned
        error = (a.measured - prediction) / a.scale[:, None]
        if self.sos is not None:
            error = signal.sosfiltfilt(self.sos, error, axis=1)
        return error[:, a.fit_mask].ravel()

    def simulate(self, points: list[np.ndarray]) -> list[np.ndarray]:
        found = {z.tobytes(): self.cache[z.tobytes()] for z in points if z.tobytes() in self.cache}
        todo = [z for z in points if z.tobytes() not in found]
        if todo:
            models = [self.space.model(z) for z in todo]
            preds = simulate_sensors(self.aligned, [m[0] for m in models], [m[1] for m in models])
            self.n_sim += len(todo)
            if len(self.cache) > 64:
                self.cache.clear()
            for z, p in zip(todo, preds):
                self.cache[z.tobytes()] = found[z.tobytes()] = p
        return [found[z.tobytes()] for z in points]

    def fun(self, z: np.ndarray) -> np.ndarray:
        return self._residuals(self.simulate([np.array(z, dtype=float)])[0])

    def jac(self, z: np.ndarray) -> np.ndarray:
        z = np.array(z, dtype=float)
        lo, hi = self.space.bounds()
        steps = []
        points = [z]
        for i in range(z.size):
            h = _STEP if z[i] + _STEP <= hi[i] else -_STEP
            zi = z.copy()
            zi[i] += h
            steps.append(h)
            points.append(zi)
        preds = self.simulate(points)
        r0 = self._residuals(preds[0])
        return np.column_stack([(self._residuals(p) - r0) / h for p, h in zip(preds[1:], steps)])


def _effective_fraction(residual: np.ndarray, n_sensors: int) -> float:
    """n_eff / n of an AR(1)-like residual, from its lag-1 autocorrelation per sensor (≤ 1)."""
    fractions = []
    for r in np.split(residual, n_sensors):
        r = r - r.mean()
        denom = float(np.dot(r, r)) or 1.0
        rho = float(np.clip(np.dot(r[1:], r[:-1]) / denom, 0.0, 0.99))
        fractions.append((1.0 - rho) / (1.0 + rho))
    return float(np.mean(fractions))


def fit_output_error(
    aligned: AlignedRecording, space: ModelSpace, z0: np.ndarray | None = None, *, max_nfev: int = 12,
    band_hz: float | None = None,
) -> OutputErrorFit:
    """Estimate the free coordinates of ``space`` by bounded least squares on the simulation error.

    Parameters
    ----------
    aligned : AlignedRecording
    space : ModelSpace
    z0 : ndarray, shape (P,), optional
        Starting coordinates (default: ``space.start()``), clipped into the bounds.
    max_nfev : int, default 12
        Iteration limit of the trust-region reflective solver (each costs one batched simulation).
    band_hz : float, optional
        Fit only the part of the errors below this frequency (zero-phase Butterworth), Hz; the
        reported costs and intervals are then of the filtered errors.

    Returns
    -------
    OutputErrorFit
    """
    objective = _Objective(aligned, space, band_hz)
    lo, hi = space.bounds()
    start = np.clip(space.start() if z0 is None else np.asarray(z0, dtype=float), lo + 1e-9, hi - 1e-9)
    if start.size:
        sol = least_squares(objective.fun, start, jac=objective.jac, bounds=(lo, hi), method="trf",
                            x_scale="jac", max_nfev=max_nfev, xtol=1e-4, ftol=1e-5)
        z, r, jac = sol.x, sol.fun, sol.jac
    else:
        z = start
        r = objective.fun(z)
        jac = np.zeros((r.size, 0))
    prediction = objective.simulate([z])[0]
    params, effects = space.model(z)
    values = space.values(z)
    ci95 = _intervals(space, z, r, jac, aligned.measured.shape[0])
    event(log, "output-error fit", parameters=len(z), simulations=objective.n_sim, cost=float(np.mean(r**2)))
    n_fit = int(aligned.fit_mask.sum())
    return OutputErrorFit(space, z, params, effects, values, ci95, prediction,
                          float(np.sum(r**2) / n_fit), n_fit)


def _intervals(space: ModelSpace, z: np.ndarray, r: np.ndarray, jac: np.ndarray, n_sensors: int
               ) -> dict[str, tuple[float, float]]:
    """95 % intervals from s²·(JᵀJ)⁻¹, s² inflated by n/n_eff; mapped through each coordinate's transform."""
    if z.size == 0:
        return {}
    dof = max(r.size - z.size, 1)
    s2 = float(np.dot(r, r)) / dof / _effective_fraction(r, n_sensors)
    cov = s2 * np.linalg.pinv(jac.T @ jac)
    half = 1.96 * np.sqrt(np.maximum(np.diag(cov), 0.0))
    out: dict[str, tuple[float, float]] = {}
    lo_b, hi_b = space.bounds()
    for i, name in enumerate(space.names):
        lo_z, hi_z = max(z[i] - half[i], lo_b[i]), min(z[i] + half[i], hi_b[i])
        _, a = _value(space, i, lo_z)
        _, b = _value(space, i, hi_z)
        out[name] = (min(a, b), max(a, b))
    return out


def _value(space: ModelSpace, i: int, coordinate: float) -> tuple[str, float]:
    k = len(space.plant_free)
    if i < k:
        name = space.plant_free[i]
        return name, getattr(space.base, name) * math.exp(coordinate)
    e, p = space.effect_free[i - k]
    return f"{e}.{p}", coordinate * EFFECTS[e].parameters[p][0]


def calibrate(aligned: AlignedRecording, nominal: PlantParameters, *, free: tuple[str, ...] = CALIBRATED,
              effects: Mapping[str, Mapping[str, float]] | None = None, max_nfev: int = 15) -> OutputErrorFit:
    """Refit the nominal model's identifiable parameters (no effect blamed yet), in two stages.

    Stage 1 fits the STATIC parameters among ``free`` to errors low-passed at SLOW_BAND_HZ (the
    cost is then smooth in the dynamic parameters' absence); stage 2 fits all of ``free`` to the
    full-band errors from there. See :func:`fit_output_error`.
    """
    fixed = {k: dict(v) for k, v in (effects or {}).items()}
    slow = tuple(n for n in free if n in STATIC)
    start = nominal
    if slow:
        start = fit_output_error(aligned, ModelSpace(nominal, fixed, slow), max_nfev=max_nfev, band_hz=SLOW_BAND_HZ
                                 ).parameters
    stage2 = fit_output_error(aligned, ModelSpace(start, fixed, free), max_nfev=max_nfev)
    # Report coordinates relative to the nominal values (the space's base is the starting model).
    return stage2
