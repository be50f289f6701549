"""NARX reference model: training (LM + Bayesian regularisation), prediction, validation, I/O."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch
from scipy.signal import lfilter

from hydrowatch.errors import DataError, NotFittedError, ParameterError
from hydrowatch.sysid.narx import NARX
from hydrowatch.sysid.narx_lines import linear_one_step
from hydrowatch.sysid.narx_lm import forward, initial_weights, jacobian, n_parameters, torch_one_thread

NOISE = 0.05


def nonlinear_system(n: int, seed: int = 0, noise: float = NOISE, lag: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """y(t) = 0.5 y(t-1) − 0.2 y(t-2) + tanh(1.5 u(t-lag)) + 0.3 u(t-lag-1) y(t-1) + e(t), e ~ N(0, noise²).

    The noise enters the equation, so the best one-step predictor leaves exactly e(t): the
    one-step NRMSE floor is noise / std(y). u is low-pass filtered uniform noise, as in the study.
    """
    rng = np.random.default_rng(seed)
    u = 2.0 * lfilter([0.3], [1.0, -0.7], rng.uniform(-1.0, 1.0, n))
    e = noise * rng.standard_normal(n)
    y = np.zeros(n)
    for t in range(lag + 2, n):
        y[t] = 0.5 * y[t - 1] - 0.2 * y[t - 2] + np.tanh(1.5 * u[t - lag]) + 0.3 * u[t - lag - 1] * y[t - 1] + e[t]
    return u, y


def nrmse(y: np.ndarray, y_hat: np.ndarray) -> float:
    ok = np.isfinite(y_hat)
    return float(np.sqrt(np.mean((y[ok] - y_hat[ok]) ** 2)) / np.std(y[ok]))


@pytest.fixture(scope="module")
def data() -> tuple[np.ndarray, np.ndarray]:
    return nonlinear_system(2600)


@pytest.fixture(scope="module")
def model(data: tuple[np.ndarray, np.ndarray]) -> NARX:
    u, y = data
    return NARX(input_delays=3, output_delays=3, hidden=6, max_iter=150).fit(u[:2000], y[:2000])


def test_analytic_jacobian_matches_finite_differences() -> None:
    torch.manual_seed(0)
    x1 = torch.randn(40, 6, dtype=torch.float64)
    x1[:, -1] = 1.0
    theta = initial_weights(5, 4, seed=1, dtype=torch.float64) + 0.1 * torch.randn(n_parameters(5, 4),
                                                                                     dtype=torch.float64)
    step = 1e-6 * torch.eye(theta.numel(), dtype=torch.float64)
    with torch_one_thread():
        _, a = forward(theta, x1, 4)
        expected = torch.stack([(forward(theta + s, x1, 4)[0] - forward(theta - s, x1, 4)[0]) / 2e-6 for s in step],
                               dim=1)
        torch.testing.assert_close(jacobian(theta, x1, a), expected, rtol=1e-7, atol=1e-8)


def test_one_step_error_reaches_noise_floor_and_beats_linear_arx(data: tuple[np.ndarray, np.ndarray],
                                                                  model: NARX) -> None:
    u, y = data
    floor = NOISE / np.std(y[2000:])
    held_out = nrmse(y[2000:], model.predict(u[2000:], y[2000:]))
    assert held_out < 1.15 * floor
    arx = nrmse(y[2000:], linear_one_step(u[:2000], y[:2000], u[2000:], y[2000:], 3, 3))  # same delay lines
    assert held_out < 0.6 * arx


def test_fitted_attributes_and_bayesian_regularisation(model: NARX) -> None:
    assert model.n_parameters_ == 6 * (6 + 2) + 1
    assert 0.0 < model.gamma_ < model.n_parameters_
    assert model.alpha_ > 0.0 and model.beta_ > 0.0
    # β estimates 1 / (2σ²) of the normalised errors: σ² = (N − γ) / (2β E_D) ... so β E_D ≈ (N − γ)/2
    sse = model.history_["sse"][-1]
    assert model.beta_ * sse == pytest.approx((model.train_summary_["n_training_rows"] - model.gamma_) / 2, rel=0.05)
    hist = model.history_
    assert len(hist["gamma"]) == len(hist["alpha"]) == len(hist["sse"]) == model.train_summary_["iterations"] - (
        model.train_summary_["stop_reason"] in ("mu_max", "min_grad"))
    assert model.residuals_.shape == (2000 - 3,)
    assert model.train_summary_["nrmse_one_step"] == pytest.approx(np.std(model.residuals_, ddof=0)
                                                                    / model.output_scale_, rel=0.05)


def test_gamma_grows_with_data() -> None:
    u, y = nonlinear_system(3000, seed=3)
    small = NARX(input_delays=2, output_delays=2, hidden=10, max_iter=100).fit(u[:150], y[:150])
    large = NARX(input_delays=2, output_delays=2, hidden=10, max_iter=100).fit(u, y)
    assert small.gamma_ < large.gamma_ < large.n_parameters_
    assert small.gamma_ < 0.8 * small.n_parameters_


def test_residual_correlations_inside_for_adequate_and_outside_for_short_delay_lines() -> None:
    u, y = nonlinear_system(3000, seed=5, lag=3)  # the output answers the input 3 samples later
    good = NARX(input_delays=4, output_delays=2, hidden=5, max_iter=100).fit(u[:2000], y[:2000])
    short = NARX(input_delays=1, output_delays=2, hidden=5, max_iter=100).fit(u[:2000], y[:2000])
    ok = good.residual_correlations(u[2000:], y[2000:], max_lag=20)
    bad = short.residual_correlations(u[2000:], y[2000:], max_lag=20)
    assert ok["acf"].shape == (21,) and ok["ccf"].shape == (1, 41)
    assert ok["acf"][0] == pytest.approx(1.0)
    assert ok["bound"] == pytest.approx(1.96 / np.sqrt(ok["n"]), rel=1e-3)
    assert ok["acf_inside"] >= 0.85 and ok["ccf_inside"] >= 0.85
    assert np.max(np.abs(ok["ccf"])) < 2 * ok["bound"]
    assert min(bad["acf_inside"], bad["ccf_inside"]) <= 0.8
    assert np.max(np.abs(bad["ccf"])) > 5 * bad["bound"]  # u(t-2), u(t-3) are missing from the line


def test_batched_one_step_equals_predict_with_documented_layout() -> None:
    rng = np.random.default_rng(2)
    n = 600
    u = rng.standard_normal((n, 2)).cumsum(axis=0) * 0.1
    y = np.tanh(u[:, 0]) + 0.5 * np.roll(u[:, 1], 2) + 0.01 * rng.standard_normal(n)
    m = NARX(input_delays=3, output_delays=2, hidden=4, max_iter=20).fit(u, y)
    assert m.regressor_layout.startswith("predicts y(t) from [y(t-1), y(t-2), u1(t-1), u1(t-2), u1(t-3), u2(t-1)")
    times = np.arange(3, n)
    rows = np.column_stack([y[times - 1], y[times - 2]]
                           + [u[times - k, i] for i in range(2) for k in (1, 2, 3)])
    predicted = m.predict(u, y)
    assert np.all(np.isnan(predicted[:3]))
    np.testing.assert_allclose(m.one_step(rows), predicted[3:], rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.one_step(rows[::-1])[::-1], predicted[3:], rtol=0, atol=1e-12)  # order-free


def test_multi_step_and_free_run_feed_back_the_model_output(model: NARX, data: tuple[np.ndarray, np.ndarray]) -> None:
    u, y = data[0][2000:2300], data[1][2000:2300]
    one = model.predict(u, y)
    np.testing.assert_array_equal(model.predict(u, y, steps_ahead=1), one)
    two = model.predict(u, y, steps_ahead=2)
    assert np.all(np.isnan(two[:4])) and np.all(np.isfinite(two[4:]))
    t = np.arange(4, 300)
    rows = np.column_stack([one[t - 1], y[t - 2], y[t - 3], u[t - 1], u[t - 2], u[t - 3]])
    np.testing.assert_allclose(two[4:], model.one_step(rows), atol=1e-12)
    free = model.predict(u, y, steps_ahead=None)
    line = list(y[:3])
    for k in range(3, 300):
        line.append(float(model.one_step(np.array([[line[k - 1], line[k - 2], line[k - 3], u[k - 1], u[k - 2],
                                                     u[k - 3]]]))[0]))
    np.testing.assert_allclose(free[3:], line[3:], atol=1e-10)
    assert nrmse(y, free) < 0.2  # the model simulates the plant, not only predicts one step


def test_save_load_round_trip(tmp_path, model: NARX, data: tuple[np.ndarray, np.ndarray]) -> None:
    u, y = data[0][2000:], data[1][2000:]
    path = tmp_path / "narx.pt"
    model.save(path)
    blob = torch.load(path, weights_only=True)
    assert blob["params"]["hidden"] == 6 and blob["train_summary"]["n_samples"] == 2000
    loaded = NARX.load(path)
    np.testing.assert_array_equal(loaded.predict(u, y), model.predict(u, y))
    assert loaded.summary() == model.summary()
    assert loaded.get_params() == model.get_params()
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(model)).predict(u, y), model.predict(u, y))


def test_load_rejects_other_files(tmp_path) -> None:
    other = tmp_path / "other.pt"
    torch.save({"format": "something"}, other)
    with pytest.raises(DataError, match="NARX model"):
        NARX.load(other)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a model")
    with pytest.raises(DataError, match="junk.pt"):
        NARX.load(junk)


def test_early_stopping_holds_out_the_tail() -> None:
    u, y = nonlinear_system(1200, seed=7)
    m = NARX(input_delays=2, output_delays=2, hidden=12, max_iter=200, early_stopping=True,
             validation_fraction=0.2).fit(u, y)
    assert m.train_summary_["n_training_rows"] == 1198 - round(0.2 * 1198)
    assert len(m.history_["validation_sse"]) == len(m.history_["sse"])
    if m.train_summary_["stop_reason"] == "validation":
        best = int(np.argmin(m.history_["validation_sse"]))
        assert len(m.history_["sse"]) - 1 - best == 6


def test_seeded_training_is_reproducible() -> None:
    u, y = nonlinear_system(400, seed=8)
    a = NARX(input_delays=2, output_delays=2, hidden=3, max_iter=30, seed=4).fit(u, y)
    b = NARX(input_delays=2, output_delays=2, hidden=3, max_iter=30, seed=4).fit(u, y)
    c = NARX(input_delays=2, output_delays=2, hidden=3, max_iter=30, seed=5).fit(u, y)
    torch.testing.assert_close(a.weights_, b.weights_, rtol=0, atol=0)
    assert not torch.equal(a.weights_, c.weights_)


def test_scikit_learn_conventions() -> None:
    from sklearn.base import clone

    m = NARX(input_delays=4, hidden=7)
    assert m.get_params()["input_delays"] == 4
    copy = clone(m)
    assert copy.get_params() == m.get_params() and copy is not m
    assert m.set_params(hidden=3).hidden == 3
    with pytest.raises(ValueError, match="neurons"):
        m.set_params(neurons=3)
    assert "input_delays=4" in repr(m)
    u, y = nonlinear_system(300, seed=9)
    params = m.get_params()
    m.set_params(max_iter=5).fit(u, y)
    assert m.get_params() == {**params, "max_iter": 5}


def test_unfitted_model_fails_clearly() -> None:
    with pytest.raises(NotFittedError, match="fit"):
        NARX().predict(np.zeros(50), np.zeros(50))
    with pytest.raises(NotFittedError):
        NARX().one_step(np.zeros((2, 30)))
    with pytest.raises(NotFittedError):
        NARX().summary()


@pytest.mark.parametrize(
    ("u", "y", "match"),
    [
        (np.zeros(10), np.zeros(10), "at least"),
        (np.zeros(100), np.zeros(99), "same number of samples"),
        (np.r_[np.zeros(50), np.nan, np.zeros(49)], np.arange(100.0), "u must be finite.*index 50"),
        (np.arange(100.0), np.r_[np.zeros(20), np.inf, np.zeros(79)], "y must be finite"),
        (np.arange(100.0), np.ones((100, 2)), "y must have shape"),
        (np.ones((100, 2, 2)), np.arange(100.0), "u must have shape"),
        (np.arange(100.0), np.ones(100), "y must vary"),
    ],
)
def test_bad_data_is_rejected(u: np.ndarray, y: np.ndarray, match: str) -> None:
    with pytest.raises(DataError, match=match):
        NARX(input_delays=3, output_delays=3, hidden=2, max_iter=2).fit(u, y)


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"hidden": 0}, "hidden must be an integer >= 1"),
        ({"input_delays": 0}, "input_delays must be"),
        ({"output_delays": -1}, "output_delays must be"),
        ({"max_iter": 2.5}, "max_iter must be"),
        ({"validation_fraction": 0.9}, "validation_fraction"),
        ({"dtype": torch.int32}, "dtype must be"),
    ],
)
def test_bad_parameters_are_rejected(params: dict, match: str) -> None:
    u, y = nonlinear_system(200)
    with pytest.raises(ParameterError, match=match):
        NARX(**params).fit(u, y)


def test_bad_prediction_input_is_rejected(model: NARX, data: tuple[np.ndarray, np.ndarray]) -> None:
    u, y = data
    with pytest.raises(DataError, match="regressors must have shape"):
        model.one_step(np.zeros((5, 7)))
    with pytest.raises(DataError, match="1 input column"):
        model.predict(np.zeros((100, 2)), y[:100])
    with pytest.raises(DataError, match="more than 3 samples"):
        model.predict(u[:3], y[:3])
    with pytest.raises(ParameterError, match="steps_ahead"):
        model.predict(u, y, steps_ahead=0)


def test_float32_training_runs() -> None:
    u, y = nonlinear_system(500, seed=11)
    m = NARX(input_delays=2, output_delays=2, hidden=3, max_iter=20, dtype=torch.float32).fit(u, y)
    assert m.weights_.dtype == torch.float64  # stored in double for prediction
    assert m.summary()["nrmse_one_step"] < 0.2
