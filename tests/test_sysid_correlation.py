"""Sample correlations and the white-noise bound."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.sysid.correlation import autocorrelation, confidence_bound, cross_correlation


def test_autocorrelation_of_ar1_matches_theory() -> None:
    rng = np.random.default_rng(0)
    e = rng.standard_normal(20000)
    x = np.empty_like(e)
    x[0] = e[0]
    for t in range(1, e.size):
        x[t] = 0.7 * x[t - 1] + e[t]
    r = autocorrelation(x + 3.0, 3)
    assert r.shape == (4,)
    assert r[0] == pytest.approx(1.0)
    np.testing.assert_allclose(r[1:], [0.7, 0.49, 0.343], atol=0.03)


def test_autocorrelation_equals_direct_sum() -> None:
    rng = np.random.default_rng(1)
    x = rng.standard_normal(50)
    xc = x - x.mean()
    direct = np.array([np.sum(xc[: 50 - k] * xc[k:]) for k in range(6)]) / np.sum(xc * xc)
    np.testing.assert_allclose(autocorrelation(x, 5), direct, atol=1e-12)


def test_cross_correlation_peaks_at_the_delay() -> None:
    rng = np.random.default_rng(2)
    u = rng.standard_normal(5000)
    y = np.concatenate([np.zeros(3), 2.0 * u[:-3]])
    r = cross_correlation(u, y, 5)
    assert r.shape == (11,)
    assert int(np.argmax(r)) - 5 == 3
    assert r[5 + 3] == pytest.approx(1.0, abs=0.01)
    # r_xy(-k) = r_yx(k)
    np.testing.assert_allclose(cross_correlation(y, u, 5), r[::-1], atol=1e-12)


def test_white_noise_stays_inside_the_bound() -> None:
    rng = np.random.default_rng(3)
    n = 4000
    r = autocorrelation(rng.standard_normal(n), 40)[1:]
    bound = confidence_bound(n)
    assert bound == pytest.approx(1.959964 / np.sqrt(n), rel=1e-5)
    assert np.mean(np.abs(r) < bound) >= 0.85


def test_bad_input_is_refused() -> None:
    with pytest.raises(DataError, match="finite"):
        autocorrelation(np.array([1.0, np.nan, 2.0]), 1)
    with pytest.raises(DataError, match="same length"):
        cross_correlation(np.ones(5), np.arange(4.0), 1)
    with pytest.raises(ParameterError, match="max_lag"):
        autocorrelation(np.arange(5.0), 5)
    with pytest.raises(DataError, match="vary"):
        autocorrelation(np.ones(10), 2)
    with pytest.raises(ParameterError, match="level"):
        confidence_bound(100, 1.5)
