"""Box-Jenkins estimation (study Eqs. 3.8-3.14, 3.26): known models come back inside their intervals."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sklearn.base import clone

from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.sysid import BoxJenkins
from hydrowatch.sysid.pem import (
    STUDY_MODEL_3_24,
    Orders,
    filtered_white_noise,
    jacobian,
    prediction_errors,
    simulate_box_jenkins,
)

SMALL = {"b": [1.0, 0.5], "f": [-1.2, 0.5], "c": [0.5], "d": [-0.8], "delay": 2}


def data(model: dict, n: int, seed: int, noise: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Input of Eq. 3.21 (offset 2 V, like range 1 of Table 3.1) and the model's output (offset 50)."""
    rng = np.random.default_rng(seed)
    u = filtered_white_noise(n, rng)
    e = noise * rng.standard_normal(n)
    y = simulate_box_jenkins(model["b"], model["f"], model["c"], model["d"], model["delay"], u, e)
    return u + 2.0, y + 50.0


def truth(model: dict) -> np.ndarray:
    return np.concatenate([model["b"], model["f"], model["c"], model["d"]])


def fit(model: dict, u: np.ndarray, y: np.ndarray) -> BoxJenkins:
    orders = {k: len(model[p]) for k, p in (("nb", "b"), ("nf", "f"), ("nc", "c"), ("nd", "d"))}
    return BoxJenkins(**orders, delay=model["delay"]).fit(u, y)


def inside(m: BoxJenkins, model: dict) -> np.ndarray:
    t = truth(model)
    return (m.ci95_[:, 0] <= t) & (t <= m.ci95_[:, 1])


def test_jacobian_is_exact() -> None:
    rng = np.random.default_rng(0)
    orders = Orders(2, 2, 1, 2, 1)
    theta = np.array([0.8, 0.3, -0.9, 0.3, 0.4, -0.5, 0.2])
    u, y = rng.standard_normal(400), rng.standard_normal(400)
    eps, w, v = prediction_errors(theta, u, y, orders)
    jac = jacobian(theta, u, orders, eps, w, v)
    h = 1e-6
    for i in range(theta.size):
        step = np.zeros_like(theta)
        step[i] = h
        numeric = (
            prediction_errors(theta + step, u, y, orders)[0] - prediction_errors(theta - step, u, y, orders)[0]
        ) / (2 * h)
        np.testing.assert_allclose(jac[:, i], numeric, atol=1e-6)


def test_small_model_parameters_inside_their_intervals() -> None:
    hits = [inside(fit(SMALL, *data(SMALL, 5000, seed)), SMALL) for seed in range(10)]
    assert np.mean(hits) >= 0.9


def test_study_model_parameters_inside_their_intervals() -> None:
    """Eq. 3.24, delay 4. Its H has nearly cancelling pole-zero pairs (the study's over-parametrised
    noise model), which makes the noise parameters' intervals reliable only from ~30,000 samples;
    G's are reliable at the study's 10,000."""
    hits, hits_g = [], []
    for seed in range(4):
        u, y = data(STUDY_MODEL_3_24, 30000, seed)
        m = fit(STUDY_MODEL_3_24, u, y)
        hits.append(inside(m, STUDY_MODEL_3_24))
        assert m.validation_["Q_p"] > 0.01 and m.validation_["S_p"] > 0.01
        assert m.validation_["stable"] and m.validation_["invertible"]
    assert np.mean(hits) >= 0.9
    for seed in range(4, 7):
        hits_g.append(inside(fit(STUDY_MODEL_3_24, *data(STUDY_MODEL_3_24, 10000, seed)), STUDY_MODEL_3_24)[:8])
    assert np.mean(hits_g) >= 0.9


def test_parameters_are_in_signal_units_whatever_the_normalisation() -> None:
    u, y = data(SMALL, 4000, 1)
    scaled = fit(SMALL, 3.0 * u, y)
    plain = BoxJenkins(nb=2, nf=2, nc=1, nd=1, delay=2).fit(u, y)
    np.testing.assert_allclose(scaled.b_ * 3.0, plain.b_, rtol=1e-5)
    np.testing.assert_allclose(scaled.f_, plain.f_, atol=1e-6)
    raw = BoxJenkins(nb=2, nf=2, nc=1, nd=1, delay=2, normalize=False).fit(u - 2.0, y - 50.0)
    np.testing.assert_allclose(raw.b_, plain.b_, rtol=1e-3)
    assert plain.sigma2_ == pytest.approx(0.25, rel=0.1)


