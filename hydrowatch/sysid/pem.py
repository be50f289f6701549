"""Prediction-error estimation of a Box-Jenkins model (study Eqs. 3.8-3.13), pure functions.

Model (Eq. 3.1), with a dead time of K samples::

    y(t) = q^-K B(q)/F(q) u(t) + C(q)/D(q) e(t)
    B(q) = b1 q^-1 + ... + b_nb q^-nb,   F, C, D monic.

Parameter vector (Eq. 3.8): theta = [b1..b_nb, f1..f_nf, c1..c_nc, d1..d_nd].
Prediction error (Eqs. 3.26, 3.27): eps(t) = D/C (y(t) - w(t)), w = q^-K B/F u.

Exact derivatives of eps (the regressors filtered, no finite differences)::

    d eps / d b_k = -q^-(K+k) D/(C F) u          d eps / d f_k = +q^-k D/(C F) w
    d eps / d c_k = -q^-k eps / C                d eps / d d_k = +q^-k v / C,  v = y - w

so the Jacobian (Eq. 3.13) costs four filters and some shifts per iteration.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from hydrowatch.log import event, get_logger
from hydrowatch.sysid.polynomials import (
    delayed_numerator,
    filter_signal,
    is_stable,
    monic,
    reflect_into_unit_circle,
)

__all__ = [
    "STUDY_MODEL_3_24",
    "Orders",
    "PEMResult",
    "filtered_white_noise",
    "fit_prediction_error",
    "initial_estimate",
    "jacobian",
    "prediction_errors",
    "simulate_box_jenkins",
]

STUDY_MODEL_3_24: dict[str, Any] = {
    "b": [1.6051, 0.6470, -0.4455, 1.0721],
    "f": [-1.6347, -0.1301, 1.3594, -0.5819],
    "c": [-1.2158, 0.8683, -0.4533, 0.2314],
    "d": [-1.3915, 1.0989, -0.8340, 0.4274, -0.1449],
    "delay": 4,
}
"""The study's final model of gearbox speed, range 1 (Eq. 3.24, Table 3.11), a known test model."""

_log = get_logger(__name__)


