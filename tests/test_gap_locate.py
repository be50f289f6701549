"""Array-only parts of the gap analysis: fit measures, noise floor, regimes, whiteness, sparse correction."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.errors import NotFittedError
from hydrowatch.gap.correction import SparseCorrection, build_library, stlsq
from hydrowatch.gap.locate import (
    coherence_with_input,
    cross_correlation_peak,
    fit_percent,
    noise_std,
    nrmse,
    regimes,
    strongest_regime,
    whiteness,
)


@pytest.fixture
def operating_point() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A 30 s filtered-noise command and a plausible speed/torque response at 200 Hz."""
    rng = np.random.default_rng(0)
    n = 6000
    w = rng.standard_normal(n)
    u = np.empty(n)
    u[0] = 0.0
    for k in range(1, n):
        u[k] = 0.9 * u[k - 1] + 0.1 * w[k]
    u = np.clip(2.0 + 1.0 * u / u.std(), 0.0, 4.0)
    speed = 4.4 * u
    torque = 10.0 + 0.2 * speed
    t = np.arange(n) / 200.0
    return t, u, speed, torque


def test_nrmse_and_fit_percent_agree() -> None:
    y = np.sin(np.linspace(0, 20, 1000))
    yhat = 0.9 * y
    assert nrmse(y, yhat) == pytest.approx(0.1 / 1.0 * np.sqrt(np.mean(y**2)) / np.std(y), rel=1e-9)
    assert fit_percent(y, yhat) == pytest.approx(100 * (1 - nrmse(y, yhat)))
    mask = np.arange(1000) < 500
    assert nrmse(y, yhat, mask) != nrmse(y, yhat)


def test_noise_std_recovers_white_noise_under_a_slow_error(operating_point) -> None:
    t, u, speed, _ = operating_point
    rng = np.random.default_rng(1)
    residual = 0.3 * np.sin(2 * np.pi * 0.5 * t) + 0.05 * rng.standard_normal(t.size)
    assert noise_std(residual) == pytest.approx(0.05, rel=0.1)


def test_regimes_find_low_speed_error(operating_point) -> None:
    t, u, speed, torque = operating_point
    rng = np.random.default_rng(2)
    residual = 0.5 * np.exp(-((speed / 2.0) ** 2)) + 0.01 * rng.standard_normal(t.size)
    found = regimes(residual, u, speed, torque, 0.01**2)
    best = strongest_regime(found)
    assert best.family in ("speed", "command", "torque")
    assert best.share > 0.6
    assert best.label.startswith(best.family)
    speed_bins = [r for r in found if r.family == "speed"]
    assert speed_bins[0].rms > 5 * speed_bins[-1].rms


def test_drift_shows_in_time_and_lowest_band(operating_point) -> None:
    t, u, speed, torque = operating_point
    residual = 0.02 * t
    found = regimes(residual, u, speed, torque, 1e-8)
    band = next(r for r in found if r.family == "frequency")
    assert band.share > 0.9
    last = [r for r in found if r.family == "time"][-1]
    assert last.share > 0.5


def test_whiteness_and_input_dependence(operating_point) -> None:
    t, u, _, _ = operating_point
    rng = np.random.default_rng(3)
    white = rng.standard_normal(t.size)
    assert whiteness(white) < 2.0
    lagged = np.concatenate([np.zeros(6), u[:-6]]) - u.mean() + 0.1 * white
    assert whiteness(lagged) > 50.0
    lag, value = cross_correlation_peak(lagged, u)
    assert lag == 6 and value > 0.9
    assert coherence_with_input(lagged, u) > 0.8
    assert coherence_with_input(white, u) < 0.1


def test_stlsq_keeps_only_the_true_terms() -> None:
    rng = np.random.default_rng(4)
    theta = rng.standard_normal((2000, 6))
    y = 2.0 * theta[:, 1] - 0.5 * theta[:, 4] + 0.01 * rng.standard_normal(2000)
    coef = stlsq(theta, y, threshold=0.05)
    assert np.flatnonzero(coef).tolist() == [1, 4]
    assert coef[1] == pytest.approx(2.0, abs=0.01)


def test_sparse_correction_explains_quadratic_torque(operating_point) -> None:
    t, u, speed, torque = operating_point
    simulated = np.vstack([u * 2.0, speed, torque])
    library = build_library(u, simulated, t, pump_speed=183.26)
    rng = np.random.default_rng(5)
    residual = 0.02 * speed * np.abs(speed) + 0.15 * rng.standard_normal(t.size)
    fit_mask = (np.arange(t.size) // 600) % 3 != 1
    corr = SparseCorrection().fit(library, residual, fit_mask, ~fit_mask)
    assert "ω·|ω|" in corr.terms_
    assert corr.holdout_gain_ > 0.5
    assert corr.predict(library).shape == t.shape


def test_sparse_correction_before_fit_fails() -> None:
    with pytest.raises(NotFittedError, match="fitted before predict"):
        SparseCorrection().predict(build_library(np.ones(10), np.ones((3, 10)), np.arange(10.0), pump_speed=1.0))
