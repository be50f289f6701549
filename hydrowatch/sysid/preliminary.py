"""Preliminary identification (study Sec. 3.2.1, 3.4.1): impulse response, disturbance, GPAC orders.

Steps, on the mean-removed signals of Eqs. 3.19, 3.20:

1. impulse response g = R_u^-1 r_uy from correlations (Eqs. 3.2-3.4), with standard errors;
   the delay K is one less than the first lag where g is significant (B starts at q^-1);
2. disturbance v = y - sum_k g(k) u(t-k) (Eq. 3.5) and its autocorrelation (Eq. 3.6);
3. G-GPAC of g gives (K + nb, nf); H-GPAC of the autocorrelation of v gives (nc, nd);
4. frequency response from the cross and input power spectra (Eq. 3.7).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import solve_toeplitz, toeplitz
from scipy.signal import csd, welch

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.sysid.boxjenkins import check_signals
from hydrowatch.sysid.correlation import autocorrelation, cross_covariance
from hydrowatch.sysid.gpac import gpac_table, read_gpac
from hydrowatch.sysid.polynomials import filter_signal

__all__ = [
    "PreliminaryIdentification",
    "disturbance_estimate",
    "frequency_response",
    "impulse_response_estimate",
    "preliminary_identification",
]


def impulse_response_estimate(u: np.ndarray, y: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
    """g(0..length) = R_u^-1 r_uy (Eqs. 3.3, 3.4) and its large-sample standard errors.

    R_u is the Toeplitz matrix of the input's autocovariances, r_uy(k) = cov(u(t), y(t+k)).
    The standard errors account for a coloured disturbance: with v = y - g * u,
    cov(g) = R_u^-1 M R_u^-1 / N, M[k, l] = sum_tau R_v(tau) R_u(tau + k - l) (Bartlett).

    Returns
    -------
    g, se : ndarray, shape (length + 1,)
        In output units per input unit.
    """
    n = u.size
    if not 1 <= length < n // 4:
        raise ParameterError(f"length must be in [1, {n // 4 - 1}] for {n} samples. Got {length}; use fewer lags.")
    r_u = cross_covariance(u, u, length)
    if r_u[0] <= 0:
        raise DataError("input u must vary. Got a constant input; excite the system.")
    g = solve_toeplitz(r_u, cross_covariance(u, y, length))
    v = disturbance_estimate(u, y, g)
    span = min(4 * length, n // 2 - 1)
    ru_long = cross_covariance(u, u, span)
    rv_long = cross_covariance(v, v, span)
    ru_full = np.concatenate([ru_long[:0:-1], ru_long])
    rv_full = np.concatenate([rv_long[:0:-1], rv_long])
    m = np.convolve(rv_full, ru_full[::-1])  # m(s) = sum_tau R_v(tau) R_u(tau + s), centre at s = 0
    centre = m.size // 2
    middle = toeplitz(m[centre : centre + length + 1])
    inverse = np.linalg.inv(toeplitz(r_u))
    cov = inverse @ middle @ inverse / n
    return np.asarray(g), np.sqrt(np.clip(np.diag(cov), 0.0, np.inf))


def disturbance_estimate(u: np.ndarray, y: np.ndarray, g: np.ndarray) -> np.ndarray:
    """v(t) = y(t) - sum_k g(k) u(t-k) (Eq. 3.5), signals mean-removed; shape (N,)."""
    return np.asarray((y - y.mean()) - filter_signal(g, [1.0], u - u.mean()))


def frequency_response(
    u: np.ndarray, y: np.ndarray, sample_rate: float = 1.0, segment: int = 256
) -> tuple[np.ndarray, np.ndarray]:
    """H(f) = Phi_uy(f) / Phi_u(f) (Eq. 3.7), Welch-averaged over Hann segments of ``segment`` samples.

    Returns
    -------
    frequency : ndarray, shape (segment // 2 + 1,)
        [Hz] when ``sample_rate`` is in Hz.
    response : ndarray of complex, same shape
        Output units per input unit.
    """
    segment = int(min(segment, u.size))
    f, p_uy = csd(u, y, fs=sample_rate, nperseg=segment)
    _, p_u = welch(u, fs=sample_rate, nperseg=segment)
    return np.asarray(f), np.asarray(p_uy / np.where(p_u > 0, p_u, np.inf))


@dataclass
class PreliminaryIdentification:
    """Results of :func:`preliminary_identification`; ``to_dict`` for JSON."""

    impulse_response: np.ndarray
    impulse_se: np.ndarray
    delay: int
    disturbance_acf: np.ndarray
    gpac_g: np.ndarray
    gpac_h: np.ndarray
    orders: dict[str, int]
    clarity: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        def rows(table: np.ndarray) -> list[list[float | None]]:
            return [[float(x) if np.isfinite(x) else None for x in row] for row in table]

        return {
            "orders": dict(self.orders),
            "delay": int(self.delay),
            "gpac_score": dict(self.clarity),
            "impulse_response": self.impulse_response.tolist(),
            "impulse_se": self.impulse_se.tolist(),
            "disturbance_acf": self.disturbance_acf.tolist(),
            "gpac_g": rows(self.gpac_g),
            "gpac_h": rows(self.gpac_h),
        }


def preliminary_identification(
    u: np.ndarray, y: np.ndarray, length: int = 50, gpac_rows: int = 12, gpac_columns: int = 7, z: float = 4.0
) -> PreliminaryIdentification:
    """Suggested orders (nb, nf, nc, nd) and delay K from the study's preliminary identification.

    Parameters
    ----------
    u, y : ndarray, shape (N,)
        Input and output.
    length : int
        Lags of the impulse response estimate (Eq. 3.3).
    gpac_rows, gpac_columns : int
        GPAC table sizes; the G-GPAC gets ``delay`` more rows.
    z : float
        |g(k)| / se(k) above which an impulse-response sample is significant (delay detection).
    """
    u, y = check_signals(u, y, 2 * length, 8 * length, 1)
    uc, yc = u - u.mean(), y - y.mean()
    g, se = impulse_response_estimate(uc, yc, length)
    significant = np.flatnonzero(np.abs(g) > z * se)
    if significant.size == 0:
        raise DataError(
            f"the output must respond to the input. Got no impulse-response lag above {z} standard errors "
            f"within {length} lags; check the columns or lengthen the record."
        )
    delay = max(int(significant[0]) - 1, 0)
    g_table = gpac_table(g, delay + gpac_rows, gpac_columns, symmetric=False)
    g_read = read_gpac(g_table, min_row=delay + 1)
    v = disturbance_estimate(uc, yc, g)
    acf = autocorrelation(v, gpac_rows + gpac_columns + 1)
    h_table = gpac_table(acf, gpac_rows, gpac_columns, symmetric=True)
    h_read = read_gpac(h_table)
    orders = {"nb": max(g_read.row - delay, 1), "nf": g_read.column, "nc": h_read.row, "nd": h_read.column}
    return PreliminaryIdentification(
        g, se, delay, acf, g_table, h_table, orders, {"G": g_read.score, "H": h_read.score}
    )
