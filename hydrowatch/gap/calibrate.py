"""Grey-box output-error estimation: bounded least squares on the simulation error.

The cost is the sum over the three sensors of the squared simulation error divided by each
sensor's standard deviation, on the fitting blocks (gap-method.md, step 1; Ljung 1999, ch. 7 and
Bohlin 2006 on grey-box estimation). Plant parameters are estimated as log-scale factors of their
starting value; effect parameters as multiples of their catalog default. The Jacobian is a forward
finite difference computed by ONE batched simulator call over the perturbed models.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.optimize import OptimizeResult, least_squares

from hydrowatch.gap.align import AlignedRecording, simulate_sensors, simulation_threads
from hydrowatch.gap.locate import noise_std
from hydrowatch.gap.space import CALIBRATED, PRIOR_SD, ModelSpace
from hydrowatch.log import event, get_logger
from hydrowatch.plant.effects import EFFECTS
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SAMPLE_RATE_HZ

log = get_logger(__name__)

STATIC: tuple[str, ...] = ("Kq", "TL", "BL", "Ctm", "Cp", "Pc", "Dp", "Dm")
"""Parameters that set the slow (below a few Hz) response; fitted first on low-passed errors."""

SLOW_BAND_HZ = 2.0
"""Corner of the zero-phase low-pass applied to the errors in the first calibration stage, Hz."""

_STEP = 1e-3
"""Forward-difference step of the Jacobian in the scaled coordinates (0.1 % of the value, or of the catalog default).

