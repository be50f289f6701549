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
    filter_settling,
    filter_signal,
    is_stable,
    monic,
)

__all__ = [
    "STUDY_MODEL_3_24",
    "Orders",
    "PEMResult",
    "errors_without_start_up",
    "filtered_white_noise",
    "fit_prediction_error",
    "jacobian",
    "prediction_errors",
    "simulate_box_jenkins",
    "start_up_basis",
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
    """Outcome of :func:`fit_prediction_error` (normalised units).

    ``errors`` are the one-step prediction errors with the start-up response removed,
    ``start_up`` that response (zeros when the initial conditions are taken as zero) and
    ``offset`` the output level mu estimated with it (0.0 likewise), ``n_start_up`` the number of
    start-up coefficients fitted (R's and mu; 0 likewise); ``cost`` = errors @ errors.
    """

    theta: np.ndarray
    errors: np.ndarray
    jacobian: np.ndarray
    n_iter: int
    converged: bool
    start_up: np.ndarray
    offset: float = 0.0
    n_start_up: int = 0

    @property
    def cost(self) -> float:
        return float(self.errors @ self.errors)


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
    jac = np.zeros((u.size, orders.n_parameters), order="F")  # columns contiguous: filled a column at a time
    i_f, i_c, i_d = orders.nb, orders.nb + orders.nf, orders.nb + orders.nf + orders.nc
    _add_shifted(jac, 0, -u_f, range(orders.delay + 1, orders.delay + orders.nb + 1))
    _add_shifted(jac, i_f, w_f, range(1, orders.nf + 1))
    _add_shifted(jac, i_c, -eps_c, range(1, orders.nc + 1))
    _add_shifted(jac, i_d, v_c, range(1, orders.nd + 1))
    return jac


def _add_shifted(jac: np.ndarray, first: int, x: np.ndarray, shifts: range) -> None:
    """Adds q^-k x to column ``first + i`` of ``jac`` for the i-th shift k, in place (no copies of x)."""
    n = x.size
    for i, k in enumerate(shifts):
        if k < n:
            jac[k:, first + i] += x[: n - k]


def _admissible(theta: np.ndarray, orders: Orders) -> bool:
    """F stable (G is a stable system) and C minimum-phase (the predictor D/C is stable)."""
    _, f, c, _ = orders.split(theta)
    return is_stable(f) and is_stable(c)


def start_up_basis(theta: np.ndarray, orders: Orders, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Signals that the unknown state at t = 0 and an output offset add to the errors.

    A record that does not start from rest adds to the from-rest errors of Eq. 3.27
    D/(C F) S(q) delta + 1/C S_v(q) delta (S of length max(nf, K + nb), the past inputs through
    G; S_v of length max(nc, nd), the past disturbance), that is R(q)/(C F) delta with R of
    length n_r = max(nd + max(nf, K + nb), nf + max(nc, nd)). An output level mu that the
    sample mean (Eq. 3.20) missed adds mu D/C 1: eps = D/C (y - mu - w). Both are linear in
    their coefficients, so :func:`fit_prediction_error` removes them by least squares.

    Returns
    -------
    transient : ndarray, shape (rows, n_r)
        Columns q^-k/(C F) delta, k = 0..n_r-1, up to the sample after which they are below
        1e-12 of their peak (zero from there on; rows <= n).
    step : ndarray, shape (n,)
        D/C applied to a unit step.
    """
    _, f, c, d = orders.split(theta)
    n_r = max(orders.nd + max(orders.nf, orders.delay + orders.nb), orders.nf + max(orders.nc, orders.nd))
    n_r = min(n_r, max(n // 4, 1))
    response = filter_settling([1.0], np.convolve(monic(c), monic(f)), [1.0], n)
    alive = np.flatnonzero(np.abs(response) > 1e-12 * np.max(np.abs(response)))
    rows = min(n, int(alive[-1]) + 1 + n_r)
    transient = np.zeros((rows, n_r))
    _add_shifted(transient, 0, response[:rows], range(n_r))
    return transient, filter_settling(monic(d), monic(c), [], n, level=1.0)


@dataclass
class _StartUp:
    """Orthonormal basis of the start-up signals: ``head`` (rows, n_r), zero after ``rows``; ``dense`` (N,)."""

    head: np.ndarray
    dense: np.ndarray
    to_coefficients: tuple[np.ndarray, np.ndarray, float]  # R_h, Q_h^T step_head, |step'|

    @classmethod
    def of(cls, theta: np.ndarray, orders: Orders, n: int) -> _StartUp:
        transient, step = start_up_basis(theta, orders, n)
        rows = transient.shape[0]
        head, r_head = np.linalg.qr(transient)
        along = head.T @ step[:rows]
        dense = step.copy()
        dense[:rows] -= head @ along
        norm = float(np.linalg.norm(dense))
        return cls(head, dense / norm if norm > 1e-12 else np.zeros(n), (r_head, along, norm))

    def components(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Coordinates of x (shape (N,) or (N, k)) along ``head`` and ``dense``."""
        return self.head.T @ x[: self.head.shape[0]], self.dense @ x

    def remove(self, x: np.ndarray) -> np.ndarray:
        """x minus its least-squares fit by the start-up signals."""
        on_head, on_dense = self.components(x)
        out = x - np.multiply.outer(self.dense, on_dense)
        out[: self.head.shape[0]] -= self.head @ on_head
        return np.asarray(out)

    def coefficients(self, x: np.ndarray) -> np.ndarray:
        """R's coefficients, then mu, of the least-squares fit of x; shape (n_r + 1,)."""
        r_head, along, norm = self.to_coefficients
        on_head, on_dense = self.components(x)
        mu = float(on_dense) / norm if norm > 1e-12 else 0.0
        r = np.linalg.lstsq(r_head, on_head - along * mu, rcond=1e-12)[0]
        return np.append(r, mu)


@dataclass
class _Evaluation:
    """Prediction errors at one theta, with what the Jacobian needs."""

    theta: np.ndarray
    errors: np.ndarray  # start-up removed
    raw: tuple[np.ndarray, np.ndarray, np.ndarray]  # from-rest eps, w, v
    start: _StartUp | None
    coefficients: np.ndarray  # R's coefficients, then mu

    @property
    def cost(self) -> float:
        return float(self.errors @ self.errors)

    def start_up(self, orders: Orders) -> np.ndarray:
        """R/(C F) delta, the response of the initial conditions alone (mu excluded); shape (N,)."""
        if self.start is None:
            return np.zeros_like(self.errors)
        _, f, c, _ = orders.split(self.theta)
        return filter_settling(self.coefficients[:-1], np.convolve(monic(c), monic(f)), [1.0], self.errors.size)


def _evaluate(theta: np.ndarray, u: np.ndarray, y: np.ndarray, orders: Orders, estimate_start: bool) -> _Evaluation:
    eps, w, v = prediction_errors(theta, u, y, orders)
    if not estimate_start:
        return _Evaluation(theta, eps, (eps, w, v), None, np.zeros(0))
    start = _StartUp.of(theta, orders, u.size)
    return _Evaluation(theta, start.remove(eps), (eps, w, v), start, start.coefficients(eps))


def errors_without_start_up(theta: np.ndarray, u: np.ndarray, y: np.ndarray, orders: Orders) -> np.ndarray:
    """Prediction errors of Eq. 3.27 with the least-squares start-up response removed; shape (N,).

    The criterion :func:`fit_prediction_error` minimises (``estimate_start=True``): compare a
    fitted theta with another one (e.g. the true parameters) on the same record.
    """
    return _evaluate(np.asarray(theta, dtype=float), u, y, orders, True).errors


def _jacobian(point: _Evaluation, u: np.ndarray, orders: Orders) -> np.ndarray:
    """d eps / d theta of the errors with the start-up removed (variable projection).

    With tau = R/(C F) delta + mu D/C 1 the start-up signal at its least-squares coefficients:
    d tau/d f_k = -q^-k tau_R / F, d tau/d c_k = -q^-k tau / C, d tau/d d_k = q^-k mu / C 1;
    the Jacobian of eps_rest - tau, projected off the start-up signals, has the exact gradient
    of the profiled criterion (Kaufman's form).
    """
    eps, w, v = point.raw
    jac = jacobian(point.theta, u, orders, eps, w, v)
    if point.start is None:
        return jac
    _, f, c, d = orders.split(point.theta)
    n = u.size
    mu = float(point.coefficients[-1])
    tau_r = point.start_up(orders)  # settles: filters of it need only its head (filter_settling)
    head = tau_r[: int(np.flatnonzero(tau_r)[-1]) + 1] if np.any(tau_r) else tau_r[:0]
    tau_r_f = filter_settling([1.0], monic(f), head, n)
    # 1/C (tau_r + mu D/C 1), the step part as a step response of D/C^2
    tau_c = filter_settling([1.0], monic(c), head, n) + filter_settling(
        mu * monic(d), np.convolve(monic(c), monic(c)), [], n, level=1.0)
    mu_c = filter_settling([mu], monic(c), [], n, level=1.0)
    i_f, i_c, i_d = orders.nb, orders.nb + orders.nf, orders.nb + orders.nf + orders.nc
    _add_shifted(jac, i_f, tau_r_f, range(1, orders.nf + 1))
    _add_shifted(jac, i_c, tau_c, range(1, orders.nc + 1))
    _add_shifted(jac, i_d, -mu_c, range(1, orders.nd + 1))
    return point.start.remove(jac)


def fit_prediction_error(
    u: np.ndarray,
    y: np.ndarray,
    orders: Orders,
    theta0: np.ndarray,
    max_iter: int = 100,
    tol: float = 1e-8,
    estimate_start: bool = True,
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
    estimate_start : bool
        Remove, at every theta, the least-squares start-up response of the unknown initial
        state and output offset (:func:`start_up_basis`); False takes the record to start from
        rest at the sample mean (the first samples then weigh on the fit with the transient).
    """
    theta = np.asarray(theta0, dtype=float).copy()
    point = _evaluate(theta, u, y, orders, estimate_start)
    jac = _jacobian(point, u, orders)
    if orders.n_parameters == 0:
        return _result(point, jac, orders, 0, True)
    hessian, gradient = jac.T @ jac, jac.T @ point.errors
    mu = 1e-4 * float(np.max(np.diag(hessian)))
    converged = False
    n_iter = 0
    for n_iter in range(1, max_iter + 1):  # noqa: B007 - n_iter is reported
        try:
            step = np.linalg.solve(hessian + mu * np.eye(theta.size), -gradient)
        except np.linalg.LinAlgError:
            mu *= 10.0
            continue
        candidate = point.theta + step
        trial = _evaluate(candidate, u, y, orders, estimate_start) if _admissible(candidate, orders) else None
        if trial is not None and trial.cost < point.cost:
            improvement = (point.cost - trial.cost) / max(point.cost, np.finfo(float).tiny)
            point = trial
            jac = _jacobian(point, u, orders)
            hessian, gradient = jac.T @ jac, jac.T @ point.errors
            mu = max(mu / 10.0, 1e-12 * float(np.max(np.diag(hessian))))
            if improvement < tol:
                converged = True
                break
        else:
            mu *= 10.0
            if mu > 1e12 * max(float(np.max(np.diag(hessian))), 1.0):
                converged = True  # no descent direction left: a (local) minimum
                break
    event(_log, "prediction-error fit", orders=orders, n_iter=n_iter, converged=converged, cost=point.cost)
    return _result(point, jac, orders, n_iter, converged)


def _result(point: _Evaluation, jac: np.ndarray, orders: Orders, n_iter: int, converged: bool) -> PEMResult:
    offset = float(point.coefficients[-1]) if point.start is not None else 0.0
    start_up = point.start_up(orders)
    return PEMResult(point.theta, point.errors, jac, n_iter, converged, start_up, offset, point.coefficients.size)
