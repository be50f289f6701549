"""Validation of a fitted Box-Jenkins model (study Sec. 3.2.3): Eqs. 3.14-3.18 and pole-zero checks.

- Parameter covariance sigma^2 [J^T J]^-1 and confidence intervals (Eq. 3.14).
- Q statistic: are the residuals white? (H(q) adequate; Eqs. 3.15, 3.17).
- S statistic: are the residuals uncorrelated with the input? (G(q) adequate; Eqs. 3.16, 3.18).
- Pole-zero cancellation in G = B/F and H = C/D, and stability (poles inside the unit circle).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

from hydrowatch.errors import ParameterError
from hydrowatch.sysid.polynomials import cancellations, monic, numerator_zeros, polynomial_roots

__all__ = [
    "confidence_intervals",
    "parameter_covariance",
    "pole_zero_report",
    "prewhiten",
    "q_statistic",
    "s_statistic",
]


def parameter_covariance(jacobian: np.ndarray, errors: np.ndarray) -> tuple[np.ndarray, float]:
    """cov(theta) = sigma^2 [J^T J]^-1 with sigma^2 = eps^T eps / N (Eq. 3.14).

    A singular J^T J (an over-parametrised model: a direction of theta that leaves the errors
    unchanged) gives infinite variances rather than a falsely precise pseudo-inverse.

    Returns
    -------
    covariance : ndarray, shape (p, p)
        In the units of theta squared.
    sigma2 : float
        Residual variance, in the units of the errors squared.
    """
    n, p = jacobian.shape
    sigma2 = float(errors @ errors) / n
    if p == 0:
        return np.zeros((0, 0)), sigma2
    information = jacobian.T @ jacobian
    if np.linalg.cond(information) > 1e13:
        return np.full((p, p), np.inf), sigma2
    return sigma2 * np.linalg.inv(information), sigma2


def confidence_intervals(theta: np.ndarray, covariance: np.ndarray, level: float = 0.95) -> np.ndarray:
    """Symmetric normal intervals theta_i +/- z sqrt(cov_ii) (Eq. 3.14); shape (p, 2)."""
    z = float(stats.norm.ppf(0.5 * (1.0 + level)))
    half = z * np.sqrt(np.clip(np.diag(covariance), 0.0, np.inf))
    return np.column_stack([theta - half, theta + half])


def _lagged_means(x: np.ndarray, y: np.ndarray, lags: int) -> np.ndarray:
    """R_xy(k) = 1/(N-k) sum_{t=1}^{N-k} x(t) y(t+k), k = 0..lags (Eqs. 3.15, 3.16)."""
    n = x.size
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    full = np.fft.irfft(np.conj(np.fft.rfft(x, nfft)) * np.fft.rfft(y, nfft), nfft)[: lags + 1]
    return np.asarray(full / (n - np.arange(lags + 1)))


def _check_lags(lags: int, n: int, n_parameters: int, name: str) -> int:
    dof = lags - n_parameters
    if dof < 1:
        raise ParameterError(
            f"lags must exceed the number of {name} parameters ({n_parameters}). Got {lags}; "
            f"use lags >= {n_parameters + 1}."
        )
    if lags >= n // 2:
        raise ParameterError(f"lags must be below half the number of samples ({n}). Got {lags}; use fewer lags.")
    return dof


def q_statistic(errors: np.ndarray, lags: int, n_noise_parameters: int) -> tuple[float, int, float]:
    """Q = N sum_{k=1}^{K} r_eps(k)^2 ~ chi2(K - nc - nd) if the residuals are white (Eq. 3.17).

    r_eps(k) = R_eps(k) / R_eps(0) with R_eps from Eq. 3.15.

    Parameters
    ----------
    errors : ndarray, shape (N,)
        Residuals (one-step prediction errors).
    lags : int
        K, number of lags summed.
    n_noise_parameters : int
        nc + nd.

    Returns
    -------
    Q, dof, p-value : float, int, float
        A small p-value (< 0.05) says H(q) under-fits: raise nc or nd.
    """
    dof = _check_lags(lags, errors.size, n_noise_parameters, "noise-model")
    r = _lagged_means(errors, errors, lags)
    q = float(errors.size * np.sum((r[1:] / r[0]) ** 2))
    return q, dof, float(stats.chi2.sf(q, dof))


def prewhiten(u: np.ndarray, order: int = 10) -> np.ndarray:
    """The input passed through its own least-squares AR(order) inverse filter: close to white.

    Box, Jenkins & Reinsel's cross-correlation check (Eq. 3.18) is chi-square only when the input
    is white; prewhitening makes it so for a coloured input (e.g. the filtered noise of Eq. 3.21).
    """
    u = u - u.mean()
    n = u.size
    regressors = np.column_stack([np.concatenate([np.zeros(k), u[:-k]]) for k in range(1, order + 1)])
    x = regressors[order:]
    a = np.linalg.lstsq(x.T @ x, x.T @ u[order:], rcond=1e-12)[0]
    return np.asarray(u - regressors @ a)[order:] if n > 2 * order else u


def s_statistic(
    u: np.ndarray, errors: np.ndarray, lags: int, n_dynamics_parameters: int, prewhiten_order: int = 10
) -> tuple[float, int, float]:
    """S = N sum_{k=1}^{K} r_ueps(k)^2 ~ chi2(K - nb - nf) if G(q) is adequate (Eq. 3.18).

    r_ueps(k) = R_ueps(k) / sqrt(var(u) var(eps)) with R_ueps from Eq. 3.16, computed with the
    prewhitened input (:func:`prewhiten`; set ``prewhiten_order=0`` for the raw input as the
    study writes it).

    Returns
    -------
    S, dof, p-value : float, int, float
        A small p-value (< 0.05) says G(q) under-fits: raise nb or nf (or fix the delay).
    """
    dof = _check_lags(lags, errors.size, n_dynamics_parameters, "dynamics")
    if prewhiten_order > 0:
        alpha = prewhiten(u, prewhiten_order)
        eps = errors[errors.size - alpha.size :]
    else:
        alpha, eps = u - u.mean(), errors
    eps = eps - eps.mean()
    r = _lagged_means(alpha, eps, lags)[1:] / np.sqrt(np.var(alpha) * np.var(eps))
    s = float(eps.size * np.sum(r**2))
    return s, dof, float(stats.chi2.sf(s, dof))


def _pairs_as_json(pairs: list[tuple[complex, complex]], which: str) -> list[dict[str, Any]]:
    return [
        {"model": which, "zero": [z.real, z.imag], "pole": [p.real, p.imag], "distance": abs(z - p)} for z, p in pairs
    ]


def pole_zero_report(
    b: np.ndarray, f: np.ndarray, c: np.ndarray, d: np.ndarray, tolerance: float = 0.05
) -> dict[str, Any]:
    """Roots of B, F, C, D; stability; pole-zero cancellations closer than ``tolerance`` (Sec. 3.2.3).

    Returns
    -------
    dict
        ``zeros_B``, ``poles_F``, ``zeros_C``, ``poles_D`` (lists of [re, im]); ``stable`` (poles of
        G and H inside the unit circle); ``invertible`` (zeros of C inside: the predictor of
        Eq. 3.26 is stable); ``cancellations`` (list of {model: "G"|"H", zero, pole, distance}).
    """
    zb, pf = numerator_zeros(b), polynomial_roots(monic(f))
    zc, pd = polynomial_roots(monic(c)), polynomial_roots(monic(d))

    def inside(roots: np.ndarray) -> bool:
        return bool(roots.size == 0 or np.max(np.abs(roots)) < 1.0)

    def listed(roots: np.ndarray) -> list[list[float]]:
        return [[float(r.real), float(r.imag)] for r in roots]

    return {
        "zeros_B": listed(zb),
        "poles_F": listed(pf),
        "zeros_C": listed(zc),
        "poles_D": listed(pd),
        "stable": inside(pf) and inside(pd),
        "invertible": inside(zc),
        "cancellations": _pairs_as_json(cancellations(zb, pf, tolerance), "G")
        + _pairs_as_json(cancellations(zc, pd, tolerance), "H"),
    }
