"""Polynomials in the delay operator q^-1 and the filters built from them (study Eq. 3.1).

Conventions used throughout :mod:`hydrowatch.sysid`:

- A *monic* polynomial F(q) = 1 + f1 q^-1 + ... + f_nf q^-nf is stored as its tail
  ``f = [f1, ..., f_nf]`` (shape ``(nf,)``); :func:`monic` gives the full ``[1, f1, ...]``.
- The numerator B(q) = b1 q^-1 + ... + b_nb q^-nb (no b0, Eq. 3.1) is stored as
  ``b = [b1, ..., b_nb]``; with a dead time of K samples the full numerator of q^-K B(q) is
  ``[0]*(K+1) + [b1, ..., b_nb]`` (:func:`delayed_numerator`).
- Filtering starts from rest (zero initial conditions), as :func:`scipy.signal.lfilter` does.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import lfilter, lfilter_zi

__all__ = [
    "cancellations",
    "delayed_numerator",
    "filter_signal",
    "filter_settling",
    "impulse_response",
    "is_stable",
    "monic",
    "numerator_zeros",
    "polynomial_roots",
    "reflect_into_unit_circle",
]


def monic(tail: ArrayLike) -> np.ndarray:
    """Full coefficients ``[1, a1, ..., an]`` of a monic polynomial from its tail; shape (n+1,)."""
    return np.concatenate([[1.0], np.asarray(tail, dtype=float)])


def delayed_numerator(b: ArrayLike, delay: int) -> np.ndarray:
    """Coefficients of q^-K B(q) with B(q) = b1 q^-1 + ... (Eq. 3.1); shape (K + 1 + nb,)."""
    return np.concatenate([np.zeros(delay + 1), np.asarray(b, dtype=float)])


def filter_signal(numerator: ArrayLike, denominator: ArrayLike, x: ArrayLike) -> np.ndarray:
    """x filtered by numerator(q)/denominator(q) from rest; ``denominator[0]`` must be non-zero.

    Parameters
    ----------
    numerator, denominator : ndarray
        Coefficients of increasing powers of q^-1.
    x : ndarray, shape (N,)

    Returns
    -------
    ndarray, shape (N,)
    """
    return np.asarray(lfilter(numerator, denominator, x))


SETTLED = 1e-14
"""Relative size (to the output's peak) below which :func:`filter_settling` takes a response as settled."""


def filter_settling(numerator: ArrayLike, denominator: ArrayLike, head: ArrayLike, n: int, level: float = 0.0,
                    block: int = 1024) -> np.ndarray:
    """The filter from rest on ``head`` followed by ``level`` up to n samples, filtered only until it settles.

    A pulse response (level 0) or a step response (level 1) of a stable filter reaches its final value
    ``level * numerator(1) / denominator(1)`` geometrically; filtering all n samples costs as much as filtering a
    measured signal. The input after ``head`` is filtered a block at a time, continuing the filter's state, until a
    block and the state are within :data:`SETTLED` of the peak from their steady values; the rest is the final
    value. Equal to :func:`filter_signal` of the whole input to 1e-14 of the peak; an unstable or slow filter is
    filtered to the end.

    Returns
    -------
    ndarray, shape (n,)
    """
    b, a = np.asarray(numerator, dtype=float), np.asarray(denominator, dtype=float)
    x = np.asarray(head, dtype=float)[:n]
    out = np.empty(n)
    order = max(a.size, b.size) - 1
    state = np.zeros(order)
    if level and not abs(float(np.sum(a))) > 1e-12 * float(np.sum(np.abs(a))):  # a pole at 1: no final value
        return filter_signal(b, a, np.concatenate([x, np.full(n - x.size, float(level))]))
    if x.size:
        out[: x.size], state = lfilter(b, a, x, zi=state) if order else (lfilter(b, a, x), state)
    final = level * float(np.sum(b) / np.sum(a)) if level else 0.0
    steady_state = level * lfilter_zi(b, a) if level and order else np.zeros(order)
    peak = float(np.max(np.abs(out[: x.size]), initial=abs(final)))
    done = x.size
    while done < n:
        start, done = done, min(n, done + block)
        piece = np.full(done - start, float(level))
        if order:
            out[start:done], state = lfilter(b, a, piece, zi=state)
        else:
            out[start:done] = lfilter(b, a, piece)
        peak = max(peak, float(np.max(np.abs(out[start:done]))))
        limit = SETTLED * max(peak, np.finfo(float).tiny)
        if np.max(np.abs(out[start:done] - final)) <= limit and \
                np.max(np.abs(state - steady_state), initial=0.0) <= limit:
            out[done:] = final
            break
    return out


def impulse_response(numerator: ArrayLike, denominator: ArrayLike, length: int) -> np.ndarray:
    """First ``length`` samples h(0), h(1), ... of the impulse response of numerator/denominator."""
    pulse = np.zeros(length)
    pulse[0] = 1.0
    return filter_signal(numerator, denominator, pulse)


def polynomial_roots(full: np.ndarray) -> np.ndarray:
    """Roots in the z-plane of a polynomial in q^-1 given by ``full = [a0, a1, ..., an]``.

    a0 + a1 z^-1 + ... + an z^-n = z^-n (a0 z^n + ... + an), so the roots are those of the
    ordinary polynomial with the same coefficient order. Trailing zeros (roots at the origin of
    z^-n) are kept out; leading zeros (pure delays) are dropped.
    """
    coeffs = np.trim_zeros(np.asarray(full, dtype=float), "f")
    coeffs = np.trim_zeros(coeffs, "b")
    if coeffs.size <= 1:
        return np.zeros(0, dtype=complex)
    return np.asarray(np.roots(coeffs), dtype=complex)


def numerator_zeros(b: np.ndarray) -> np.ndarray:
    """Finite non-zero zeros of B(q) = b1 q^-1 + ... + b_nb q^-nb; at most nb - 1 of them."""
    return polynomial_roots(np.asarray(b, dtype=float))


def is_stable(tail: np.ndarray, margin: float = 0.0) -> bool:
    """True when every root of the monic polynomial 1 + a1 q^-1 + ... lies strictly inside |z| < 1 - margin."""
    roots = polynomial_roots(monic(tail))
    return bool(roots.size == 0 or np.max(np.abs(roots)) < 1.0 - margin)


def reflect_into_unit_circle(tail: np.ndarray) -> np.ndarray:
    """Tail of the monic polynomial whose roots outside the unit circle are reflected to 1/conj(z).

    Reflection keeps the spectrum's shape (up to a gain) and makes a predictor filter stable;
    used to start the prediction-error iterations from a stable point.
    """
    tail = np.asarray(tail, dtype=float)
    roots = polynomial_roots(monic(tail))
    if roots.size == 0 or np.max(np.abs(roots)) < 1.0:
        return tail.copy()
    outside = np.abs(roots) >= 1.0
    roots[outside] = 1.0 / np.conj(roots[outside])
    roots = np.where(np.abs(roots) > 0.99, roots * (0.99 / np.abs(roots)), roots)
    full = np.real(np.poly(roots))
    return np.asarray(full[1:], dtype=float)


def cancellations(zeros: np.ndarray, poles: np.ndarray, tolerance: float) -> list[tuple[complex, complex]]:
    """Pairs (zero, pole) closer than ``tolerance`` in the z-plane (pole-zero cancellation, Sec. 3.2.3).

    Each pole is matched to at most one zero, nearest pairs first.

    Parameters
    ----------
    zeros, poles : ndarray of complex
    tolerance : float
        Largest distance |z - p| that counts as a cancellation (dimensionless).
    """
    pairs: list[tuple[complex, complex]] = []
    if zeros.size == 0 or poles.size == 0:
        return pairs
    distance = np.abs(zeros[:, None] - poles[None, :])
    used_z: set[int] = set()
    used_p: set[int] = set()
    for flat in np.argsort(distance, axis=None):
        i, j = np.unravel_index(flat, distance.shape)
        if distance[i, j] >= tolerance:
            break
        if i in used_z or j in used_p:
            continue
        used_z.add(int(i))
        used_p.add(int(j))
        pairs.append((complex(zeros[i]), complex(poles[j])))
    return pairs
