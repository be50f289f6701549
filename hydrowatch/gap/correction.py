"""A data-driven correction for physics the catalog does not hold: sparse regression on the residual.

The residual of one sensor ``e = y − ŷ`` is regressed on a library Θ of candidate terms built from
the command and the *simulated* (noise-free) operating point, ``e ≈ Θ·ξ`` with few non-zero ξ
(sequentially thresholded least squares, the SINDy-with-control regression of Brunton, Proctor &
Kutz 2016). The terms chosen say what the missing physics depends on; the corrected prediction is
``ŷ + Θ·ξ``. The same fit is a second opinion on a catalog effect (gap-method.md, step 4).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hydrowatch.errors import NotFittedError, ParameterError
from hydrowatch.recording import SAMPLE_RATE_HZ

LOW_SPEED_RAD_S = 1.0
"""Speed scale of the low-speed (breakaway) term exp(−(ω/ω0)²), gearbox side, rad/s."""


DELAY_SAMPLES = 4
"""Delay of the ``u(t−20 ms)`` term, samples at 200 Hz."""

RATE_SCALE_FRACTION = 0.1
"""The ``sign(du/dt)`` term is tanh(u̇ / s) with s = this fraction of the record's std of u̇."""


@dataclass(frozen=True)
class Library:
    """Candidate terms evaluated on a trajectory.

    Attributes
    ----------
    names : tuple of str
        One name per column, e.g. ``"ω·|ω|"``.
    theta : ndarray, shape (n, K)
        Term values.
    settings : dict of str to float
        What fixes the terms besides the trajectory: ``pump_speed`` (rad/s) and ``rate_scale``
        (V/s, the smoothing of sign(du/dt)). Rebuilding the library on another trajectory with the
        same settings gives the same functions (the saved model stores them; discrepancy.py).
    """

    names: tuple[str, ...]
    theta: np.ndarray
    settings: dict[str, float] = field(default_factory=dict)

    def column(self, name: str) -> np.ndarray:
        """The values of one term, shape (n,)."""
        return self.theta[:, self.names.index(name)]


def build_library(
    voltage: np.ndarray, simulated: np.ndarray, t: np.ndarray, *, pump_speed: float, fs: float = SAMPLE_RATE_HZ,
    rate_scale: float | None = None,
) -> Library:
    """The regressor library of gap-method.md, step 3.

    Parameters
    ----------
    voltage : ndarray, shape (n,)
        Command, V.
    simulated : ndarray, shape (3, n)
        Simulated flow [L/min], speed [rad/s], torque [N·m].
    t : ndarray, shape (n,)
        Sample times, s (terms use the time since the first sample).
    pump_speed : float
        Pump shaft speed ωp, rad/s (ripple lines).
    rate_scale : float, optional
        Smoothing of sign(du/dt), V/s (default: RATE_SCALE_FRACTION × the std of u̇ on this record).
    """
    flow, speed, torque = simulated
    du = np.gradient(voltage) * fs
    if rate_scale is None:
        rate_scale = RATE_SCALE_FRACTION * float(np.std(du)) + 1e-12
    delayed = np.concatenate([np.full(DELAY_SAMPLES, voltage[0]), voltage[:-DELAY_SAMPLES]])
    tt = t - t[0]
    phase = pump_speed * tt
    terms = {
        "1": np.ones_like(voltage),
        "u": voltage,
        "u(t−20 ms)": delayed,
        "du/dt": du,
        "sign(du/dt)": np.tanh(du / rate_scale),
        "max(0.5 V − u, 0)": np.maximum(0.5 - voltage, 0.0),
        "max(u − 3 V, 0)": np.maximum(voltage - 3.0, 0.0),
        "ω": speed,
        "ω·|ω|": speed * np.abs(speed),
        "exp(−(ω/ω0)²)": np.exp(-((speed / LOW_SPEED_RAD_S) ** 2)),
        "dω/dt": np.gradient(speed) * fs,
        "T": torque,
        "dT/dt": np.gradient(torque) * fs,
        "Q": flow,
        "dQ/dt": np.gradient(flow) * fs,
        "t": tt,
        "t·T": tt * torque,
        "sin(ωp·t)": np.sin(phase),
        "cos(ωp·t)": np.cos(phase),
        "sin(2ωp·t)": np.sin(2 * phase),
        "cos(2ωp·t)": np.cos(2 * phase),
    }
    return Library(tuple(terms), np.column_stack(list(terms.values())),
                   {"pump_speed": float(pump_speed), "rate_scale": float(rate_scale)})


