"""The severity search of one valve-side hypothesis per window: coarse grid, local grid, past a flat stretch,
damped Gauss-Newton (compiled; the supply line's kernels are :mod:`hydrowatch.condition.supply`).

Each hypothesis of the valve relation has one severity per window (:mod:`hydrowatch.condition.parity`); its cost
Σ r² over the window's block residuals has kinks where the relief opens or closes and flat stretches where a relief
stays shut at every severity tried, so a derivative alone does not find its minimum (:func:`fit_windows`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hydrowatch.condition.supply import LINEAR, sweep


@njit(cache=True, error_model="numpy")
def _lowest(sse: np.ndarray, points: np.ndarray, k: int) -> int:
    """Index of the smallest of ``sse[:k]``; of equal ones, the point nearest severity 0 (nominal).

    Equal costs are a flat stretch that the window does not determine (a relief hypothesis whose relief stays shut
    there: every stronger spring gives the same flow). The first of them was the search range's end (−0.5 for a
    relief), where the local grid could not reach the valley just past the stretch's other end: on two tuning relief
    paths (seed 2054 units 5 and 7) 4.3 and 7.6 % of the windows' relief fits stayed at −0.5, 1.3–12× worse than
    the coil's in the windows looked at, and the pool blamed the relief's wear on the coil (docs/degradation.md).
    Of a stretch the data do not decide, nominal is the point to keep; :func:`_past_flat` then looks past its ends."""
    best = 0
    for j in range(1, k):
        if sse[j] < sse[best] or (sse[j] == sse[best] and abs(points[j]) < abs(points[best])):
            best = j
    return best


SECANT_DIVISIONS = 18.0
"""The curvature's secants step (hi − lo) / SECANT_DIVISIONS either side of the fit: the local step of the default
7-point grid, whatever the grid. With the refit's 19-point grid's own step (0.009 for a relief) the flat side of a
hockey stick read as a curvature 80× that of the same fit found by the first search, and on a tuning relief path
(seed 2054 unit 7) those windows outweighed the pool: false wear 0 → 8.6 % (docs/degradation.md)."""

FLAT_BATCHES = 3
"""Batches of ``grid`` points searched past each end of a flat stretch (:func:`fit_windows`, :func:`_past_flat`)."""


@njit(cache=True, error_model="numpy")
def _flat_ends(points: np.ndarray, sse: np.ndarray, cost: float) -> tuple[float, float]:
    """The ends (lowest, highest point) of the stretch of ``points`` whose cost equals ``cost`` (a flat stretch);
    NaN when fewer than two points have that cost."""
    left, right, flat = np.inf, -np.inf, 0
    for j in range(points.size):
        if sse[j] == cost:
            flat += 1
            left, right = min(left, points[j]), max(right, points[j])
    if flat < 2:
        return np.nan, np.nan
    return left, right


@njit(cache=True, error_model="numpy")
def _past_flat(code: int, end: float, width: float, cost: float, fine: np.ndarray, g: np.ndarray, pl: np.ndarray,
               q: np.ndarray, f: float, base: np.ndarray, block: int, r: np.ndarray, sse: np.ndarray,
               best: np.ndarray) -> tuple[float, float]:
    """Search (end, end + width] (``width`` < 0: leftwards) beyond one end of a flat stretch at ``cost`` on
    :data:`FLAT_BATCHES` × ``fine.size`` evenly spaced points. Returns the lowest point below ``cost`` and its cost
    (its residuals copied into ``best``), or (NaN, ``cost``) if none.

    Past the end the relief starts to crack within the window; the cost may first rise a little (the relief opens at
    the wrong moments) and then drop into a valley at the true severity about as wide as twice its distance from the
    end: 0.1 for a severity 0.05 past it (seed 2054 unit 2, a hold at 3.06 V), where a step of 0.08 from a point on
    the stretch missed it and the fit stayed at 417× the coil's MSE."""
    k = fine.size
    total = FLAT_BATCHES * k
    found, low = np.nan, cost
    for batch in range(FLAT_BATCHES):
        for j in range(k):
            fine[j] = end + width * (batch * k + j + 1) / total
        sweep(code, fine, g, pl, q, f, base, block, r, sse)
        top = _lowest(sse, fine, k)
        if sse[top] < low:
            found, low = fine[top], sse[top]
            best[:] = r[top]
    return found, low


