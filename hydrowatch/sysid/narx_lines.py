"""Tapped delay lines of the NARX model: input checks, regressor matrices, z-score normalisation.

Regressor layout (study Eq. 4.18, most recent first): to predict y(t) the network sees

    [y(t-1), …, y(t-n_y), u₁(t-1), …, u₁(t-n_u), u₂(t-1), …, u₂(t-n_u), …]

i.e. the output delay line, then each input channel's delay line (delays 1..n, as MATLAB's
``narxnet(1:n_u, 1:n_y)``). The first ``max(n_u, n_y)`` samples only fill the delay lines.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from hydrowatch.errors import DataError

__all__ = ["check_signals", "layout_names", "lagged", "linear_one_step", "regressors", "zscore"]


def _check_finite(arr: np.ndarray, name: str) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        rows = np.flatnonzero(bad.reshape(arr.shape[0], -1).any(axis=1))
        raise DataError(
            f"{name} must be finite. Got {rows.size} NaN/inf samples, first at index {int(rows[0])}; "
            "drop or interpolate them before identification."
        )


def check_signals(u: np.ndarray, y: np.ndarray, n_inputs: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Validate an input/output record; returns u as float (n, n_inputs) and y as float (n,).

    Parameters
    ----------
    u : array_like, shape (n,) or (n, n_inputs)
        Input signal(s), e.g. the valve command [V].
    y : array_like, shape (n,)
        Measured output, e.g. gearbox speed [rad/s].
    n_inputs : int, optional
        Number of input channels the model was fitted with (checked when given).
    """
    u_arr = np.asarray(u, dtype=float)
    y_arr = np.asarray(y, dtype=float)
    if u_arr.ndim == 1:
        u_arr = u_arr[:, None]
    if u_arr.ndim != 2:
        raise DataError(f"u must have shape (n,) or (n, n_inputs). Got shape {u_arr.shape}; pass one column per input.")
    if y_arr.ndim == 2 and y_arr.shape[1] == 1:
        y_arr = y_arr[:, 0]
    if y_arr.ndim != 1:
        raise DataError(f"y must have shape (n,), one output. Got shape {y_arr.shape}; fit one model per sensor.")
    if u_arr.shape[0] != y_arr.shape[0]:
        raise DataError(
            f"u and y must have the same number of samples. Got {u_arr.shape[0]} and {y_arr.shape[0]}; "
            "align the input and output records."
        )
    if n_inputs is not None and u_arr.shape[1] != n_inputs:
        raise DataError(f"u must have {n_inputs} input column(s) like the fitted model. Got {u_arr.shape[1]}.")
    _check_finite(u_arr, "u")
    _check_finite(y_arr, "y")
    return u_arr, y_arr


def lagged(x: np.ndarray, delays: int, start: int) -> np.ndarray:
    """Delay line of one signal: row i = [x(t-1), …, x(t-delays)] for t = start + i; shape (n-start, delays)."""
    if delays == 0:
        return np.empty((x.shape[0] - start, 0))
    window = sliding_window_view(x[start - delays : x.shape[0] - 1], delays)
    return np.ascontiguousarray(window[:, ::-1])


def regressors(u: np.ndarray, y: np.ndarray, input_delays: int, output_delays: int) -> np.ndarray:
    """Raw regressor matrix in the module's layout, shape (n - d, output_delays + input_delays·n_inputs).

    Row i predicts y(d + i), d = max(input_delays, output_delays). ``u`` is (n, n_inputs), ``y`` (n,).
    """
    start = max(input_delays, output_delays)
    if y.shape[0] <= start:
        raise DataError(
            f"u and y must have more than {start} samples to fill the delay lines "
            f"({input_delays} input, {output_delays} output delays). Got {y.shape[0]}; "
            "pass a longer record or shorten the delay lines."
        )
    blocks = [lagged(y, output_delays, start)]
    blocks += [lagged(u[:, i], input_delays, start) for i in range(u.shape[1])]
    return np.concatenate(blocks, axis=1)


def layout_names(input_delays: int, output_delays: int, n_inputs: int) -> list[str]:
    """Names of the regressor columns, e.g. ``['y(t-1)', …, 'u1(t-1)', …]``."""
    names = [f"y(t-{k})" for k in range(1, output_delays + 1)]
    for i in range(n_inputs):
        names += [f"u{i + 1}(t-{k})" for k in range(1, input_delays + 1)]
    return names


def zscore(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-column mean and scale (standard deviation, 1 where a column is constant) of x (n, k)."""
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    return mean, np.where(scale > 0.0, scale, 1.0)


def linear_one_step(u_fit: np.ndarray, y_fit: np.ndarray, u: np.ndarray, y: np.ndarray, input_delays: int,
                    output_delays: int) -> np.ndarray:
    """Linear ARX baseline (Eq. 4.15) on the same delay lines: least squares on one record, one-step
    predictions of another.

    Parameters
    ----------
    u_fit, y_fit : ndarray, shape (n_fit,) or (n_fit, n_inputs) and (n_fit,)
        Record the coefficients are fitted on.
    u, y : ndarray, shape (n,) or (n, n_inputs) and (n,)
        Record to predict.
    input_delays, output_delays : int

    Returns
    -------
    ndarray, shape (n,)
        One-step predictions in y's unit, NaN for the first max(input_delays, output_delays) samples.
    """
    u_fit, y_fit = check_signals(u_fit, y_fit)
    u, y = check_signals(u, y, u_fit.shape[1])
    start = max(input_delays, output_delays)
    design = regressors(u_fit, y_fit, input_delays, output_delays)
    coef = np.linalg.lstsq(np.column_stack([design, np.ones(design.shape[0])]), y_fit[start:], rcond=None)[0]
    out = np.full(y.shape[0], np.nan)
    out[start:] = regressors(u, y, input_delays, output_delays) @ coef[:-1] + coef[-1]
    return out