def stlsq(
    theta: np.ndarray, target: np.ndarray, threshold: float, ridge: float = 1e-6, max_iter: int = 10
) -> np.ndarray:
    """Sequentially thresholded least squares on standardised columns.

    Parameters
    ----------
    theta : ndarray, shape (n, K)
        Library (the first column may be the constant).
    target : ndarray, shape (n,)
        Residual to explain.
    threshold : float
        Terms whose standardised coefficient (in units of the target's std) falls below it are dropped.

    Returns
    -------
    ndarray, shape (K,)
        Coefficients in the library's own units (zeros for dropped terms).
    """
    scale = theta.std(axis=0)
    scale[scale == 0] = np.abs(theta[0, scale == 0]) + 1e-12
    z = theta / scale
    ystd = float(target.std()) or 1.0
    active = np.ones(theta.shape[1], dtype=bool)
    coef = np.zeros(theta.shape[1])
    for _ in range(max_iter):
        za = z[:, active]
        sol = np.linalg.solve(za.T @ za + ridge * len(target) * np.eye(za.shape[1]), za.T @ target)
        coef[:] = 0.0
        coef[active] = sol
        keep = np.abs(coef) / ystd >= threshold
        if np.array_equal(keep, active) or not keep.any():
            active = keep
            break
        active = keep
    coef[~active] = 0.0
    return coef / scale


class SparseCorrection:
    """Sparse additive correction of one sensor's simulation, chosen by held-out error.

    Parameters
    ----------
    thresholds : tuple of float, default (0.02, 0.05, 0.1, 0.2)
        Candidate thresholds of :func:`stlsq`; the one with the lowest held-out error wins.
    ridge : float, default 1e-6
        Ridge regularisation on standardised columns.

    Attributes
    ----------
    coef_ : ndarray, shape (K,)
        Coefficients of the library terms.
    terms_ : dict of str to float
        The non-zero terms and their coefficients.
    holdout_gain_ : float
        Relative drop of the held-out residual RMS, 0…1 (negative when the correction hurts).
    threshold_ : float
        The threshold chosen.
    settings_ : dict of str to float
        The library's settings (``Library.settings``), to rebuild the same terms elsewhere.
    """

    def __init__(self, *, thresholds: tuple[float, ...] = (0.02, 0.05, 0.1, 0.2), ridge: float = 1e-6) -> None:
        self.thresholds = thresholds
        self.ridge = ridge

    def fit(self, library: Library, residual: np.ndarray, fit_mask: np.ndarray, holdout_mask: np.ndarray
            ) -> SparseCorrection:
        """Fit on ``fit_mask`` samples, choose the threshold on ``holdout_mask`` samples; returns self."""
        if not self.thresholds:
            raise ParameterError("thresholds must be a non-empty tuple of floats. Got (). Give e.g. (0.05, 0.1).")
        theta_fit, theta_hold = library.theta[fit_mask], library.theta[holdout_mask]
        base = float(np.sqrt(np.mean(residual[holdout_mask] ** 2)))
        best: tuple[float, np.ndarray, float] | None = None
        for threshold in self.thresholds:
            coef = stlsq(theta_fit, residual[fit_mask], threshold, self.ridge)
            err = float(np.sqrt(np.mean((residual[holdout_mask] - theta_hold @ coef) ** 2)))
            if best is None or err < best[0]:
                best = (err, coef, threshold)
        assert best is not None
        self.coef_ = best[1]
        self.threshold_ = best[2]
        self.settings_ = dict(library.settings)
        self.names_ = library.names
        self.terms_ = {name: float(c) for name, c in zip(library.names, best[1]) if c != 0.0}
        self.holdout_gain_ = 1.0 - best[0] / base if base > 0 else 0.0
        return self

    def predict(self, library: Library) -> np.ndarray:
        """The correction Θ·ξ, shape (n,), sensor unit."""
        if not hasattr(self, "coef_"):
            raise NotFittedError("SparseCorrection must be fitted before predict. Call fit(library, residual, ...).")
        return library.theta @ self.coef_
