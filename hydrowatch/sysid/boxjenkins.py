"""Box-Jenkins reference model (study chapter 3) as a scikit-learn style estimator.

Model (Eq. 3.1) with a dead time of K samples, on the normalised signals of Eqs. 3.19, 3.20::

    y(t) = q^-K B(q)/F(q) u(t) + C(q)/D(q) e(t)
    B(q) = b1 q^-1 + ... + b_nb q^-nb
    F(q) = 1 + f1 q^-1 + ... ,  C(q) = 1 + c1 q^-1 + ... ,  D(q) = 1 + d1 q^-1 + ...

so the first sample of the impulse response that can be non-zero is at lag K + 1.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.base import BaseEstimator
from threadpoolctl import threadpool_limits

from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.sysid.pem import Orders
from hydrowatch.sysid.polynomials import delayed_numerator, filter_signal, impulse_response, monic
from hydrowatch.sysid.starts import estimate
from hydrowatch.sysid.validation import (
    confidence_intervals,
    parameter_covariance,
    pole_zero_report,
    q_statistic,
    s_statistic,
)

__all__ = ["BoxJenkins", "check_signals"]

_FORMAT = "hydrowatch.sysid.BoxJenkins"


def check_signals(
    u: Any, y: Any, n_parameters: int, min_samples: int, excitation_order: int
) -> tuple[np.ndarray, np.ndarray]:
    """Validated float copies of input u and output y for identification.

    Raises DataError for non-1-D, mismatched, non-finite or too short signals and for an input
    that is not persistently exciting of order ``excitation_order`` (the lagged-input matrix
    [u(t-1) ... u(t-n)] must have full rank; nb + nf is what a Box-Jenkins model needs).
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    for name, x in (("input u", u), ("output y", y)):
        if x.ndim != 1:
            raise DataError(f"{name} must be a 1-D signal. Got shape {x.shape}; pass one column.")
        if not np.all(np.isfinite(x)):
            bad = np.flatnonzero(~np.isfinite(x))
            raise DataError(
                f"{name} must be finite. Got {bad.size} NaN/inf samples (first at index {bad[0]}); "
                "drop or interpolate them before identification."
            )
    if u.size != y.size:
        raise DataError(f"input u and output y must have the same length. Got {u.size} and {y.size}; align them.")
    if u.size < min_samples:
        raise DataError(
            f"the number of samples must be at least {min_samples} for {n_parameters} parameters. "
            f"Got {u.size}; record longer or lower the orders."
        )
    if np.std(u) == 0.0:
        raise DataError("input u must vary. Got a constant input; excite the system (e.g. filtered white noise).")
    if excitation_order > 0:
        centred = u - u.mean()
        lagged = np.column_stack([centred[excitation_order - k : u.size - k] for k in range(excitation_order)])
        s = np.linalg.svd(lagged, compute_uv=False)
        if s[-1] < 1e-6 * s[0]:
            rank = int(np.sum(s > 1e-6 * s[0]))
            raise DataError(
                f"input u must be persistently exciting of order nb + nf = {excitation_order}. Got order {rank}; "
                "use a richer input (filtered white noise, Eq. 3.21) or lower nb/nf."
            )
    return u, y


