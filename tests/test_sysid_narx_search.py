"""The study's NARX structure search (section 4.5.2): delay lines first, then neurons."""

from __future__ import annotations

import numpy as np
import pytest
from test_sysid_narx import nonlinear_system

from hydrowatch.errors import ParameterError
from hydrowatch.sysid.narx_search import search_structure


@pytest.fixture(scope="module")
def result():  # noqa: ANN201
    u, y = nonlinear_system(2400, seed=21, lag=3)  # needs u(t-3) and u(t-4): delay lines of 4 or more
    return search_structure(u, y, delays=(1, 2, 4, 6), hidden=(4, 8, 16), max_iter=60)


def test_delay_lines_grow_until_the_correlations_are_inside(result) -> None:  # noqa: ANN001
    model, table = result
    delay_rows = [r for r in table if r["phase"] == "delays"]
    assert [r["input_delays"] for r in delay_rows][:3] == [1, 2, 4]
    assert all("lengthen" in r["decision"] for r in delay_rows[:2])
    assert min(delay_rows[0]["acf_inside"], delay_rows[0]["ccf_inside"]) < 0.9
    assert model.input_delays == model.output_delays == 4  # inside the bounds, or 6 no better than 4
    assert delay_rows[2]["nrmse_one_step"] < 0.3 * delay_rows[0]["nrmse_one_step"]


def test_neurons_grow_while_gamma_is_close_to_the_parameter_count(result) -> None:  # noqa: ANN001
    model, table = result
    chosen = [r for r in table if r.get("chosen")]
    assert len(chosen) == 1 and chosen[0]["hidden"] == model.hidden
    for before, after in zip(table, table[1:], strict=False):
        if after["phase"] == "neurons":  # a bigger network is only tried when γ filled the smaller one
            assert before["gamma"] >= 0.85 * before["n_parameters"]
    assert model.hidden == 4  # 8 neurons do not lower the held-out error: the noise floor is reached
    assert model.n_parameters_ == 4 * (8 + 2) + 1
    assert np.isfinite(model.gamma_) and model.train_summary_["n_samples"] == 2400  # refit on the whole record


def test_search_rejects_bad_grids() -> None:
    u, y = nonlinear_system(300)
    with pytest.raises(ParameterError, match="delays must be"):
        search_structure(u, y, delays=(5, 3))
    with pytest.raises(ParameterError, match="hidden must be"):
        search_structure(u, y, hidden=())
    with pytest.raises(ParameterError, match="holdout"):
        search_structure(u, y, holdout=0.9)