def test_one_step_prediction_is_eq_3_26() -> None:
    u, y = data(SMALL, 3000, 2)
    m = fit(SMALL, u, y)
    # the fit removes the response of the estimated initial state; predict starts from rest
    np.testing.assert_allclose(y - m.predict(u, y) - m.start_up_response_, m.residuals_, atol=1e-9)
    assert np.max(np.abs(m.start_up_response_[200:])) < 1e-6 < np.max(np.abs(m.start_up_response_[:10]))
    # Eq. 3.26 written out: D B q^-K / (C F) u + (1 - D/C) y on the normalised signals
    from scipy.signal import lfilter

    un, yn = (u - m.input_mean_) / m.input_scale_, (y - m.output_mean_) / m.output_scale_
    b = np.r_[np.zeros(3), m.b_ * m.input_scale_ / m.output_scale_]
    c, d, f = np.r_[1, m.c_], np.r_[1, m.d_], np.r_[1, m.f_]
    eq326 = lfilter(np.convolve(d, b), np.convolve(c, f), un) + yn - lfilter(d, c, yn)
    np.testing.assert_allclose(m.predict(u, y), m.output_mean_ + m.output_scale_ * eq326, atol=1e-9)
    rms = [np.sqrt(np.mean((y - m.predict(u, y, steps_ahead=k)) ** 2)) for k in (1, 3, 10)]
    free = np.sqrt(np.mean((y - m.simulate(u)) ** 2))
    assert rms[0] == pytest.approx(0.5, rel=0.05)
    assert rms[0] < rms[1] < rms[2] <= free * 1.01
    np.testing.assert_allclose(m.simulate(u), m.predict(u, steps_ahead=None))
    assert m.nrmse_one_step_ == pytest.approx(np.sqrt(np.mean(m.residuals_**2)) / np.std(y), rel=1e-9)
    assert m.nrmse_one_step_ == pytest.approx(rms[0] / np.std(y), rel=0.01)


def test_contract_json_and_save_load_round_trip(tmp_path) -> None:
    u, y = data(SMALL, 2000, 3)
    m = fit(SMALL, u, y)
    document = json.loads(json.dumps(m.to_dict()))
    assert document["model"] == "bj" and document["delay"] == 2
    assert document["orders"] == {"nb": 2, "nf": 2, "nc": 1, "nd": 1}
    assert list(document["parameters"]) == ["b1", "b2", "f1", "f2", "c1", "d1"]
    lo, hi = document["parameters"]["f1"]["ci95"]
    assert lo < document["parameters"]["f1"]["value"] < hi
    for key in ("Q", "Q_dof", "Q_p", "S", "S_dof", "S_p"):
        assert key in document["validation"]
    m.save(tmp_path / "bj.json")
    back = BoxJenkins.load(tmp_path / "bj.json")
    np.testing.assert_allclose(back.predict(u, y), m.predict(u, y))
    assert back.to_dict() == m.to_dict()
    (tmp_path / "other.json").write_text("{}")
    with pytest.raises(DataError, match="format"):
        BoxJenkins.load(tmp_path / "other.json")


def test_estimator_contract() -> None:
    m = BoxJenkins(nb=2, nf=2, nc=1, nd=1, delay=2)
    params = m.get_params()
    assert clone(m).get_params() == params
    with pytest.raises(NotFittedError, match="fit"):
        m.predict(np.zeros(10), np.zeros(10))
    u, y = data(SMALL, 1000, 4)
    m.fit(u, y)
    assert m.get_params() == params


@pytest.mark.parametrize(
    ("u", "y", "kwargs", "error", "match"),
    [
        (np.arange(50.0), np.ones(50), {}, DataError, "at least"),
        (np.r_[np.nan, np.ones(999)], np.ones(1000), {}, DataError, "finite"),
        (np.ones(1000), np.ones(999), {}, DataError, "same length"),
        (np.ones(1000), np.arange(1000.0), {}, DataError, "vary"),
        (np.sin(0.3 * np.arange(1000)), np.arange(1000.0), {}, DataError, "persistently exciting"),
        (np.arange(1000.0), np.arange(1000.0), {"nb": 0}, ParameterError, "nb must be"),
        (np.arange(1000.0), np.arange(1000.0), {"delay": -1}, ParameterError, "delay must be"),
    ],
)
def test_bad_input_is_refused(u, y, kwargs, error, match) -> None:
    with pytest.raises(error, match=match):
        BoxJenkins(**{"nb": 2, "nf": 2, "nc": 1, "nd": 1, **kwargs}).fit(u, y)