@njit(cache=True, error_model="numpy")
def fit_windows(code: int, lo: float, hi: float, grid: int, iterations: int, flat_search: bool, g: np.ndarray,
                pl: np.ndarray, q: np.ndarray, f: np.ndarray, base: np.ndarray, block: int, s_out: np.ndarray,
                mse_out: np.ndarray, curvature_out: np.ndarray) -> None:
    """Severity of one valve-side hypothesis per window, clipped to [lo, hi], its mean squared residual and curvature.

    ``curvature_out`` receives the Gauss-Newton curvature Σ (∂r/∂s)² / nb, (L/min)², so that near
    the fit MSE(s) ≈ MSE(ŝ) + curvature·(s − ŝ)² (what pooling windows with one severity costs, and
    what holding a window's severity in a state's box costs). For nonlinear hypotheses it is at
    most the secant (MSE(ŝ ± h) − MSE(ŝ))/h² of either side, h the default grid's local step (hi − lo)/18: where
    the relief opens or closes the cost is a hockey stick, nearly flat on the side where the relief
    is open (the supply pressure, hence the valve flow, barely moves with a leak) and steep on the
    other, and the fit stops at the bend, where the local derivative reads the steep side. Extrapolated
    across the flat side it called a consistent pump leak inconsistent (development population,
    seed 7, unit 5, pump_leak_warning on cold oil: in low holds of the duty cycle the MSE varies by
    under 2× over severities 0.3–0.85 and the fits stop at 0.80–0.89 against 0.53–0.60 in other
    windows, one with the weight (curvature over MSE) 1373 of a well-determined window; the pooled
    open set read 25 of its 40 windows ``unknown``).

    Nonlinear hypotheses: a coarse grid of ``grid`` points over [lo, hi], a local grid around its
    best point (of equal costs, the one nearest 0: :func:`_lowest`; the cost has kinks where the relief opens or
    closes), past the ends of a flat stretch where there is one (:func:`_past_flat`), then up to ``iterations``
    damped Gauss-Newton steps with a forward-difference derivative, stopping at the first step
    that does not lower the cost (the next one would be the same step) or is below 10⁻⁶ of the
    range (converged). ``valve_leak``: exact
    least squares on its linear residual, clipped.
    """
    m, n = g.shape
    nb = (n - 1) // block
    r = np.empty((grid, nb))
    sse = np.empty(grid)
    best = np.empty(nb)
    span0 = (hi - lo) / (grid - 1)
    delta = 1e-4 * (hi - lo)
    coarse = np.empty(grid)
    for j in range(grid):
        coarse[j] = lo + span0 * j if j < grid - 1 else hi
    local = np.empty(grid - 2)
    coarse_sse, local_sse, fine, trial = np.empty(grid), np.empty(grid - 2), np.empty(grid), np.empty(nb)
    points, costs = np.empty(2 * grid - 2), np.empty(2 * grid - 2)
    step = (hi - lo) / SECANT_DIVISIONS  # the secants' step, whatever ``grid`` is
    pair = np.empty(2)
    for i in range(m):
        gi, pli, qi, fi = g[i], pl[i], q[i], f[i]
        if code == LINEAR:
            pair[0], pair[1] = 0.0, 1.0
            sweep(code, pair, gi, pli, qi, fi, base, block, r, sse)
            num, den = 0.0, 0.0
            for b in range(nb):
                slope = r[1, b] - r[0, b]
                num += slope * r[0, b]
                den += slope * slope
            s = min(max(-num / max(den, 1e-300), lo), hi)
            curvature_out[i] = den / nb
            pair[0] = s
            sweep(code, pair[:1], gi, pli, qi, fi, base, block, r, sse)
            s_out[i] = s
            mse_out[i] = sse[0] / nb
            continue
        sweep(code, coarse, gi, pli, qi, fi, base, block, r, sse)
        coarse_sse[:] = sse[:grid]
        top = _lowest(sse, coarse, grid)
        s, cost = coarse[top], sse[top]
        best[:] = r[top]
        for j in range(grid - 2):
            local[j] = min(max(s - span0 + 2.0 * span0 * (j + 1) / (grid - 1), lo), hi)
        sweep(code, local, gi, pli, qi, fi, base, block, r, sse)
        local_sse[:] = sse[:grid - 2]
        top = _lowest(sse, local, grid - 2)
        if sse[top] < cost:
            s, cost = local[top], sse[top]
            best[:] = r[top]
        # A flat stretch (equal costs: a relief shut throughout the window at every severity there) can end in a
        # valley narrower than the local step, within a coarse step past either end of the stretch.
        left, right = np.nan, np.nan
        if flat_search:
            points[:grid], points[grid:] = coarse, local
            costs[:grid], costs[grid:] = coarse_sse, local_sse
            left, right = _flat_ends(points, costs, cost)
        if not np.isnan(left):
            for end, width in ((right, min(span0, hi - right)), (left, max(-span0, lo - left))):
                if abs(width) > 0.0:
                    t, low = _past_flat(code, end, width, cost, fine, gi, pli, qi, fi, base, block, r, sse, trial)
                    if low < cost:
                        s, cost = t, low
                        best[:] = trial
        span = span0 / (grid - 1)
        pair[0] = s + delta  # the derivative point
        sweep(code, pair[:1], gi, pli, qi, fi, base, block, r, sse)
        for _ in range(iterations):
            num, den = 0.0, 0.0
            for b in range(nb):
                jac = (r[0, b] - best[b]) / delta
                num += jac * best[b]
                den += jac * jac
            t = min(max(s + min(max(-num / max(den, 1e-300), -span), span), lo), hi)
            if abs(t - s) < 0.01 * delta:  # converged: a step this small cannot change the cost measurably
                break
            pair[0], pair[1] = t, t + delta  # the trial, and its derivative point for the next step
            sweep(code, pair, gi, pli, qi, fi, base, block, r[1:], sse[1:])
            if not sse[1] < cost:
                break
            s, cost = t, sse[1]
            best[:] = r[1]
            r[0] = r[2]
        num = 0.0  # r[0] holds the residual at s + delta here (set before the loop and on every accepted step)
        for b in range(nb):
            jac = (r[0, b] - best[b]) / delta
            num += jac * jac
        # Secants one step either side (docstring: the cost's kinks).
        pair[0], pair[1] = max(s - step, lo), min(s + step, hi)
        sweep(code, pair, gi, pli, qi, fi, base, block, r, sse)
        for side in range(2):
            h = pair[side] - s
            if abs(h) > 0.5 * step:
                num = min(num, max(sse[side] - cost, 0.0) / (h * h))
        s_out[i] = s
        mse_out[i] = cost / nb
        curvature_out[i] = num / nb
