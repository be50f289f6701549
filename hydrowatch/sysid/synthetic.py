"""Synthetic records from the study's final Box-Jenkins model (Eq. 3.24), for tests and benchmarks.

The record of issue 14: the input is 3 x (unit white noise through 0.1 / (1 - 0.9 q^-1)), a
low-pass filtered noise like the plant's excitation; the disturbance is unit-variance white
noise through C/D; the model runs ``run_in`` samples before the record starts, so the record
does not start from rest (as no real recording does).
"""

from __future__ import annotations

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.sysid.pem import STUDY_MODEL_3_24, simulate_box_jenkins
from hydrowatch.sysid.polynomials import filter_signal

__all__ = ["STUDY_ORDERS", "study_parameters", "study_record"]

STUDY_ORDERS: dict[str, int] = {"nb": 4, "nf": 4, "nc": 4, "nd": 5, "delay": 4}
"""Orders and delay of Eq. 3.24 (Table 3.11), as ``hydrowatch identify --orders 4,4,4,5 --delay 4``."""


def study_parameters() -> np.ndarray:
    """[b1..b4, f1..f4, c1..c4, d1..d5] of Eq. 3.24 (the order of Eq. 3.8); shape (17,)."""
    m = STUDY_MODEL_3_24
    return np.concatenate([m["b"], m["f"], m["c"], m["d"]]).astype(float)


def study_record(
    seed: int, n: int = 10_000, *, run_in: int = 500, input_gain: float = 3.0, noise_std: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Input u and output y of Eq. 3.24, ``n`` samples after ``run_in`` samples of run-in.

    Parameters
    ----------
    seed : int
        Seed of ``numpy.random.default_rng``; the input's white noise is drawn first, then e.
    n : int, default 10,000
        Samples returned.
    run_in : int, default 500
        Samples simulated and dropped before the record starts (>= 0).
    input_gain : float, default 3.0
        u = input_gain x 0.1 / (1 - 0.9 q^-1) of unit white noise [V].
    noise_std : float, default 1.0
        Standard deviation of the white noise e driving C/D (output units).

    Returns
    -------
    u, y : ndarray, shape (n,)
    """
    if run_in < 0 or n < 1:
        raise ParameterError(f"n must be >= 1 and run_in >= 0. Got n={n}, run_in={run_in}.")
    m = STUDY_MODEL_3_24
    rng = np.random.default_rng(seed)
    white = rng.standard_normal(n + run_in)
    e = noise_std * rng.standard_normal(n + run_in)
    u = input_gain * filter_signal([0.1], [1.0, -0.9], white)
    y = simulate_box_jenkins(m["b"], m["f"], m["c"], m["d"], int(m["delay"]), u, e)
    return u[run_in:], y[run_in:]