Issue 12, item 5 (docs/gap.md, "Fifteenth change"): with 1e-2 the Jacobian's truncation error steered the solver
along a curved valley in small steps: continuing seed 2063 unit 16's accepted backlash + air model for 8 iterations
lowered its cost 9.82 → 8.36 with 1e-2, → 4.11 with 1e-3, → 3.04 with 3e-4, → 4.34 with 1e-4 and → 6.94 with 1e-5
(there the kinks' bisection shows as noise in the differences); 3 settles of 30 iterations each with 1e-2 reached 3.14.
1e-3 keeps a factor 10 from the noisy end."""

STALL_ITERATIONS = 3
STALL_DROP = 1e-3
"""A fit stops once its cost has fallen by less than STALL_DROP (relative) over the last STALL_ITERATIONS
solver iterations (issue 12, item 5): each iteration costs one batched simulation of every coordinate's
finite difference (20 simulations of 120 s for a unit with one effect), and the solver's own tolerances
(ftol, xtol) rarely end a fit on a noisy 120 s record, so fits ran to their iteration limit while the cost
no longer moved (gear backlash on population 2035: a confirmation's last iterations and its 20-iteration
polish changed the cost by 3·10⁻⁴ of it, for 220 simulations)."""


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
    covariance : ndarray, shape (P, P)
        That covariance of the scaled coordinates (with the prior's information when the space has one).
    prediction : ndarray, shape (3, n)
        Simulated sensors of the estimated model.
    fit_cost : float
        Mean over fitting samples of the summed squared normalised errors of the three sensors.
    n_fit : int
        Number of fitting samples per sensor.
    converged : bool
        Whether the solver stopped on its tolerances or on the stall rule (STALL_DROP), not on its
        iteration limit.
    """

    space: ModelSpace
    z: np.ndarray
    parameters: PlantParameters
    effects: dict[str, dict[str, float]]
    values: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    covariance: np.ndarray
    prediction: np.ndarray
    fit_cost: float
    n_fit: int
    converged: bool = False


class _Objective:
    """Normalised residuals and their batched finite-difference Jacobian, sharing simulations.

    The solver asks for the residuals at one point at a time (its start, then each trial step) and for the Jacobian
    at each point it accepts, whose P perturbed models share the :func:`simulation_threads` threads. A single model
    leaves all threads but one idle, so the residuals' simulation takes some of the Jacobian's along (issue 12, item
    5): at the start all of them (the solver always asks for the start's Jacobian next), at a trial step the P mod
    threads perturbations that the Jacobian's batch would otherwise leave one thread alone to run (used when the
    step is accepted; simulated for nothing when it is rejected). Every number is the same; the Jacobian takes
    them from the fit's cache.
    """

    def __init__(self, aligned: AlignedRecording, space: ModelSpace, band_hz: float | None = None) -> None:
        self.aligned, self.space = aligned, space
        self.sos = None if band_hz is None else signal.butter(2, band_hz, fs=SAMPLE_RATE_HZ, output="sos")
        self.cache: dict[bytes, np.ndarray] = {}
        self.n_sim = 0
        self.calls = 0

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
                # Bounded: forget older points, not this call's (the solver's point, found here, is simulated
                # again otherwise when the fit ends on it).
                self.cache.clear()
                self.cache.update(found)
            for z, p in zip(todo, preds):
                self.cache[z.tobytes()] = found[z.tobytes()] = p
        return [found[z.tobytes()] for z in points]

    def fun(self, z: np.ndarray) -> np.ndarray:
        z = np.array(z, dtype=float)
        points, _ = self._perturbed(z)
        along = len(points) - 1 if self.calls == 0 else (len(points) - 1) % simulation_threads()
        self.calls += 1
        return np.concatenate([self._residuals(self.simulate(points[: 1 + along])[0]), self.space.prior_residuals(z)])

    def _perturbed(self, z: np.ndarray) -> tuple[list[np.ndarray], list[float]]:
        """``z`` and its P forward-difference points (a step back where the upper bound is near), and the steps."""
        lo, hi = self.space.bounds()
        steps = []
        points = [z]
        for i in range(z.size):
            h = _STEP if z[i] + _STEP <= hi[i] else -_STEP
            zi = z.copy()
            zi[i] += h
            steps.append(h)
            points.append(zi)
        return points, steps

    def jac(self, z: np.ndarray) -> np.ndarray:
        z = np.array(z, dtype=float)
        points, steps = self._perturbed(z)
        preds = self.simulate(points)
        r0 = np.concatenate([self._residuals(preds[0]), self.space.prior_residuals(z)])
        return np.column_stack([(np.concatenate([self._residuals(p), self.space.prior_residuals(zi)]) - r0) / h
                                for p, h, zi in zip(preds[1:], steps, points[1:])])


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
    band_hz: float | None = None, stall: bool = True,
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
    stall : bool, default True
        Stop once the cost stops falling (STALL_DROP over STALL_ITERATIONS iterations); False: only
        on the solver's tolerances or ``max_nfev`` (the calibration without effects, :func:`calibrate`).

    Returns
    -------
    OutputErrorFit
    """
    objective = _Objective(aligned, space, band_hz)
    lo, hi = space.bounds()
    start = np.clip(space.start() if z0 is None else np.asarray(z0, dtype=float), lo + 1e-9, hi - 1e-9)
    trace: list[float] = []

    def iteration(intermediate_result: OptimizeResult) -> None:
        trace.append(2.0 * float(intermediate_result.cost))
        if not stall or len(trace) <= STALL_ITERATIONS:
            return
        if trace[-1 - STALL_ITERATIONS] - trace[-1] < STALL_DROP * trace[-1]:
            raise StopIteration

    converged = True
    if start.size:
        sol = least_squares(objective.fun, start, jac=objective.jac, bounds=(lo, hi), method="trf",
                            x_scale="jac", max_nfev=max_nfev, xtol=1e-4, ftol=1e-5, callback=iteration)
        z, r, jac = sol.x, sol.fun, sol.jac
        converged = sol.status != 0
    else:
        z = start
        r = objective.fun(z)
        jac = np.zeros((r.size, 0))
    prediction = objective.simulate([z])[0]
    params, effects = space.model(z)
    values = space.values(z)
    n_prior = space.prior_residuals(z).size
    data_r = r[: r.size - n_prior]
    cov = _covariance(space, z, data_r, jac[: r.size - n_prior], aligned.measured.shape[0])
    ci95 = intervals(space, z, cov)
    event(log, "output-error fit", parameters=len(z), simulations=objective.n_sim, cost=float(np.mean(data_r**2)),
          iterations=len(trace), converged=converged)
    event(log, "output-error trace", level=logging.DEBUG, iterations=len(trace),
          trace=",".join(f"{v:.6g}" for v in trace))
    n_fit = int(aligned.fit_mask.sum())
    return OutputErrorFit(space, z, params, effects, values, ci95, cov, prediction,
                          float(np.sum(data_r**2) / n_fit), n_fit, converged)


def _covariance(space: ModelSpace, z: np.ndarray, data_r: np.ndarray, jac: np.ndarray, n_sensors: int
                ) -> np.ndarray:
    """Covariance of the coordinates: the inverse of the data's information JᵀJ/s² (J of the data rows,
    s² their residual variance inflated by n/n_eff) plus the prior's, 1/PRIOR_SD² on each plant
    coordinate when the space has a prior (whatever weight the fit gave the prior's rows)."""
    if z.size == 0:
        return np.zeros((0, 0))
    dof = max(data_r.size - z.size, 1)
    s2 = float(np.dot(data_r, data_r)) / dof / _effective_fraction(data_r, n_sensors)
    information = jac.T @ jac / s2
    if space.prior is not None:
        k = len(space.plant_free)
        information[np.arange(k), np.arange(k)] += 1.0 / PRIOR_SD**2
    return np.linalg.pinv(information)


def intervals(space: ModelSpace, z: np.ndarray, cov: np.ndarray) -> dict[str, tuple[float, float]]:
    """95 % intervals from the coordinates' covariance, mapped through each coordinate's transform."""
    if z.size == 0:
        return {}
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
              effects: Mapping[str, Mapping[str, float]] | None = None, max_nfev: int = 15,
              prior: bool = True, effect_free: tuple[tuple[str, str], ...] = (),
              pump: float | None = None, stall: bool = False) -> OutputErrorFit:
    """Refit the nominal model's plant parameters (no effect blamed yet), in two stages.

    Stage 1 fits the STATIC parameters among ``free`` to errors low-passed at SLOW_BAND_HZ (the
    cost is then smooth in the dynamic parameters' absence); stage 2 fits all of ``free`` to the
    full-band errors from there, for ``2 · max_nfev`` iterations at most (the 18 coordinates of a
    unit need more than the old 9). With ``prior`` every free parameter carries the design-value
    prior of :data:`PRIOR_SD` centred on ``nominal`` (MAP estimation), which holds the directions
    the recording does not determine; the returned fit's covariance then says which it determines
    (identify.py). ``effect_free``: effect parameters estimated with the plant in stage 2 (the
    calibration under the hypothesis that those effects are present; stage 1 holds them at their
    values in ``effects``). ``pump``: the pump displacement Dp to start from, m³/rad, when an earlier
    calibration of the same recording found it (the calibration under a hypothesis, diagnose.py):
    it replaces the PUMP_SCAN scan and the PUMP_RESTART restart, which only put a fit on the side
    of Dp where the pump limits (issue 12, item 5: the restart doubled a hypothesis's cost). See
    :func:`fit_output_error`. ``stall``: whether its fits stop once the cost stops falling (off by default:
    the calibration every later step starts from runs to its tolerances or iteration limits as before issue
    12's fourth pass; on population 2035's backlash + air pair the stall rule ended it after 12 of 30
    iterations at a 0.07 % higher held-out cost, and the greedy diagnosis then took another path and missed
    the air).
    """
    fixed = {k: dict(v) for k, v in (effects or {}).items()}
    design = nominal if prior else None
    start, prediction = static_stage(aligned, nominal, free=free, effects=fixed, max_nfev=max_nfev, pump=pump,
                                     stall=stall)
    weight = prior_weight(aligned, prediction) if prior else 0.0
    fit = fit_output_error(aligned, ModelSpace(start, fixed, free, effect_free, design, weight), max_nfev=2 * max_nfev,
                           stall=stall)
    k = fit.space.names.index("Dp") if "Dp" in free else -1
    if k < 0 or pump is not None or math.sqrt(fit.covariance[k, k]) < PRIOR_SD / 2:
        return fit
    # The model's pump never limits (Dp not determined at the fit): it may sit on the flat side of a
    # unit whose pump does. Start again with a pump that limits, keep the better fit.
    smaller = fit.parameters.replace(Dp=fit.parameters.Dp * PUMP_RESTART)
    event(log, "pump displacement restart", before=fit.parameters.Dp, start=smaller.Dp)
    again = fit_output_error(aligned, ModelSpace(smaller, fit.effects, free, effect_free, design, weight),
                             max_nfev=2 * max_nfev, stall=stall)
    return again if again.fit_cost < fit.fit_cost else fit


