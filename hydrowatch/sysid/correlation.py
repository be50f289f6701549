"""Sample correlations of signals and the large-sample bound of a white sequence's correlations.

Used by the preliminary identification (study Eqs. 3.2-3.6), the residual tests of the
Box-Jenkins validation (Eqs. 3.17, 3.18) and the NARX residual checks (Eqs. 4.22, 4.23).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from hydrowatch.errors import DataError, ParameterError

__all__ = ["autocorrelation", "confidence_bound", "cross_correlation", "cross_covariance"]


def _as_signal(x: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim != 1:
        raise DataError(f"{name} must be a 1-D signal. Got shape {arr.shape}; pass one column.")
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise DataError(f"{name} must be finite. Got {bad} NaN/inf samples; drop or interpolate them.")
    return arr


def _check_lag(max_lag: int, n: int) -> None:
    if not isinstance(max_lag, (int, np.integer)) or max_lag < 0 or max_lag >= n:
        raise ParameterError(f"max_lag must be an integer in [0, {n - 1}]. Got {max_lag!r}; use fewer lags.")


def cross_covariance(x: np.ndarray, y: np.ndarray, max_lag: int) -> np.ndarray:
    """Biased sample cross-covariance c_xy(k) = 1/N sum_t x~(t) y~(t+k), k = 0..max_lag.

    Means are removed (x~ = x - mean x). Uses an FFT, O(N log N).

    Parameters
    ----------
    x, y : ndarray, shape (N,)
    max_lag : int
        Largest lag k >= 0, < N.

    Returns
    -------
    ndarray, shape (max_lag + 1,)
        In the product of the units of x and y.
    """
    x = _as_signal(x, "x")
    y = _as_signal(y, "y")
    if x.shape != y.shape:
        raise DataError(f"x and y must have the same length. Got {x.size} and {y.size}; align them.")
    n = x.size
    _check_lag(max_lag, n)
    xc = x - x.mean()
    yc = y - y.mean()
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    spec = np.conj(np.fft.rfft(xc, nfft)) * np.fft.rfft(yc, nfft)
    full = np.fft.irfft(spec, nfft)
    return np.asarray(full[: max_lag + 1] / n)


def autocorrelation(x: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised sample autocorrelation r(k), k = 0..max_lag (r(0) = 1), mean removed.

    r(k) = c_xx(k) / c_xx(0) with the biased covariance c_xx(k) = 1/N sum x~(t) x~(t+k).

    Parameters
    ----------
    x : ndarray, shape (N,)
    max_lag : int
        Largest lag, 0 <= max_lag < N.

    Returns
    -------
    ndarray, shape (max_lag + 1,)
        Dimensionless; r[0] = 1 (a constant signal raises DataError).
    """
    c = cross_covariance(x, x, max_lag)
    if c[0] <= 0.0:
        raise DataError("x must vary. Got a constant signal; its autocorrelation is undefined.")
    return np.asarray(c / c[0])


def cross_correlation(x: np.ndarray, y: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised r_xy(k) = corr(x(t), y(t+k)) for k = -max_lag..max_lag; shape (2*max_lag+1,).

    r_xy(k) = c_xy(k) / sqrt(c_xx(0) c_yy(0)) with biased covariances, means removed. Index
    ``max_lag`` of the result is lag 0; positive lags mean y lags behind x.

    Parameters
    ----------
    x, y : ndarray, shape (N,)
    max_lag : int
        Largest |k|, 0 <= max_lag < N.

    Returns
    -------
    ndarray, shape (2 * max_lag + 1,)
        Dimensionless, in [-1, 1].
    """
    x = _as_signal(x, "x")
    y = _as_signal(y, "y")
    positive = cross_covariance(x, y, max_lag)
    negative = cross_covariance(y, x, max_lag)  # c_xy(-k) = c_yx(k)
    scale = np.sqrt(np.var(x) * np.var(y))
    if scale <= 0.0:
        raise DataError("x and y must both vary. Got a constant signal; its correlation is undefined.")
    return np.concatenate([negative[:0:-1], positive]) / scale


def confidence_bound(n: int, level: float = 0.95) -> float:
    """Large-sample bound z_{(1+level)/2}/sqrt(n) for a white sequence's correlations.

    A white sequence of n samples has sample correlations at lags k != 0 approximately normal
    with mean 0 and variance 1/n; about ``level`` of them fall within +/- this bound.

    Parameters
    ----------
    n : int
        Number of samples, > 0.
    level : float
        Confidence level in (0, 1); default 0.95 gives 1.96/sqrt(n).
    """
    if n <= 0:
        raise ParameterError(f"n must be a positive number of samples. Got {n!r}.")
    if not 0.0 < level < 1.0:
        raise ParameterError(f"level must be in (0, 1). Got {level!r}; use e.g. 0.95.")
    return float(stats.norm.ppf(0.5 * (1.0 + level)) / np.sqrt(n))
