import numpy as np
import pytest
from scipy.integrate import quad
from scipy.stats import norm

from hydrowatch.errors import DataError, NotFittedError
from hydrowatch.health.distributions import GaussianBase, Mixture, MixtureBase, fit_gaussian, fit_mixture
from hydrowatch.health.entropy import (
    gaussian_relative_entropy,
    mixture_relative_entropy,
    monte_carlo_relative_entropy,
    quadrature_rule,
)
from hydrowatch.health.features import RelativeEntropyFeatures, log_features
from hydrowatch.health.synthetic import STUDY_STATES, synthetic_errors


@pytest.mark.parametrize("m1,s1,m2,s2", [(0.0, 1.0, 0.5, 1.3), (2.0, 0.3, -1.0, 2.0), (0.01, 0.02, 0.0, 0.015)])
def test_eq_5_3_matches_numerical_integration_of_eq_5_2(m1, s1, m2, s2):
    closed = float(gaussian_relative_entropy(m1, s1, m2, s2))
    integrand = lambda x: norm.pdf(x, m1, s1) * (norm.logpdf(x, m1, s1) - norm.logpdf(x, m2, s2))  # noqa: E731
    numeric, _ = quad(integrand, m1 - 12 * s1, m1 + 12 * s1, limit=200)
    assert closed == pytest.approx(numeric, rel=1e-7, abs=1e-12)
    # direction: base (1) first, window (2) second; the divergence is not symmetric
    assert closed != pytest.approx(float(gaussian_relative_entropy(m2, s2, m1, s1)), rel=1e-3)


def test_gaussian_entropy_is_zero_for_the_same_distribution_and_vectorised():
    d = gaussian_relative_entropy(np.array([0.0, 1.0])[None, :], np.array([1.0, 2.0])[None, :],
                                  np.array([[0.0], [1.0]]), np.array([[1.0], [2.0]]))
    assert d.shape == (2, 2)
    assert d[0, 0] == pytest.approx(0.0, abs=1e-15) and d[1, 1] == pytest.approx(0.0, abs=1e-15)
    assert d[0, 1] > 0.1 and d[1, 0] > 0.1


def _skewed(rng, n):
    return np.concatenate([rng.normal(0.0, 1.0, int(0.75 * n)), rng.normal(2.5, 0.5, n - int(0.75 * n))])


@pytest.mark.parametrize("case", range(3))
def test_mixture_quadrature_agrees_with_monte_carlo(case):
    rng = np.random.default_rng(case)
    base = fit_mixture(_skewed(rng, 40_000), 3)
    window_samples = [rng.normal(0.5, 1.0, 1000), rng.gamma(2.0, 1.0, 1000) - 1.0, _skewed(rng, 1000) * 1.2][case]
    window = fit_mixture(window_samples, 2)
    batch = Mixture(window.weights[None], window.means[None], window.stds[None])
    quadrature = mixture_relative_entropy(base, batch)[0]
    mc = monte_carlo_relative_entropy(base, window, n=400_000, seed=case)
    assert quadrature > 0.05
    assert quadrature == pytest.approx(mc, rel=0.02)


def test_mixture_entropy_of_one_component_mixtures_is_eq_5_3():
    base = Mixture(np.ones(1), np.array([0.3]), np.array([1.1]))
    windows = Mixture(np.ones((2, 1)), np.array([[0.0], [1.0]]), np.array([[1.0], [0.7]]))
    rule = quadrature_rule(base)
    got = mixture_relative_entropy(base, windows, rule=rule)
    want = gaussian_relative_entropy(0.3, 1.1, windows.means[:, 0], windows.stds[:, 0])
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_base_estimators_fit_and_refuse_bad_data():
    rng = np.random.default_rng(0)
    x = _skewed(rng, 20_000)
    g = GaussianBase().fit(x)
    assert g.mean_ == pytest.approx(x.mean()) and g.std_ == pytest.approx(x.std())
    m = MixtureBase(n_components=2, random_state=0).fit(x)
    assert m.weights_.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(np.sort(m.means_), [0.0, 2.5], atol=0.15)
    # the mixture fits the skewed errors better than the Gaussian (log-likelihood per sample)
    assert m.logpdf(x).mean() > g.logpdf(x).mean() + 0.05
    with pytest.raises(NotFittedError, match="fitted before use"):
        MixtureBase().logpdf(x)
    with pytest.raises(DataError, match="must vary"):
        fit_gaussian(np.ones(100))
    with pytest.raises(DataError, match="must be finite"):
        fit_mixture(np.array([1.0, np.nan, 2.0, 3.0]), 1)


@pytest.mark.parametrize("distribution", ["gaussian", "mixture"])
def test_window_is_close_to_its_own_base_and_far_from_others(distribution):
    states = STUDY_STATES
    base = {s: synthetic_errors(s, 10_000, seed=i) for i, s in enumerate(states)}
    features = RelativeEntropyFeatures(distribution=distribution).fit(base)
    assert features.feature_names_[:2] == ["flow|healthy", "flow|load_warning"]
    for i, s in enumerate(states):
        d = features.window_entropies(synthetic_errors(s, 3000, seed=50 + i))  # 3 windows
        assert d.shape == (3, 3, 7)
        total = d.sum(axis=1)  # sum over sensors, (windows, states)
        own = total[:, i]
        others = np.delete(total, i, axis=1)
        assert np.all(own < 0.2), (s, own)
        assert np.all(others.min(axis=1) > 2 * own), (s, own, others.min(axis=1))


def test_log_features_floor_and_nan():
    out = log_features(np.array([0.0, 1.0, np.nan]))
    assert out[0] == pytest.approx(np.log(1e-6)) and out[1] == 0.0 and np.isnan(out[2])
