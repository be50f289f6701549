"""NARX reference model of a healthy machine (study chapter 4).

A two-layer network (log-sigmoid hidden layer, linear output; Eqs. 4.2, 4.6) maps tapped delay
lines of past inputs and outputs (Eq. 4.18) to the next output. It is trained series-parallel
(measured outputs in the delay lines) by Levenberg-Marquardt with Bayesian regularisation
(Eqs. 4.20, 4.21; :mod:`hydrowatch.sysid.narx_lm`) and validated by the residual correlations of
Eqs. 4.22 and 4.23. The structure search of section 4.5.2 is :func:`hydrowatch.sysid.narx_search.search_structure`.

Example
-------
>>> model = NARX(input_delays=15, output_delays=15, hidden=35).fit(voltage, speed)
>>> speed_hat = model.predict(voltage, speed)            # one step ahead, NaN while the lines fill
>>> free = model.predict(voltage, speed, steps_ahead=None)  # closed loop (Fig. 4.10)
"""

from __future__ import annotations

import os
import pickle
from typing import Any

import numpy as np
import torch
from sklearn.base import BaseEstimator

from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.log import event, get_logger
from hydrowatch.sysid import narx_lines as lines
from hydrowatch.sysid.correlation import autocorrelation, confidence_bound, cross_correlation
from hydrowatch.sysid.narx_lm import LMSettings, initial_weights, n_parameters, torch_one_thread, train

__all__ = ["NARX"]

_log = get_logger(__name__)
FORMAT = "hydrowatch.narx"
FORMAT_VERSION = 1
_DTYPES = {"float64": torch.float64, "float32": torch.float32}


def _dtype_name(dtype: Any) -> str:
    for name, value in _DTYPES.items():
        if dtype is value or dtype == name:
            return name
    raise ParameterError(f"dtype must be torch.float64 or torch.float32. Got {dtype!r}; use torch.float64.")