def static_stage(aligned: AlignedRecording, nominal: PlantParameters, *, free: tuple[str, ...] = CALIBRATED,
                 effects: Mapping[str, Mapping[str, float]] | None = None, max_nfev: int = 15,
                 pump: float | None = None, stall: bool = False) -> tuple[PlantParameters, np.ndarray]:
    """Stage 1 of :func:`calibrate`: ``nominal`` with the STATIC parameters among ``free`` fitted to the
    errors low-passed at SLOW_BAND_HZ (``effects`` held as given), starting from the PUMP_SCAN pump
    displacement (or ``pump``, m³/rad); returns the parameters and their prediction, shape (3, n).
    ``stall`` as in :func:`fit_output_error` (off: the prediction also sets a hypothesis's prior weight,
    and a shorter stage 1 changed which rules a round-1 backlash confirmation met on population 2035)."""
    fixed = {k: dict(v) for k, v in (effects or {}).items()}
    # Stage 1 leaves out the second of two parameters that act alike (Cvl beside Cp: both leak supply → tank).
    slow = tuple(n for n in free if n in STATIC and not (n == "Cvl" and "Cp" in free))
    if "Dp" in free and pump is None:
        start, prediction = _pump_start(aligned, nominal, fixed)
    else:
        start = nominal if pump is None else nominal.replace(Dp=pump)
        prediction = simulate_sensors(aligned, [start], [fixed])[0]
    if slow:
        stage1 = fit_output_error(aligned, ModelSpace(start, fixed, slow), max_nfev=max_nfev, band_hz=SLOW_BAND_HZ,
                                  stall=stall)
        start, prediction = stage1.parameters, stage1.prediction
    return start, prediction


