"""Which part of one component's index history a forecast rests on (issue 15; :mod:`hydrowatch.condition.forecast`,
steps 1 and 2): the windows' **operating time** (clock jumps and long stops count as one hop) and the **reset** that
starts the current trend (a part replaced reads near 0 again)."""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

RESET_BEFORE = 12
"""Windows (60 s) whose median is the level before a candidate reset: long enough that a burst of a few outlier
windows (a look-alike blamed for a moment) does not pass for a worn part that was replaced."""
RESET_SETTLED = 60
"""Windows (300 s; fewer at the ends of the history) on either side of a reset whose medians must also mark it
(:func:`_settled_drop`): a part replaced stays new, and a worn one was worn for longer than a minute. An index
that scatters with the command (pump_leak reading 0.5–0.7 through a minute of one phase of the duty cycle and
0.1–0.2 in the holds around it, for a true 0.16–0.3) passed the 60 s test after such bursts: on the tuning units
(seed 7) two of four pump_leak paths restarted their trend there, 17 minutes before the forecast of a 35-minute
history, and forecast the alert 32 % and 52 % off."""
RESET_AFTER = 24
"""Windows (120 s) whose median is the level after a candidate reset: a new part stays near 0, while an index that
drops out for a stretch of the duty cycle comes back (pump_leak read 0.08 for up to 75 s for a true 0.4 on a unit
of seed 2027; 6 windows, before 2026-11-26, restarted its trend 3 minutes before the forecast)."""
RESET_DROP = 0.25
"""Fall of the median index (a quarter of the alert) that marks a part replaced."""
RESET_NEAR_ZERO = 0.2
"""The median index after a reset must be below this (a new part reads near 0)."""


def operating_time(t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Operating time of consecutive windows, s, shape (n,): steps ≤ 0 or > ``max_gap_s`` count as one typical hop.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Window times in arrival order, s (may jump back or forward).
    max_gap_s : float
        Longest step counted as it is, s.
    """
    t = np.asarray(t, dtype=np.float64)
    if t.size < 2:
        return t - (t[0] if t.size else 0.0)
    dt = np.diff(t)
    ok = (dt > 0) & (dt <= max_gap_s)
    hop = float(np.median(dt[ok])) if ok.any() else 1.0
    return np.concatenate([[0.0], np.cumsum(np.where(ok, dt, hop))])


def reset_start(index: np.ndarray) -> int:
    """Position where the current trend starts: after the last reset (module docstring), else 0.

    Parameters
    ----------
    index : ndarray, shape (n,)
        Valid indices in time order.
    """
    v = np.asarray(index, dtype=np.float64)
    n, r, q = v.size, RESET_BEFORE, RESET_AFTER
    if n < r + q:
        return 0
    positions = np.arange(r, n - q + 1)
    before = np.median(sliding_window_view(v[:n - q], r), axis=1)  # v[i - r:i] for every position i
    after = np.median(sliding_window_view(v[r:], q), axis=1)  # v[i:i + q]
    found = np.flatnonzero((after < RESET_NEAR_ZERO) & (before - after >= RESET_DROP))
    found = np.array([k for k in found if _settled_drop(v, int(positions[k]))], dtype=np.int64)  # few: a loop
    if not found.size:
        return 0
    run = [found[-1]]  # the last run of candidate positions; the step is where the means differ most
    while run[-1] - 1 in found:
        run.append(run[-1] - 1)
    step = [np.mean(v[positions[k] - r:positions[k]]) - np.mean(v[positions[k]:positions[k] + q]) for k in run]
    return int(positions[run[int(np.argmax(step))]])


def _settled_drop(v: np.ndarray, i: int) -> bool:
    """Whether the medians of the :data:`RESET_SETTLED` windows on either side of position ``i`` (fewer at the ends
    of the history) also mark a reset: after below :data:`RESET_NEAR_ZERO`, before at least :data:`RESET_DROP`
    higher."""
    before, after = np.median(v[max(0, i - RESET_SETTLED):i]), np.median(v[i:i + RESET_SETTLED])
    return bool(after < RESET_NEAR_ZERO and before - after >= RESET_DROP)
