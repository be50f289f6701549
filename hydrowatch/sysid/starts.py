"""Starting values and restarts of the Box-Jenkins prediction-error fit (study Eqs. 3.8-3.13).

The criterion of Eq. 3.9 has local minima. On records of the study's Eq. 3.24 they hold a
spurious zero-pole pair of H = C/D near the unit circle (e.g. zero -0.994, pole -0.991) or a
rotated noise model, at a criterion 0.1-0.2 % above the best one, and the iterations stop
there with every test passing. :func:`estimate` therefore

1. fits from the instrumental-variable / Hannan-Rissanen start (:func:`initial_estimate`);
2. fits from an *order-recursive* start: the model with nc - 1, nd - 1 fitted first, then its
   C and D padded with a root at the origin each (:func:`order_recursive_start`);
3. keeps the fit with the lower criterion and, while its G or H has a near pole-zero
   cancellation, refits from the start with that pair removed (:func:`without_cancellation`),
   keeping the refit only if its criterion is not worse.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hydrowatch.sysid.pem import Orders, PEMResult, _shift, fit_prediction_error
from hydrowatch.sysid.polynomials import (
    cancellations,
    delayed_numerator,
    filter_signal,
    monic,
    numerator_zeros,
    polynomial_roots,
    reflect_into_unit_circle,
)

__all__ = ["estimate", "initial_estimate", "order_recursive_start", "without_cancellation"]


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


def order_recursive_start(
    u: np.ndarray, y: np.ndarray, orders: Orders, max_iter: int, tol: float, estimate_start: bool
) -> np.ndarray | None:
    """Start from the fitted model with one order less in C and in D, padded with zero roots.

    The smaller noise model is better determined (its initial estimate has fewer spurious
    near-common factors); adding a root at the origin to C and to D gives the same predictor,
    from which the iterations place the extra pair. None when nc = nd = 0.
    """
    if orders.nc == 0 and orders.nd == 0:
        return None
    lower = Orders(orders.nb, orders.nf, max(orders.nc - 1, 0), max(orders.nd - 1, 0), orders.delay)
    fitted = fit_prediction_error(u, y, lower, initial_estimate(u, y, lower), max_iter, tol, estimate_start)
    b, f, c, d = lower.split(fitted.theta)
    pad_c, pad_d = orders.nc - lower.nc, orders.nd - lower.nd
    return np.concatenate([b, f, c, np.zeros(pad_c), d, np.zeros(pad_d)])


def _remove_root(roots: np.ndarray, root: complex) -> np.ndarray:
    """``roots`` without ``root`` (and its conjugate when complex)."""
    keep = np.ones(roots.size, dtype=bool)
    for target in (root, np.conj(root)) if abs(root.imag) > 1e-9 else (root,):
        distance = np.where(keep, np.abs(roots - target), np.inf)
        keep[int(np.argmin(distance))] = False
    return roots[keep]


def _tail(roots: np.ndarray, length: int, lead: float = 1.0) -> np.ndarray:
    """Coefficients of lead * prod(1 - r q^-1) after the leading term, padded with zeros to ``length``.

    For a numerator B (no leading 1) ``lead`` is b1 and the whole polynomial is returned.
    """
    full = lead * np.real(np.poly(roots)) if roots.size else np.array([lead])
    part = full if lead != 1.0 else full[1:]
    out = np.zeros(length)
    out[: part.size] = part[:length]
    return out


def without_cancellation(theta: np.ndarray, orders: Orders, tolerance: float) -> list[tuple[str, np.ndarray]]:
    """Starting points with each near pole-zero cancellation of G = B/F or H = C/D removed.

    For every zero-pole pair closer than ``tolerance`` (:func:`polynomials.cancellations`) the
    pair (with its conjugates) is divided out and the freed coefficients set to zero (roots at
    the origin), so the orders stay; nearest pairs first.

    Returns
    -------
    list of (label, theta) : theta shape (n_parameters,), in the units of ``theta``
    """
    b, f, c, d = orders.split(np.asarray(theta, dtype=float))
    found: list[tuple[float, str, np.ndarray]] = []
    zb, pf = numerator_zeros(b), polynomial_roots(monic(f))
    for zero, pole in cancellations(zb, pf, tolerance):
        new_b = _tail(_remove_root(zb, zero), orders.nb, float(b[0]))
        new_f = _tail(_remove_root(pf, pole), orders.nf)
        label = f"G zero {zero:.3f} / pole {pole:.3f} removed"
        found.append((abs(zero - pole), label, np.concatenate([new_b, new_f, c, d])))
    zc, pd = polynomial_roots(monic(c)), polynomial_roots(monic(d))
    for zero, pole in cancellations(zc, pd, tolerance):
        new_c = _tail(_remove_root(zc, zero), orders.nc)
        new_d = _tail(_remove_root(pd, pole), orders.nd)
        label = f"H zero {zero:.3f} / pole {pole:.3f} removed"
        found.append((abs(zero - pole), label, np.concatenate([b, f, new_c, new_d])))
    found.sort(key=lambda item: item[0])
    return [(label, start) for _, label, start in found]


def estimate(
    u: np.ndarray,
    y: np.ndarray,
    orders: Orders,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    estimate_start: bool = True,
    guard: bool = True,
    tolerance: float = 0.05,
    max_restarts: int = 3,
) -> tuple[PEMResult, list[dict[str, Any]]]:
    """Prediction-error fit of a Box-Jenkins model guarded against local minima (module docstring).

    Parameters
    ----------
    u, y : ndarray, shape (N,)
        Normalised input and output (Eqs. 3.19, 3.20).
    orders : Orders
    max_iter, tol, estimate_start
        Passed to :func:`pem.fit_prediction_error`.
    guard : bool, default True
        Fit from both starts and restart away from cancellations; False: one fit from
        :func:`initial_estimate` (faster, may stop in a local minimum).
    tolerance : float, default 0.05
        Zero-pole distance in the z-plane below which a pair counts as cancelling.
    max_restarts : int, default 3
        Largest number of accepted cancellation restarts.

    Returns
    -------
    result : PEMResult
        The fit with the lowest criterion sum eps^2 (Eq. 3.9).
    attempts : list of dict
        Every fit: ``start`` (label), ``cost`` (sum eps^2, normalised units), ``n_iter``,
        ``cancellations`` (count at that fit's estimate) and ``kept`` (True for the returned one).
    """
    attempts: list[tuple[str, PEMResult]] = []

    def attempt(label: str, theta0: np.ndarray) -> PEMResult:
        result = fit_prediction_error(u, y, orders, theta0, max_iter, tol, estimate_start)
        attempts.append((label, result))
        return result

    best = attempt("instrumental variables + Hannan-Rissanen", initial_estimate(u, y, orders))
    if guard:
        recursive = order_recursive_start(u, y, orders, max_iter, tol, estimate_start)
        if recursive is not None:
            candidate = attempt("order-recursive (nc - 1, nd - 1, padded)", recursive)
            best = candidate if candidate.cost < best.cost else best
        for _ in range(max_restarts):
            for label, theta0 in without_cancellation(best.theta, orders, tolerance):
                candidate = attempt(label, theta0)
                if candidate.cost <= best.cost:
                    best = candidate
                    break
            else:
                break
    summary = [
        {
            "start": label,
            "cost": result.cost,
            "n_iter": result.n_iter,
            "cancellations": len(without_cancellation(result.theta, orders, tolerance)),
            "kept": result is best,
        }
        for label, result in attempts
    ]
    return best, summary