PUMP_SCAN = tuple(float(v) for v in np.linspace(0.6, 1.4, 9))
"""Pump displacements tried before the fit, × the design value (one batched simulation)."""


PUMP_RESTART = 0.75
"""Factor on the fitted pump displacement from which the fit starts again when it left Dp undetermined."""


def _pump_start(aligned: AlignedRecording, nominal: PlantParameters, effects: dict[str, dict[str, float]],
                band_hz: float | None = SLOW_BAND_HZ) -> tuple[PlantParameters, np.ndarray]:
    """The design values with the pump displacement of PUMP_SCAN that fits the low-passed errors best,
    and its prediction.

    The pump displacement sets the output only where the pump limits the flow: a model whose pump is
    larger than the unit's never limits, its cost is flat in Dp there and a local fit stays put (a
    unit 20 % smaller than its design stayed at +15 %). The scan starts the fit on the right side.
    """
    starts = [nominal.replace(Dp=nominal.Dp * k) for k in PUMP_SCAN]
    preds = simulate_sensors(aligned, starts, [effects] * len(starts))
    objective = _Objective(aligned, ModelSpace(nominal, effects, ()), band_hz)
    costs = [float(np.sum(objective._residuals(p) ** 2)) for p in preds]
    best = int(np.argmin(costs))
    return starts[best], preds[best]


def prior_weight(aligned: AlignedRecording, prediction: np.ndarray) -> float:
    """RMS over the sensors of the noise ceiling (noise std / signal std) of a model's residual,
    read from its 70–100 Hz band; an upper bound while the model is still off (plant response
    left in the band), which makes the prior stronger than PRIOR_SD during the fit, never weaker."""
    used = aligned.used_mask
    ceilings = [noise_std(aligned.measured[i, used] - prediction[i, used]) / float(aligned.scale[i])
                for i in range(aligned.measured.shape[0])]
    return float(np.sqrt(np.mean(np.square(ceilings))))