class NARX(BaseEstimator):  # type: ignore[misc]
    """Non-linear ARX one-step-ahead predictor, a healthy reference model (study section 4.3).

    Parameters
    ----------
    input_delays : int, default 15
        Taps n_u of each input's delay line (u(t-1)..u(t-n_u)), >= 1 (Table 4.5: 15).
    output_delays : int, default 15
        Taps n_y of the output delay line (y(t-1)..y(t-n_y)), >= 0 (Table 4.5: 15).
    hidden : int, default 35
        Log-sigmoid neurons in the first layer (Table 4.5: 35).
    max_iter : int, default 200
        Levenberg-Marquardt iterations at most.
    early_stopping : bool, default False
        Hold out the last ``validation_fraction`` of the record and stop when its error has not
        improved for 6 iterations (Bayesian regularisation alone needs no hold-out).
    validation_fraction : float, default 0.15
        Share of the regressor rows (the most recent ones) held out when ``early_stopping``.
    seed : int or None, default 0
        Seed of the Nguyen-Widrow initial weights.
    dtype : torch.dtype, default torch.float64
        Precision of training.
    tol : float, default 1e-6
        Training stops as converged after 5 iterations whose relative changes of the sum of
        squared errors E_D and of γ/n are below ``tol``.

    Attributes
    ----------
    weights_ : torch.Tensor, shape (n_parameters_,)
        Flat weights (layout in :mod:`hydrowatch.sysid.narx_lm`), on normalised signals.
    alpha_, beta_, gamma_ : float
        Bayesian regularisation hyperparameters and effective number of parameters (Eq. 4.21).
    n_parameters_ : int
        Weights and biases, hidden·(R + 2) + 1.
    n_inputs_ : int
    input_mean_, input_scale_ : ndarray, shape (n_inputs_,)
        z-score of each input, in its unit.
    output_mean_, output_scale_ : float
        z-score of the output, in its unit.
    history_ : dict of lists
        Per-iteration ``sse`` (E_D), ``sse_weights`` (E_W), ``alpha``, ``beta``, ``gamma``, ``mu``
        (and ``validation_sse`` with early stopping), normalised units.
    residuals_ : ndarray, shape (n - d,)
        One-step prediction errors ε(t) = y(t) − ŷ(t|θ) on the fit data (Eq. 4.24), output unit.
    train_summary_ : dict
        Sample count, signal ranges, NRMSE, iterations, stop reason, fit seconds.
    """

    def __init__(self, *, input_delays: int = 15, output_delays: int = 15, hidden: int = 35, max_iter: int = 200,
                 early_stopping: bool = False, validation_fraction: float = 0.15, seed: int | None = 0,
                 dtype: torch.dtype = torch.float64, tol: float = 1e-6) -> None:
        self.input_delays = input_delays
        self.output_delays = output_delays
        self.hidden = hidden
        self.max_iter = max_iter
        self.early_stopping = early_stopping
        self.validation_fraction = validation_fraction
        self.seed = seed
        self.dtype = dtype
        self.tol = tol

    def _validate_params(self) -> None:
        def integer(name: str, low: int) -> None:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise ParameterError(f"{name} must be an integer >= {low}. Got {value!r}.")

        integer("input_delays", 1)
        integer("output_delays", 0)
        integer("hidden", 1)
        integer("max_iter", 1)
        if not 0.0 < float(self.validation_fraction) <= 0.5:
            raise ParameterError(f"validation_fraction must be in (0, 0.5]. Got {self.validation_fraction!r}.")
        if not (np.isfinite(self.tol) and self.tol >= 0.0):
            raise ParameterError(f"tol must be a finite number >= 0. Got {self.tol!r}; use e.g. 1e-6.")
        _dtype_name(self.dtype)

    @property
    def delay(self) -> int:
        """Samples that fill the delay lines before the first prediction, max(n_u, n_y)."""
        return max(self.input_delays, self.output_delays)

    # -- fitting ------------------------------------------------------------------------------
    def fit(self, u: np.ndarray, y: np.ndarray) -> NARX:
        """Train on one record (series-parallel, Fig. 4.9) by LM with Bayesian regularisation.

        Parameters
        ----------
        u : ndarray, shape (n,) or (n, n_inputs)
            Input(s), e.g. valve command [V].
        y : ndarray, shape (n,)
            Output, e.g. gearbox speed [rad/s]; must vary.

        Returns
        -------
        self
        """
        self._validate_params()
        u_arr, y_arr = lines.check_signals(u, y)
        n_inputs = u_arr.shape[1]
        n_reg = self.output_delays + self.input_delays * n_inputs
        needed = self.delay + 2 * (n_reg + 1)
        if y_arr.shape[0] < needed:
            raise DataError(
                f"u and y must have at least {needed} samples for {self.input_delays} input and "
                f"{self.output_delays} output delays ({n_reg} regressors). Got {y_arr.shape[0]}; "
                "pass a longer record or shorten the delay lines."
            )
        if np.std(y_arr) == 0.0:
            raise DataError("y must vary. Got a constant output; record while the machine moves.")
        dtype = _DTYPES[_dtype_name(self.dtype)]
        self.n_inputs_ = n_inputs
        self.input_mean_, self.input_scale_ = lines.zscore(u_arr)
        self.output_mean_, self.output_scale_ = float(np.mean(y_arr)), float(np.std(y_arr))
        raw = lines.regressors(u_arr, y_arr, self.input_delays, self.output_delays)
        x1 = torch.as_tensor(np.column_stack([self._normalise(raw), np.ones(raw.shape[0])]), dtype=dtype)
        target = torch.as_tensor((y_arr[self.delay :] - self.output_mean_) / self.output_scale_, dtype=dtype)
        validation = None
        if self.early_stopping:
            n_val = max(1, int(round(self.validation_fraction * target.numel())))
            validation = (x1[-n_val:], target[-n_val:])
            x1, target = x1[:-n_val], target[:-n_val]
        settings = LMSettings(max_iter=int(self.max_iter), tol=float(self.tol))
        theta0 = initial_weights(n_reg, int(self.hidden), self.seed, dtype)
        result = train(x1, target, theta0, int(self.hidden), settings, validation)
        self.weights_ = result.theta.to(torch.float64)
        self.alpha_, self.beta_, self.gamma_ = result.alpha, result.beta, result.gamma
        self.n_parameters_ = n_parameters(n_reg, int(self.hidden))
        self.history_ = result.history
        self._fold()
        self.residuals_ = y_arr[self.delay :] - self.one_step(raw)
        self.train_summary_: dict[str, Any] = {
            "n_samples": int(y_arr.shape[0]), "n_training_rows": int(target.numel()),
            "u_min": [float(v) for v in u_arr.min(axis=0)], "u_max": [float(v) for v in u_arr.max(axis=0)],
            "y_min": float(y_arr.min()), "y_max": float(y_arr.max()),
            "y_mean": self.output_mean_, "y_std": self.output_scale_,
            "nrmse_one_step": float(np.sqrt(np.mean(self.residuals_**2)) / self.output_scale_),
            "iterations": result.iterations, "stop_reason": result.stop_reason, "fit_seconds": result.seconds,
        }
        event(_log, "narx fitted", n=y_arr.shape[0], gamma=round(self.gamma_, 1), n_parameters=self.n_parameters_,
              iterations=result.iterations, stop=result.stop_reason, seconds=round(result.seconds, 2))
        return self

    def _normalise(self, raw: np.ndarray) -> np.ndarray:
        mean, scale = self._regressor_scaling()
        return (raw - mean) / scale

    def _regressor_scaling(self) -> tuple[np.ndarray, np.ndarray]:
        reps = [self.output_delays] + [self.input_delays] * self.n_inputs_
        mean = np.repeat(np.concatenate([[self.output_mean_], self.input_mean_]), reps)
        scale = np.repeat(np.concatenate([[self.output_scale_], self.input_scale_]), reps)
        return mean, scale

    def _fold(self) -> None:
        """Fold the normalisation into float64 weights that act on raw delay-line contents."""
        n_reg = self.output_delays + self.input_delays * self.n_inputs_
        theta = self.weights_.to(torch.float64)
        w1b = theta[: self.hidden * (n_reg + 1)].view(self.hidden, n_reg + 1)
        mean, scale = (torch.as_tensor(v) for v in self._regressor_scaling())
        w1 = w1b[:, :-1] / scale
        self._w1t = w1.T.contiguous()
        self._b1 = w1b[:, -1] - w1 @ mean
        w2 = theta[self.hidden * (n_reg + 1) : -1]
        self._w2 = (w2 * self.output_scale_).contiguous()
        self._b2 = float(theta[-1]) * self.output_scale_ + self.output_mean_

    def _check_fitted(self) -> None:
        if not hasattr(self, "weights_"):
            raise NotFittedError("NARX is not fitted. Call fit(u, y) or NARX.load(path) first.")

    # -- prediction ---------------------------------------------------------------------------
    @property
    def n_regressors(self) -> int:
        """Width of one delay-line row, output_delays + input_delays · n_inputs_ (needs a fit)."""
        self._check_fitted()
        return self.output_delays + self.input_delays * self.n_inputs_

    @property
    def regressor_layout(self) -> str:
        """Order of the entries of a :meth:`one_step` row (Eq. 4.18, most recent first)."""
        names = lines.layout_names(self.input_delays, self.output_delays, self.n_inputs_ if hasattr(self, "n_inputs_")
                                   else 1)
        return "predicts y(t) from [" + ", ".join(names) + "] (raw units, output line first, then each input)"

    def one_step(self, regressors: np.ndarray) -> np.ndarray:
        """One-step predictions for a batch of raw delay lines (the online scorer's path).

        Parameters
        ----------
        regressors : ndarray, shape (batch, output_delays + input_delays·n_inputs)
            Unnormalised delay-line contents in :attr:`regressor_layout` order, one row per machine
            or time step. NaN entries give NaN predictions.

        Returns
        -------
        ndarray, shape (batch,)
            ŷ(t|θ) in the output's unit.

        Runs on one thread (see :func:`hydrowatch.sysid.narx_lm.torch_one_thread`): about 5 million
        rows per CPU-second for 15/15/35; scale out with processes, one per group of machines.
        """
        self._check_fitted()
        x = np.asarray(regressors, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self._w1t.shape[0]:
            raise DataError(
                f"regressors must have shape (batch, {self._w1t.shape[0]}). Got {x.shape}; "
                f"order them as {self.regressor_layout}."
            )
        xt = torch.from_numpy(np.ascontiguousarray(x))
        with torch.no_grad(), torch_one_thread():
            a = torch.sigmoid_(torch.addmm(self._b1, xt, self._w1t))
            out = torch.mv(a, self._w2).add_(self._b2)
        return out.numpy()

    def predict(self, u: np.ndarray, y: np.ndarray, steps_ahead: int | None = 1) -> np.ndarray:
        """Predictions of y over a record.

        Parameters
        ----------
        u : ndarray, shape (n,) or (n, n_inputs)
        y : ndarray, shape (n,)
            Measured output; in free run only its first ``delay`` samples are used (initial state).
        steps_ahead : int or None, default 1
            1: one step ahead, measured y in the delay line (series-parallel, Fig. 4.9);
            k > 1: k steps ahead, the last k−1 outputs in the line are the model's own;
            None: free run (parallel / closed loop, Fig. 4.10).

        Returns
        -------
        ndarray, shape (n,)
            In y's unit; NaN where the delay lines are not yet full (first ``delay`` samples,
            first ``delay + k − 1`` for k steps ahead).
        """
        self._check_fitted()
        if steps_ahead is not None and (isinstance(steps_ahead, bool) or not isinstance(steps_ahead, (int, np.integer))
                                        or steps_ahead < 1):
            raise ParameterError(f"steps_ahead must be an integer >= 1 or None. Got {steps_ahead!r}.")
        u_arr, y_arr = lines.check_signals(u, y, self.n_inputs_)
        raw = lines.regressors(u_arr, y_arr, self.input_delays, self.output_delays)
        out = np.full(y_arr.shape[0], np.nan)
        if steps_ahead is None:
            out[self.delay :] = self._free_run(raw, y_arr[: self.delay])
        else:
            out[self.delay :] = self._k_steps(raw, int(steps_ahead))
        return out

    def _k_steps(self, raw: np.ndarray, k: int) -> np.ndarray:
        """k-step predictions for every row at once: step s feeds back steps s−1, s−2, … ."""
        steps: list[np.ndarray] = []
        for s in range(1, k + 1):
            x = raw.copy()
            for lag in range(1, min(s - 1, self.output_delays) + 1):
                x[:lag, lag - 1] = np.nan
                x[lag:, lag - 1] = steps[s - lag - 1][:-lag]
            steps.append(self.one_step(x))
        return steps[-1]

    def _free_run(self, raw: np.ndarray, initial: np.ndarray) -> np.ndarray:
        """Closed-loop simulation: the output delay line holds the model's own predictions."""
        ny = self.output_delays
        w1t = self._w1t.numpy()
        drive = raw[:, ny:] @ w1t[ny:] + self._b1.numpy()  # input lines' share, known in advance
        w_y, w2 = w1t[:ny].T, self._w2.numpy()
        line = initial[::-1][:ny].copy()  # y(t-1), …, y(t-ny)
        out = np.empty(raw.shape[0])
        for i in range(raw.shape[0]):
            a = 1.0 / (1.0 + np.exp(-(drive[i] + w_y @ line)))
            out[i] = a @ w2 + self._b2
            if ny:
                line[1:] = line[:-1]
                line[0] = out[i]
        return out

    # -- validation ---------------------------------------------------------------------------
    def residual_correlations(self, u: np.ndarray, y: np.ndarray, max_lag: int = 20,
                              level: float = 0.95) -> dict[str, Any]:
        """Residual autocorrelation (Eq. 4.22) and input-residual cross-correlation (Eq. 4.23).

        Both are normalised (r(0) = 1; divided by the signals' standard deviations) and compared with
        the white-noise bound ±z/√N of :func:`hydrowatch.sysid.correlation.confidence_bound`.

        Returns
        -------
        dict
            ``acf`` (max_lag+1,) lags 0..max_lag; ``ccf`` (n_inputs, 2·max_lag+1) lags −max_lag..max_lag,
            r(k) = corr(u(t), ε(t+k)); ``bound``; ``acf_inside`` (share of lags 1..max_lag with
            |r| <= bound); ``ccf_inside`` (share of all ccf entries within the bound); ``n``.
        """
        u_arr, y_arr = lines.check_signals(u, y, getattr(self, "n_inputs_", None))
        eps = y_arr[self.delay :] - self.predict(u_arr, y_arr)[self.delay :]
        acf = autocorrelation(eps, max_lag)
        ccf = np.stack([cross_correlation(u_arr[self.delay :, i], eps, max_lag) for i in range(u_arr.shape[1])])
        bound = confidence_bound(eps.size, level)
        return {
            "acf": acf, "ccf": ccf, "bound": bound, "n": int(eps.size), "max_lag": int(max_lag),
            "acf_inside": float(np.mean(np.abs(acf[1:]) <= bound)) if max_lag else 1.0,
            "ccf_inside": float(np.mean(np.abs(ccf) <= bound)),
        }

    def summary(self) -> dict[str, Any]:
        """Network summary for reports and ``hydrowatch identify --json`` (JSON-serialisable)."""
        self._check_fitted()
        return {
            "input_delays": int(self.input_delays), "output_delays": int(self.output_delays),
            "hidden": int(self.hidden), "n_inputs": int(self.n_inputs_), "n_parameters": int(self.n_parameters_),
            "gamma": float(self.gamma_), "alpha": float(self.alpha_), "beta": float(self.beta_),
            "nrmse_one_step": float(self.train_summary_["nrmse_one_step"]),
            "iterations": int(self.train_summary_["iterations"]),
            "stop_reason": str(self.train_summary_["stop_reason"]),
            "n_samples": int(self.train_summary_["n_samples"]),
        }

    # -- persistence --------------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write weights and metadata as a plain dict with :func:`torch.save` (loads with weights_only)."""
        self._check_fitted()
        params = self.get_params()
        params["dtype"] = _dtype_name(self.dtype)
        torch.save({
            "format": FORMAT, "version": FORMAT_VERSION, "params": params,
            "weights": self.weights_.clone(), "alpha": self.alpha_, "beta": self.beta_, "gamma": self.gamma_,
            "n_inputs": int(self.n_inputs_),
            "input_mean": [float(v) for v in self.input_mean_], "input_scale": [float(v) for v in self.input_scale_],
            "output_mean": self.output_mean_, "output_scale": self.output_scale_,
            "train_summary": self.train_summary_, "history": self.history_,
        }, path)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> NARX:
        """Read a model written by :meth:`save`; ``residuals_`` are not stored."""
        try:
            blob = torch.load(path, weights_only=True)
        except (OSError, RuntimeError, EOFError, pickle.UnpicklingError) as exc:
            raise DataError(f"file must be a NARX model written by NARX.save. Got an unreadable file ({exc}).",
                            source=str(path)) from exc
        if not isinstance(blob, dict) or blob.get("format") != FORMAT:
            raise DataError(f"file must be a NARX model (format {FORMAT!r}). Got another file.", source=str(path))
        if blob.get("version") != FORMAT_VERSION:
            raise DataError(f"model version must be {FORMAT_VERSION}. Got {blob.get('version')!r}; refit the model.",
                            source=str(path))
        params = dict(blob["params"])
        params["dtype"] = _DTYPES[params["dtype"]]
        model = cls(**params)
        model.weights_ = blob["weights"]
        model.alpha_, model.beta_, model.gamma_ = blob["alpha"], blob["beta"], blob["gamma"]
        model.n_inputs_ = blob["n_inputs"]
        model.input_mean_ = np.asarray(blob["input_mean"])
        model.input_scale_ = np.asarray(blob["input_scale"])
        model.output_mean_, model.output_scale_ = blob["output_mean"], blob["output_scale"]
        model.n_parameters_ = n_parameters(model.output_delays + model.input_delays * model.n_inputs_, model.hidden)
        model.train_summary_, model.history_ = blob["train_summary"], blob["history"]
        model._fold()
        return model
