"""Cutting prediction errors into windows (study section 5.2.1: 1,000 samples = 5 s at 200 Hz).

Window ``k`` covers samples ``[k * hop, k * hop + window)``; only complete windows count. The
streaming counterpart is :mod:`hydrowatch.health.streaming`, which closes exactly the same windows.
"""

from __future__ import annotations

import numpy as np

from hydrowatch.errors import DataError, ParameterError

DEFAULT_WINDOW = 1000
"""Samples per window: 5 s at 200 Hz (study sections 5.2.1, 6.2)."""


def check_window(window: int, hop: int) -> None:
    """Raise ParameterError unless ``window >= 2`` and ``hop >= 1`` are integers."""
    if not isinstance(window, int | np.integer) or window < 2:
        raise ParameterError(f"window must be an integer >= 2 samples. Got {window!r}; the study uses 1000 (5 s).")
    if not isinstance(hop, int | np.integer) or hop < 1:
        raise ParameterError(f"hop must be an integer >= 1 sample. Got {hop!r}; use hop=window for no overlap.")


def n_windows(n_samples: int, window: int, hop: int) -> int:
    """Number of complete windows in ``n_samples`` samples."""
    check_window(window, hop)
    return 0 if n_samples < window else (n_samples - window) // hop + 1


def window_starts(n_samples: int, window: int, hop: int) -> np.ndarray:
    """First sample index of every complete window, shape (n_windows,)."""
    return np.arange(n_windows(n_samples, window, hop)) * hop


def sliding_windows(errors: np.ndarray, window: int, hop: int) -> np.ndarray:
    """Windows of a sensor's prediction errors, shape (n_windows, window), C-contiguous copy.

    Parameters
    ----------
    errors : ndarray, shape (n,)
        Prediction errors of one sensor (Eq. 5.1), sensor unit.
    """
    x = np.asarray(errors, dtype=np.float64)
    if x.ndim != 1:
        raise DataError(f"prediction errors of one sensor must be 1-D. Got shape {x.shape}.")
    count = n_windows(x.shape[0], window, hop)
    if count == 0:
        return np.empty((0, window))
    view = np.lib.stride_tricks.sliding_window_view(x, window)[::hop][:count]
    return np.ascontiguousarray(view)


def invalid_reasons(windows: np.ndarray) -> list[str | None]:
    """Why each window cannot be judged, or None where it can; ``windows`` shape (n_windows, window).

    A window is invalid when it holds NaN/inf prediction errors (a gap or a dropped sensor) or when
    its errors are constant (a stuck sensor: no distribution to compare).
    """
    bad = (~np.isfinite(windows)).sum(axis=1)
    flat = np.ptp(np.where(np.isfinite(windows), windows, 0.0), axis=1) == 0.0
    reasons: list[str | None] = []
    for nb, fl in zip(bad.tolist(), flat.tolist()):
        if nb:
            reasons.append(f"{nb} NaN/inf prediction errors in the window")
        elif fl:
            reasons.append("prediction error is constant in the window (stuck sensor?)")
        else:
            reasons.append(None)
    return reasons