class BoxJenkins(BaseEstimator):  # type: ignore[misc]
    """Box-Jenkins model y = q^-K B/F u + C/D e fitted by prediction error (Eqs. 3.1, 3.8-3.14).

    Parameters
    ----------
    nb : int, default 2
        Number of B coefficients b1..b_nb (>= 1).
    nf, nc, nd : int, default 2, 1, 1
        Orders of the monic F, C, D (>= 0).
    delay : int, default 0
        Dead time K [samples] in front of B (which itself starts at q^-1).
    normalize : bool, default True
        Remove the means (Eqs. 3.19, 3.20) and divide by the standard deviations inside fit and
        predict; parameters are reported in the signals' own units either way.
    max_iter : int, default 100
        Levenberg-Marquardt iterations (Eq. 3.12).
    tol : float, default 1e-8
        Relative cost decrease that stops the iterations.
    lags : int, default 35
        K of the Q and S statistics (Eqs. 3.17, 3.18); the study's degrees of freedom imply 35.
    cancellation_tolerance : float, default 0.05
        Distance in the z-plane under which a zero and a pole count as cancelling (reported in
        ``validation_``, and the trigger of the guard's restarts).
    initial_conditions : {"estimate", "zero"}, default "estimate"
        "estimate": the state at the first sample and an output offset are fitted by least
        squares at every step (a record that does not start from rest); "zero": all filters
        start from rest at the sample means, the first residuals carry the start-up transient.
    guard : bool, default True
        Fit from two starts and restart away from near pole-zero cancellations, keeping the
        lowest criterion (:func:`hydrowatch.sysid.starts.estimate`); False: one fit from the
        instrumental-variable start (faster, may stop in a local minimum).

    Attributes
    ----------
    b_, f_, c_, d_ : ndarray
        Coefficients b1.., f1.., c1.., d1.. (F, C, D monic; leading 1 not stored). b_ in output
        units per input unit.
    covariance_ : ndarray, shape (p, p)
        Covariance of [b, f, c, d] (Eq. 3.14).
    ci95_ : ndarray, shape (p, 2)
        95 % confidence intervals, rows in the order of ``parameter_names_``.
    sigma2_ : float
        Residual variance, output units squared.
    residuals_ : ndarray, shape (N,)
        One-step prediction errors on the training data (Eq. 3.27), output units, with the
        start-up response removed: ``y - predict(u, y) - start_up_response_``.
    start_up_response_ : ndarray, shape (N,)
        Response of the estimated initial state in those errors (zeros with
        ``initial_conditions="zero"``), output units. The estimated output offset is in
        ``output_mean_``.
    n_start_up_ : int
        Start-up coefficients fitted with the parameters (initial state and output offset; 0
        with ``initial_conditions="zero"``), counted by the order search's criterion.
    starts_ : list of dict
        Every prediction-error fit tried: ``start``, ``sigma2`` (output units squared),
        ``n_iter``, ``cancellations`` and ``kept``.
    validation_ : dict
        Q, Q_dof, Q_p, S, S_dof, S_p, stable, invertible, cancellations, roots.
    nrmse_one_step_ : float
        RMS(residuals) / std(y) on the training data.
    """

    def __init__(
        self,
        *,
        nb: int = 2,
        nf: int = 2,
        nc: int = 1,
        nd: int = 1,
        delay: int = 0,
        normalize: bool = True,
        max_iter: int = 100,
        tol: float = 1e-8,
        lags: int = 35,
        cancellation_tolerance: float = 0.05,
        initial_conditions: str = "estimate",
        guard: bool = True,
    ) -> None:
        self.nb = nb
        self.nf = nf
        self.nc = nc
        self.nd = nd
        self.delay = delay
        self.normalize = normalize
        self.max_iter = max_iter
        self.tol = tol
        self.lags = lags
        self.cancellation_tolerance = cancellation_tolerance
        self.initial_conditions = initial_conditions
        self.guard = guard

    # ---------------------------------------------------------------- fitting
    def _orders(self) -> Orders:
        for name, low in (("nb", 1), ("nf", 0), ("nc", 0), ("nd", 0), ("delay", 0)):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < low:
                raise ParameterError(f"{name} must be an integer >= {low}. Got {value!r}.")
        if not isinstance(self.max_iter, (int, np.integer)) or self.max_iter < 1:
            raise ParameterError(f"max_iter must be a positive integer. Got {self.max_iter!r}.")
        if not self.tol > 0:
            raise ParameterError(f"tol must be positive. Got {self.tol!r}; use e.g. 1e-8.")
        if self.initial_conditions not in ("estimate", "zero"):
            raise ParameterError(
                f"initial_conditions must be 'estimate' or 'zero'. Got {self.initial_conditions!r}; use 'estimate'."
            )
        if not self.cancellation_tolerance > 0:
            raise ParameterError(
                f"cancellation_tolerance must be positive. Got {self.cancellation_tolerance!r}; use e.g. 0.05."
            )
        return Orders(int(self.nb), int(self.nf), int(self.nc), int(self.nd), int(self.delay))

    @property
    def parameter_names_(self) -> list[str]:
        """["b1", .., "f1", .., "c1", .., "d1", ..] in the order of Eq. 3.8."""
        o = self._orders()
        return [f"{p}{i}" for p, n in (("b", o.nb), ("f", o.nf), ("c", o.nc), ("d", o.nd)) for i in range(1, n + 1)]

    def fit(self, u: np.ndarray, y: np.ndarray) -> BoxJenkins:
        """Estimate B, F, C, D from input u and output y (Eqs. 3.9-3.13) and validate the fit.

        Parameters
        ----------
        u : ndarray, shape (N,)
            Input (e.g. servo-valve voltage [V]).
        y : ndarray, shape (N,)
            Output (e.g. gearbox speed [rad/s]).
        """
        orders = self._orders()
        p = orders.n_parameters
        min_samples = max(
            2 * int(self.lags) + 2, orders.delay + max(orders.nb, orders.nf, orders.nc, orders.nd) + 10 * p
        )
        u, y = check_signals(u, y, p, min_samples, orders.nb + orders.nf)
        self.input_mean_, self.output_mean_ = (float(u.mean()), float(y.mean())) if self.normalize else (0.0, 0.0)
        self.input_scale_, self.output_scale_ = (
            (float(u.std()), float(y.std()) or 1.0) if self.normalize else (1.0, 1.0)
        )
        un = (u - self.input_mean_) / self.input_scale_
        yn = (y - self.output_mean_) / self.output_scale_
        # one BLAS thread: the products are N x p with p <= ~20, too small to share; on 2 busy
        # cores OpenBLAS's spinning threads made a fit of Eq. 3.24 (N = 30,000) 8x dearer in CPU
        # time and wall time (30.4 against 3.6 CPU-s for three fits)
        with threadpool_limits(limits=1):
            result, attempts = estimate(
                un, yn, orders, max_iter=int(self.max_iter), tol=float(self.tol),
                estimate_start=self.initial_conditions == "estimate", guard=bool(self.guard),
                tolerance=float(self.cancellation_tolerance),
            )  # fmt: skip
        self.output_mean_ += result.offset * self.output_scale_
        covariance, sigma2 = parameter_covariance(result.jacobian, result.errors)
        gain = self.output_scale_ / self.input_scale_
        to_units = np.concatenate([np.full(orders.nb, gain), np.ones(p - orders.nb)])
        theta = result.theta * to_units
        self.b_, self.f_, self.c_, self.d_ = (np.array(x) for x in orders.split(theta))
        self.covariance_ = covariance * np.outer(to_units, to_units)
        self.ci95_ = confidence_intervals(theta, self.covariance_, 0.95)
        self.sigma2_ = sigma2 * self.output_scale_**2
        self.residuals_ = result.errors * self.output_scale_
        self.start_up_response_ = result.start_up * self.output_scale_
        self.starts_ = [
            {**{k: v for k, v in a.items() if k != "cost"}, "sigma2": a["cost"] / u.size * self.output_scale_**2}
            for a in attempts
        ]
        self.n_iter_, self.converged_, self.n_samples_ = result.n_iter, result.converged, int(u.size)
        self.n_start_up_ = result.n_start_up
        self.nrmse_one_step_ = float(np.sqrt(np.mean(self.residuals_**2)) / (np.std(y) or 1.0))
        self.validation_ = self._validate(un, result.errors, orders)
        return self

    def _validate(self, un: np.ndarray, errors: np.ndarray, orders: Orders) -> dict[str, Any]:
        q, q_dof, q_p = q_statistic(errors, self.lags, orders.nc + orders.nd)
        s, s_dof, s_p = s_statistic(un, errors, self.lags, orders.nb + orders.nf)
        roots = pole_zero_report(self.b_, self.f_, self.c_, self.d_, self.cancellation_tolerance)
        return {
            "Q": q, "Q_dof": q_dof, "Q_p": q_p, "S": s, "S_dof": s_dof, "S_p": s_p,
            "lags": int(self.lags),
            "stable": roots.pop("stable"), "invertible": roots.pop("invertible"),
            "cancellations": roots.pop("cancellations"), "roots": roots,
        }  # fmt: skip

    # ------------------------------------------------------------- prediction
    def _check_fitted(self) -> None:
        if not hasattr(self, "b_"):
            raise NotFittedError("BoxJenkins must be fitted before use. Call fit(u, y) or BoxJenkins.load(path).")

    def predict(self, u: np.ndarray, y: np.ndarray | None = None, *, steps_ahead: int | None = 1) -> np.ndarray:
        """k-step-ahead prediction of y (Eq. 3.26 for k = 1) or free-run simulation (k = None).

        y_hat(t|t-k) = y(t) - W_k(q) (y(t) - q^-K B/F u(t)), W_k = Hbar_k D/C, where Hbar_k is
        the first k terms of the impulse response of H = C/D (W_1 = D/C gives Eq. 3.26). With
        ``steps_ahead=None`` the output is not used: y_hat = q^-K B/F u. Both start from rest.

        Parameters
        ----------
        u : ndarray, shape (N,)
            Input, same units as in fit.
        y : ndarray, shape (N,), optional
            Measured output; required unless ``steps_ahead`` is None.
        steps_ahead : int or None, default 1

        Returns
        -------
        ndarray, shape (N,)
            Predicted output in output units.
        """
        self._check_fitted()
        u = np.asarray(u, dtype=float)
        un = (u - self.input_mean_) / self.input_scale_
        gain = self.output_scale_ / self.input_scale_
        w = filter_signal(delayed_numerator(self.b_ / gain, int(self.delay)), monic(self.f_), un)
        if steps_ahead is None:
            return self.output_mean_ + self.output_scale_ * w
        if y is None:
            raise ParameterError("y must be given for steps_ahead >= 1. Got None; pass y or steps_ahead=None.")
        if not isinstance(steps_ahead, (int, np.integer)) or steps_ahead < 1:
            raise ParameterError(f"steps_ahead must be a positive integer or None. Got {steps_ahead!r}.")
        y = np.asarray(y, dtype=float)
        if y.shape != u.shape:
            raise DataError(f"u and y must have the same shape. Got {u.shape} and {y.shape}; align them.")
        yn = (y - self.output_mean_) / self.output_scale_
        h_bar = impulse_response(monic(self.c_), monic(self.d_), int(steps_ahead))
        w_k = filter_signal(np.convolve(h_bar, monic(self.d_)), monic(self.c_), yn - w)
        return self.output_mean_ + self.output_scale_ * (yn - w_k)

    def simulate(self, u: np.ndarray) -> np.ndarray:
        """Free-run output q^-K B/F u (noise-free), from rest; same as ``predict(u, steps_ahead=None)``."""
        return self.predict(u, steps_ahead=None)

    # ---------------------------------------------------------- serialisation
    def to_dict(self) -> dict[str, Any]:
        """The contract's ``hydrowatch identify --json`` object for this model."""
        self._check_fitted()
        theta = np.concatenate([self.b_, self.f_, self.c_, self.d_])
        parameters = {
            name: {"value": float(v), "ci95": _jsonable([lo, hi])}
            for name, v, (lo, hi) in zip(self.parameter_names_, theta, self.ci95_)
        }
        return {
            "model": "bj",
            "orders": {"nb": int(self.nb), "nf": int(self.nf), "nc": int(self.nc), "nd": int(self.nd)},
            "delay": int(self.delay),
            "parameters": parameters,
            "validation": _jsonable(self.validation_),
            "nrmse_one_step": float(self.nrmse_one_step_),
            "n_samples": int(self.n_samples_),
            "converged": bool(self.converged_),
            "initial_conditions": str(self.initial_conditions),
            "starts": _jsonable(self.starts_),
        }

    _STATE = ("b_", "f_", "c_", "d_", "covariance_", "ci95_", "sigma2_", "nrmse_one_step_")
    _RECORDS = ("validation_", "starts_")
    _SCALARS = (
        "input_mean_", "input_scale_", "output_mean_", "output_scale_", "n_iter_", "converged_", "n_samples_",
        "n_start_up_",
    )  # fmt: skip
    _VERSION_1_DEFAULTS: dict[str, Any] = {"starts_": [], "n_start_up_": 0}  # fields that version 1 files lack

    def save(self, path: str | Path) -> None:
        """Write parameters and fitted state as JSON (residuals are not kept)."""
        self._check_fitted()
        state = {name: _jsonable(getattr(self, name)) for name in self._STATE + self._RECORDS + self._SCALARS}
        document = {"format": _FORMAT, "version": 2, "params": self.get_params(), "fitted": state}
        Path(path).write_text(json.dumps(document, indent=1))

    @classmethod
    def load(cls, path: str | Path) -> BoxJenkins:
        """A fitted model read back from :meth:`save`'s JSON."""
        try:
            document = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise DataError(f"file must be a readable JSON model. Got {exc}.", source=str(path)) from exc
        if not isinstance(document, dict) or document.get("format") != _FORMAT:
            raise DataError(f"format must be {_FORMAT!r}. Got another file; pass a saved BoxJenkins.", source=str(path))
        fitted_as = {"initial_conditions": "zero", "guard": False} if document.get("version") == 1 else {}
        model = cls(**{**fitted_as, **document["params"]})
        fitted = document["fitted"]
        for name in cls._STATE:
            setattr(model, name, np.asarray(fitted[name], dtype=float))
        for name in cls._RECORDS + cls._SCALARS:
            setattr(model, name, fitted[name] if name in fitted else cls._VERSION_1_DEFAULTS[name])
        return model


def _jsonable(value: Any) -> Any:
    """Arrays, numpy scalars and nested containers as plain JSON types; NaN/inf become null."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if np.isfinite(value) else None
    return value
