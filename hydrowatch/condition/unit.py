"""The unit's own nominal parameters, identified from its healthy windows (training and commissioning).

The parity relations (:mod:`hydrowatch.condition.parity`) hold for one set of parameters. No real
machine has plant-model.md's defaults: displacements, inertias, damping, line volumes, the relief
valve and every leakage differ from unit to unit by percents to tens of percents. Held at the
defaults, a healthy unit looks like a fault to every relation (a motor whose displacement is 10 %
larger leaves a residual ∝ ω that no health state's box explains), and pooled evidence then
reads every window ``unknown`` (issue 11). So every relation is first fitted to the unit's own
healthy windows, and the health states are boxes around *that* unit.

Each relation is fitted in turn, by regularised nonlinear least squares over log-factors
θ_j = ln(p_j / p0_j) of its parameters (:func:`scipy.optimize.least_squares`, trust-region
reflective within ``BOUND``):

    minimise Σ_blocks (e_b / σ)² + Σ_j (θ_j / τ_j)²

where e_b is the relation's block-averaged residual (the same blocks of :data:`parity.BLOCK`
samples the health scores use), σ the residual's noise level measured on the data, and τ_j the
prior spread of parameter j between units (:data:`PRIOR`: 0.3 for build tolerances, 0.7 for
leakages). The prior term only decides the directions the data cannot tell apart (for example
the relief gain when the relief never opens); where the data speak, a window holds hundreds of
blocks and outweighs it.

1. **load** (Eq. 7): T − JL·ω̇ − BL·ω − TL·tanh(ω/ωs); JL, BL, TL, ωs.
2. **motor** (Eqs. 6–8, with P̂L from the shaft balance, which needs Dm): Q − N·Dm·ω −
   (Vt/4βe)·dP̂L/dt − Ctm·P̂L; Dm, Ctm, Vt (βe stays: only Vt/βe enters here).
3. **valve and supply** (Eqs. 1–5): the measured flow against the supply line integrated from the
   command side; Kq, Dp, Cp, Pc, Kr, Vs (βe/Vs), ωv.

What is not identified: N (a known gear ratio), u_max and Kc (only Kq·Kc/u_max enters), η, Jm and
Bm (they scale P̂L together with Dm and Ctm, which absorb them), βe (only Vt/βe and βe/Vs enter),
Cvl (only Cp + Cvl enters), and whatever a missing sensor takes away: without torque there is no
load relation (nor P̂L), without flow no motor or valve relation. Those keep the given nominal.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from hydrowatch.condition import parity
from hydrowatch.condition.estimates import LPM_TO_M3S, check_windows, invalid_reasons
from hydrowatch.errors import DataError
from hydrowatch.log import event, get_logger
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SENSORS

_log = get_logger(__name__)

RELATION_PARAMETERS: dict[str, tuple[str, ...]] = {
    "load": ("JL", "BL", "TL", "omega_s"),
    "motor": ("Dm", "Ctm", "Vt"),
    "valve": ("Kq", "Dp", "Cp", "Pc", "Kr", "Vs", "omega_v"),
}
"""Parameters identified in each relation, in the order they are fitted."""
PRIOR: dict[str, float] = {"Ctm": 0.7, "Cp": 0.7, "BL": 0.7, "Kr": 0.7, "omega_s": 0.7}
"""Prior spread τ (log scale) of a parameter between units; the rest :data:`DEFAULT_PRIOR`."""
DEFAULT_PRIOR = 0.3
BOUND = 1.5
"""Largest |ln(p / p0)| searched (a factor 4.5 either way) ..."""
LEAK_BOUND = 4.0
"""... except for the leakages Ctm and Cp (a factor 55): a worn seal adds a conductance many times a new one's
(a motor_leak warning is ~10× the default Ctm), and commissioning must see it to refuse the recording."""
BOUNDS = {"Ctm": LEAK_BOUND, "Cp": LEAK_BOUND}
MAX_WINDOWS = 60
"""Windows used for the valve relation (evenly spaced among the valid ones): its supply line is integrated per
trial. 60 windows (300 s, a commissioning recording); measured on duty cycles, 40 left the valve gain and relief
more biased by sensor noise (load warning level +64 % instead of +29 % on the worst of 3 units)."""


@dataclass(frozen=True)
class UnitFit:
    """A unit's identified parameters and what the identification changed.

    Attributes
    ----------
    parameters : PlantParameters
        The unit's own nominal parameters (the given nominal where nothing was identified).
    factors : dict of str to float
        Identified parameter / given nominal, per identified parameter.
    rms_before, rms_after : dict of str to float
        Each identified relation's RMS block residual at the given nominal and at the unit's
        parameters (load N·m, motor and valve L/min).
    windows : int
        Healthy windows used.
    covariance : dict of str to (names, ndarray)
        Per identified relation, its parameters and the posterior covariance of their log-factors
        ln(p / p0) (Gauss-Newton, (JᵀJ)⁻¹ of the regularised problem at the solution): what the
        recording leaves undetermined shows as a variance near the prior's τ².
    """

    parameters: PlantParameters
    factors: dict[str, float] = field(default_factory=dict)
    rms_before: dict[str, float] = field(default_factory=dict)
    rms_after: dict[str, float] = field(default_factory=dict)
    windows: int = 0
    covariance: dict[str, tuple[tuple[str, ...], np.ndarray]] = field(default_factory=dict)

    def summary(self) -> dict[str, object]:
        """JSON-able summary: factors and RMS before/after, rounded."""
        return {"windows": self.windows, "factors": {k: round(v, 4) for k, v in self.factors.items()},
                "rms_before": {k: float(f"{v:.4g}") for k, v in self.rms_before.items()},
                "rms_after": {k: float(f"{v:.4g}") for k, v in self.rms_after.items()}}


@dataclass
class _Signals:
    """SI signals of the healthy windows, (m, n) each; leak (m, 1)."""

    voltage: np.ndarray
    flow: np.ndarray
    speed: np.ndarray
    torque: np.ndarray
    leak: np.ndarray


def _noise_level(e: np.ndarray) -> float:
    """Robust scale of block residuals: 1.4826·MAD of their first differences / √2 (the misfit's slow part
    cancels in differences), floored at a tiny positive number."""
    d = np.diff(e, axis=-1).ravel()
    return max(1.4826 * float(np.median(np.abs(d - np.median(d)))) / np.sqrt(2.0), 1e-12)


def _fit(names: Sequence[str], p: PlantParameters, residual: Callable[[PlantParameters], np.ndarray]
         ) -> tuple[PlantParameters, float, float, np.ndarray]:
    """Regularised least squares over log-factors of ``names`` (module docstring): (parameters, RMS before, after,
    posterior covariance of the log-factors, (JᵀJ)⁻¹ at the solution, the prior included)."""
    base = np.array([getattr(p, n) for n in names])
    tau = np.array([PRIOR.get(n, DEFAULT_PRIOR) for n in names])

    def at(theta: np.ndarray) -> PlantParameters:
        return p.replace(**{n: float(v) for n, v in zip(names, base * np.exp(theta))})

    e0 = residual(p)
    sigma = _noise_level(e0)

    def cost(theta: np.ndarray) -> np.ndarray:
        e = residual(at(theta)).ravel()
        return np.concatenate([np.nan_to_num(e / sigma, nan=1e6), theta / tau])

    bound = np.array([BOUNDS.get(n, BOUND) for n in names])
    result = least_squares(cost, np.zeros(len(names)), bounds=(-bound, bound), x_scale=tau, diff_step=1e-4,
                           max_nfev=60 * len(names))
    fitted = at(result.x)
    rms0 = float(np.sqrt(np.mean(e0**2)))
    rms1 = float(np.sqrt(np.mean(residual(fitted) ** 2)))
    covariance = np.linalg.pinv(result.jac.T @ result.jac)
    if not rms1 <= rms0:  # the prior pulled a flat direction: never leave a unit worse explained than nominal
        return p, rms0, rms0, np.diag(tau**2)
    return fitted, rms0, rms1, covariance


def _load_residual(s: _Signals) -> Callable[[PlantParameters], np.ndarray]:
    def residual(p: PlantParameters) -> np.ndarray:
        y = parity.block_means(s.torque - p.BL * s.speed) - p.JL * parity.block_rates(s.speed)
        return y - p.TL * parity.block_means(np.tanh(s.speed / p.omega_s))
    return residual


def _motor_residual(s: _Signals) -> Callable[[PlantParameters], np.ndarray]:
    def residual(p: PlantParameters) -> np.ndarray:
        pl = parity.load_pressure(s.speed, s.torque, p, leak=s.leak)
        y = parity.block_means(s.flow - p.N * p.Dm * s.speed) - p.Vt / (4.0 * p.beta_e) * parity.block_rates(pl)
        return (y - p.Ctm * s.leak * parity.block_means(pl)) * parity.M3S_TO_LPM
    return residual


def _valve_residual(s: _Signals) -> Callable[[PlantParameters], np.ndarray]:
    def residual(p: PlantParameters) -> np.ndarray:
        pl = parity.load_pressure(s.speed, s.torque, p, leak=s.leak)
        spool = parity.spool_position(s.voltage, p)
        return parity.valve_residual(s.flow, spool, pl, p, None, np.zeros(s.flow.shape[0]), s.leak)
    return residual


def identify_unit(windows: np.ndarray, nominal: PlantParameters | None = None, sensors: Sequence[str] = SENSORS,
                  viscosity_coefficient: float = 0.04,
                  parameters: Mapping[str, tuple[str, ...]] = RELATION_PARAMETERS) -> UnitFit:
    """Identify a unit's nominal parameters from raw windows of it running healthy (module docstring).

    Parameters
    ----------
    windows : ndarray, shape (m, n, 4) or (m, n, 5)
        Raw windows (voltage [V], flow [L/min], speed [rad/s], torque [N·m][, oil temperature [°C]])
        of the unit in its healthy state, on any command that moves the motor.
    nominal : PlantParameters, optional
        The design values to start from and regularise towards (default: plant-model.md's table).
    sensors : sequence of str
        The sensors the unit has; relations they cannot test are not identified.
    viscosity_coefficient : float, default 0.04
        k, 1/K, refers the leakages to 40 °C when the windows carry the temperature.
    parameters : mapping of relation to parameter names, default :data:`RELATION_PARAMETERS`
        What to identify in each relation (a relation left out or given no names is not fitted).

    Raises
    ------
    DataError
        With fewer than 2 valid windows.
    """
    p = nominal if nominal is not None else PlantParameters()
    w = np.asarray(windows, dtype=np.float64)
    if w.ndim != 3 or w.shape[2] not in (4, 5):
        raise DataError(f"healthy windows must have shape (m, n, 4 or 5). Got {w.shape}.")
    w = check_windows(w, w.shape[1])
    ok = np.array([r is None for r in invalid_reasons(w, sensors)], dtype=bool)
    if ok.sum() < 2:
        raise DataError(f"identifying a unit needs at least 2 valid healthy windows. Got {int(ok.sum())}.")
    w = w[ok]
    leak = parity.leakage_factor(w[:, :, 4] if w.shape[2] > 4 else None, w.shape[0], viscosity_coefficient)
    s = _Signals(w[:, :, 0], w[:, :, 1] * LPM_TO_M3S, w[:, :, 2], w[:, :, 3], leak)
    have = set(sensors)
    fit = UnitFit(p, windows=int(w.shape[0]))
    plan = [("load", {"speed", "torque"}, _load_residual, s),
            ("motor", {"flow", "speed", "torque"}, _motor_residual, s)]
    pick = np.unique(np.linspace(0, w.shape[0] - 1, min(MAX_WINDOWS, w.shape[0])).round().astype(int))
    few = _Signals(s.voltage[pick], s.flow[pick], s.speed[pick], s.torque[pick], s.leak[pick])
    plan.append(("valve", {"flow", "speed", "torque"}, _valve_residual, few))
    for relation, needs, make, signals in plan:
        if not needs <= have:
            continue
        names = tuple(parameters.get(relation, ()))
        if not names:
            continue
        p, fit.rms_before[relation], fit.rms_after[relation], cov = _fit(names, p, make(signals))
        fit.covariance[relation] = (names, cov)
    base = nominal if nominal is not None else PlantParameters()
    fit.factors.update({n: getattr(p, n) / getattr(base, n) for r in fit.rms_before for n in parameters[r]})
    result = UnitFit(p, fit.factors, fit.rms_before, fit.rms_after, fit.windows, fit.covariance)
    rms = {f"rms_{r}": f"{fit.rms_before[r]:.3g}->{fit.rms_after[r]:.3g}" for r in fit.rms_before}
    event(_log, "unit identified", logging.INFO, windows=result.windows, **rms)
    return result
