"""Generalized Partial Autocorrelation (GPAC) tables and the orders they suggest (study Sec. 3.2.1).

For a sequence R(m) that obeys R(m) + a1 R(m-1) + ... + a_n R(m-n) = 0 for every m > j0
(an autocorrelation of an ARMA(n, j0) process, or the impulse response of q^-K B/F with
n = nf and j0 = K + nb), Woodward and Gray's table

    phi(j, k) = det(N_jk) / det(D_jk),   D_jk[i, l] = R(j + i - l),  i, l = 0..k-1,
    N_jk = D_jk with its last column replaced by [R(j+1), ..., R(j+k)],

has a constant column k = n (value -a_n) from row j0 down, and zeros to its right on row j0.
The study reads (nb + K, nf) from the G-GPAC of the impulse response (Fig. 3.4) and (nc, nd)
from the H-GPAC of the disturbance's autocorrelation (Fig. 3.6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrowatch.errors import ParameterError

__all__ = ["GPACPattern", "gpac_table", "read_gpac"]


def gpac_table(sequence: np.ndarray, rows: int, columns: int, symmetric: bool) -> np.ndarray:
    """GPAC table phi(j, k) for j = 0..rows-1 (rows) and k = 1..columns (columns).

    Parameters
    ----------
    sequence : ndarray, shape (M,)
        R(0), R(1), ...; needs M >= rows + columns.
    rows, columns : int
        Table size.
    symmetric : bool
        True for an autocorrelation (R(-m) = R(m)); False for a causal impulse response
        (R(-m) = 0).

    Returns
    -------
    ndarray, shape (rows, columns)
        NaN where D_jk is singular.
    """
    r = np.asarray(sequence, dtype=float)
    if rows < 1 or columns < 1:
        raise ParameterError(f"rows and columns must be >= 1. Got {rows} and {columns}.")
    if r.size < rows + columns:
        raise ParameterError(
            f"sequence must have at least rows + columns = {rows + columns} values. Got {r.size}; "
            "estimate more lags or ask for a smaller table."
        )

    def value(m: int) -> float:
        if m >= 0:
            return float(r[m])
        return float(r[-m]) if symmetric else 0.0

    scale = np.max(np.abs(r)) or 1.0
    table = np.full((rows, columns), np.nan)
    for j in range(rows):
        for k in range(1, columns + 1):
            den = np.array([[value(j + i - l) for l in range(k)] for i in range(k)]) / scale
            num = den.copy()
            num[:, -1] = [value(j + i + 1) / scale for i in range(k)]
            d = np.linalg.det(den)
            if abs(d) > 1e-12:
                table[j, k - 1] = np.linalg.det(num) / d
    return table


@dataclass(frozen=True)
class GPACPattern:
    """Where a GPAC table shows its pattern: row j0, column n, and how clean it is.

    score : the larger of the constant column's relative spread and the row's relative size
    to the right (0 for an exact pattern; below ~0.2 reads as clear).
    """

    row: int
    column: int
    value: float
    score: float


def read_gpac(table: np.ndarray, min_row: int = 0, threshold: float = 0.2, depth: int = 2) -> GPACPattern:
    """The most parsimonious (row, column) where ``table`` shows a constant column with zeros right.

    A cell (j, k) qualifies when phi(j..j+depth, k) agree within ``threshold`` relative to
    phi(j, k), and |phi(j, k+1..k+depth)| <= ``threshold`` |phi(j, k)|. The first qualifying cell
    in order of increasing column + row (columns first) is returned; if none qualifies, the one
    with the lowest score.

    Parameters
    ----------
    table : ndarray, shape (rows, columns)
        From :func:`gpac_table` (column index 0 is k = 1).
    min_row : int
        Rows before this are not considered (e.g. the delay for a G-GPAC).
    """
    rows, columns = table.shape
    best: GPACPattern | None = None
    candidates = sorted(
        ((j, k) for j in range(min_row, rows) for k in range(1, columns + 1)), key=lambda jk: (jk[0] + jk[1], jk[1])
    )
    for j, k in candidates:
        const = table[j, k - 1]
        if not np.isfinite(const) or abs(const) < 1e-9:
            continue
        below = table[j + 1 : j + 1 + depth, k - 1]
        right = table[j, k : k + depth]
        spread = np.max(np.abs(below - const)) / abs(const) if below.size else 1.0
        size = np.max(np.abs(right)) / abs(const) if right.size else 1.0
        score = float(np.nan_to_num(max(spread, size), nan=np.inf))
        pattern = GPACPattern(j, k, float(const), score)
        if score <= threshold:
            return pattern
        if best is None or score < best.score:
            best = pattern
    if best is None:
        return GPACPattern(min_row, 1, float("nan"), float("inf"))
    return best