@dataclass(frozen=True)
class Orders:
    """Orders (nb, nf, nc, nd) and dead time K [samples] of a Box-Jenkins model (Eq. 3.1)."""

    nb: int
    nf: int
    nc: int
    nd: int
    delay: int

    @property
    def n_parameters(self) -> int:
        return self.nb + self.nf + self.nc + self.nd

    def split(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(b, f, c, d) from theta (Eq. 3.8)."""
        i1, i2, i3 = self.nb, self.nb + self.nf, self.nb + self.nf + self.nc
        return theta[:i1], theta[i1:i2], theta[i2:i3], theta[i3:]


@dataclass
class PEMResult:
    """Outcome of :func:`fit_prediction_error` (normalised units)."""

    theta: np.ndarray
    errors: np.ndarray
    jacobian: np.ndarray
    n_iter: int
    converged: bool


def filtered_white_noise(n: int, rng: np.random.Generator) -> np.ndarray:
    """Test input of Eq. 3.21: white noise through 0.9 / (1 + 0.9 q^-1); shape (n,), unit-variance noise."""
    return filter_signal([0.9], [1.0, 0.9], rng.standard_normal(n))


def simulate_box_jenkins(
    b: ArrayLike, f: ArrayLike, c: ArrayLike, d: ArrayLike, delay: int, u: ArrayLike, e: ArrayLike
) -> np.ndarray:
    """y = q^-K B/F u + C/D e (Eq. 3.1) from rest; u, e and y shape (N,)."""
    w = filter_signal(delayed_numerator(b, delay), monic(f), u)
    return np.asarray(w + filter_signal(monic(c), monic(d), np.asarray(e, dtype=float)))


def _shift(x: np.ndarray, k: int) -> np.ndarray:
    """q^-k x: x delayed by k samples, zeros in front."""
    if k == 0:
        return x
    out = np.zeros_like(x)
    out[k:] = x[:-k]
    return out


def prediction_errors(
    theta: np.ndarray, u: np.ndarray, y: np.ndarray, orders: Orders
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-step prediction errors eps = D/C (y - q^-K B/F u) (Eqs. 3.26, 3.27), from rest.

    Returns
    -------
    eps, w, v : ndarray, shape (N,)
        Prediction errors, noise-free output w = q^-K B/F u and disturbance v = y - w.
    """
    b, f, c, d = orders.split(theta)
    w = filter_signal(delayed_numerator(b, orders.delay), monic(f), u)
    v = y - w
    eps = filter_signal(monic(d), monic(c), v)
    return eps, w, v


def jacobian(
    theta: np.ndarray, u: np.ndarray, orders: Orders, eps: np.ndarray, w: np.ndarray, v: np.ndarray
) -> np.ndarray:
    """Exact Jacobian d eps(t) / d theta (Eq. 3.13) by filtering the regressors; shape (N, n_parameters)."""
    b, f, c, d = orders.split(theta)
    cf = np.convolve(monic(c), monic(f))
    u_f = filter_signal(monic(d), cf, u)
    w_f = filter_signal(monic(d), cf, w)
    eps_c = filter_signal([1.0], monic(c), eps)
    v_c = filter_signal([1.0], monic(c), v)
    columns = [-_shift(u_f, orders.delay + k) for k in range(1, orders.nb + 1)]
    columns += [_shift(w_f, k) for k in range(1, orders.nf + 1)]
    columns += [-_shift(eps_c, k) for k in range(1, orders.nc + 1)]
    columns += [_shift(v_c, k) for k in range(1, orders.nd + 1)]
    return np.column_stack(columns) if columns else np.zeros((u.size, 0))


def _lagged(x: np.ndarray, lags: range) -> np.ndarray:
    return np.column_stack([_shift(x, k) for k in lags]) if len(lags) else np.zeros((x.size, 0))


def _solve(a: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Least-squares solution of a x = rhs by the (small) normal equations; pseudo-inverse if singular."""
    return np.asarray(np.linalg.lstsq(a.T @ a, a.T @ rhs, rcond=1e-12)[0])


def _dynamics_estimate(u: np.ndarray, y: np.ndarray, orders: Orders) -> tuple[np.ndarray, np.ndarray]:
    """B and F by least squares (ARX) refined by three instrumental-variable passes.

    The instruments are past noise-free outputs simulated with the previous B/F, which makes the
    estimate consistent whatever the disturbance's colour.
    """
    nb, nf, k = orders.nb, orders.nf, orders.delay
    u_reg = _lagged(u, range(k + 1, k + nb + 1))
    if nf == 0:
        return _solve(u_reg, y), np.zeros(0)
    phi = np.column_stack([-_lagged(y, range(1, nf + 1)), u_reg])
    theta = _solve(phi, y)
    for _ in range(3):
        b, f = theta[nf:], reflect_into_unit_circle(theta[:nf])
        x = filter_signal(delayed_numerator(b, k), monic(f), u)
        zeta = np.column_stack([-_lagged(x, range(1, nf + 1)), u_reg])
        theta = np.linalg.lstsq(zeta.T @ phi, zeta.T @ y, rcond=1e-12)[0]
    return theta[nf:], reflect_into_unit_circle(theta[:nf])


def _noise_estimate(v: np.ndarray, nc: int, nd: int) -> tuple[np.ndarray, np.ndarray]:
    """C and D of the disturbance v = C/D e by the Hannan-Rissanen two-stage least squares."""
    if nc == 0 and nd == 0:
        return np.zeros(0), np.zeros(0)
    n = v.size
    long_order = int(min(max(20, 3 * (nc + nd)), max(nc + nd + 1, n // 20)))
    a = _solve(_lagged(v, range(1, long_order + 1)), v)
    e = v - _lagged(v, range(1, long_order + 1)) @ a
    phi = np.column_stack([-_lagged(v, range(1, nd + 1)), _lagged(e, range(1, nc + 1))])
    start = long_order + max(nc, nd)
    theta = _solve(phi[start:], v[start:])
    d, c = theta[:nd], theta[nd:]
    return reflect_into_unit_circle(c), reflect_into_unit_circle(d)


def initial_estimate(u: np.ndarray, y: np.ndarray, orders: Orders) -> np.ndarray:
    """Starting point for the Levenberg-Marquardt iterations (normalised data); shape (n_parameters,).

    B, F by instrumental variables; C, D by Hannan-Rissanen on the disturbance y - q^-K B/F u.
    F, C and D are reflected into the unit circle so the predictor starts stable.
    """
    b, f = _dynamics_estimate(u, y, orders)
    v = y - filter_signal(delayed_numerator(b, orders.delay), monic(f), u)
    c, d = _noise_estimate(v, orders.nc, orders.nd)
    return np.concatenate([b, f, c, d])


def _admissible(theta: np.ndarray, orders: Orders) -> bool:
    """F stable (G is a stable system) and C minimum-phase (the predictor D/C is stable)."""
    _, f, c, _ = orders.split(theta)
    return is_stable(f) and is_stable(c)


def fit_prediction_error(
    u: np.ndarray, y: np.ndarray, orders: Orders, theta0: np.ndarray, max_iter: int = 100, tol: float = 1e-8
) -> PEMResult:
    """Minimise sum eps(t, theta)^2 (Eq. 3.9) by Levenberg-Marquardt (Eq. 3.12) with exact Jacobian.

    Step: theta <- theta - (J^T J + mu I)^-1 J^T eps, with J = d eps/d theta (the study writes
    J for -d eps/d theta, hence its + sign). mu shrinks by 10 after a step that lowers the cost
    and keeps F stable and C minimum-phase, and grows by 10 otherwise.

    Parameters
    ----------
    u, y : ndarray, shape (N,)
        Normalised input and output (Eqs. 3.19, 3.20).
    orders : Orders
    theta0 : ndarray, shape (n_parameters,)
    max_iter : int
        Largest number of accepted or rejected steps.
    tol : float
        Stop when an accepted step lowers the cost by less than ``tol`` relative.
    """
    theta = np.asarray(theta0, dtype=float).copy()
    eps, w, v = prediction_errors(theta, u, y, orders)
    cost = float(eps @ eps)
    jac = jacobian(theta, u, orders, eps, w, v)
    if orders.n_parameters == 0:
        return PEMResult(theta, eps, jac, 0, True)
    hessian, gradient = jac.T @ jac, jac.T @ eps
    mu = 1e-4 * float(np.max(np.diag(hessian)))
    converged = False
    n_iter = 0
    for n_iter in range(1, max_iter + 1):  # noqa: B007 - n_iter is reported
        try:
            step = np.linalg.solve(hessian + mu * np.eye(theta.size), -gradient)
        except np.linalg.LinAlgError:
            mu *= 10.0
            continue
        candidate = theta + step
        if _admissible(candidate, orders):
            eps_c, w_c, v_c = prediction_errors(candidate, u, y, orders)
            cost_c = float(eps_c @ eps_c)
        else:
            cost_c = np.inf
        if cost_c < cost:
            improvement = (cost - cost_c) / max(cost, np.finfo(float).tiny)
            theta, eps, w, v, cost = candidate, eps_c, w_c, v_c, cost_c
            jac = jacobian(theta, u, orders, eps, w, v)
            hessian, gradient = jac.T @ jac, jac.T @ eps
            mu = max(mu / 10.0, 1e-12 * float(np.max(np.diag(hessian))))
            if improvement < tol:
                converged = True
                break
        else:
            mu *= 10.0
            if mu > 1e12 * max(float(np.max(np.diag(hessian))), 1.0):
                converged = True  # no descent direction left: a (local) minimum
                break
    event(_log, "prediction-error fit", orders=orders, n_iter=n_iter, converged=converged, cost=cost)
    return PEMResult(theta, eps, jac, n_iter, converged)
