"""Box-Jenkins validation (Eqs. 3.14-3.18), pole-zero checks, preliminary identification and GPAC."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.errors import ParameterError
from hydrowatch.sysid import (
    BoxJenkins,
    frequency_response,
    gpac_table,
    preliminary_identification,
    q_statistic,
    read_gpac,
    s_statistic,
)
from hydrowatch.sysid.pem import STUDY_MODEL_3_24, filtered_white_noise, simulate_box_jenkins
from hydrowatch.sysid.polynomials import cancellations, impulse_response, reflect_into_unit_circle
from hydrowatch.sysid.validation import pole_zero_report

M = STUDY_MODEL_3_24


def study_data(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = filtered_white_noise(n, rng)
    return u, simulate_box_jenkins(M["b"], M["f"], M["c"], M["d"], 4, u, 0.5 * rng.standard_normal(n))


def test_q_and_s_are_chi_square_for_white_residuals() -> None:
    rng = np.random.default_rng(0)
    p_q, p_s = [], []
    for _ in range(200):
        e, u = rng.standard_normal(600), rng.standard_normal(600)
        p_q.append(q_statistic(e, 20, 2)[2])
        p_s.append(s_statistic(u, e, 20, 3)[2])
    # p-values of a correct model are roughly uniform: about 5 % below 0.05
    assert 0.0 <= np.mean(np.array(p_q) < 0.05) <= 0.12
    assert 0.0 <= np.mean(np.array(p_s) < 0.05) <= 0.12
    q, dof, _ = q_statistic(rng.standard_normal(600), 35, 5)
    assert dof == 30
    with pytest.raises(ParameterError, match="lags must exceed"):
        q_statistic(rng.standard_normal(600), 5, 5)


def test_study_tables_3_3_and_3_4() -> None:
    """The study's validation story on data from Eq. 3.24: orders (4,4,1,3) fail Q with 31 degrees
    of freedom while S passes with 27; the final orders (4,4,4,5) pass both (26 and 27)."""
    u, y = study_data(10000, 1)
    first = BoxJenkins(nb=4, nf=4, nc=1, nd=3, delay=4).fit(u, y).validation_
    assert (first["Q_dof"], first["S_dof"]) == (31, 27)
    assert first["Q_p"] < 1e-3 < first["S_p"]
    final = BoxJenkins(nb=4, nf=4, nc=4, nd=5, delay=4).fit(u, y).validation_
    assert (final["Q_dof"], final["S_dof"]) == (26, 27)
    assert final["Q_p"] > 0.01 and final["S_p"] > 0.01
    assert final["stable"] and final["invertible"] and final["cancellations"] == []
    # a G that is too small fails S
    assert BoxJenkins(nb=2, nf=2, nc=4, nd=5, delay=4).fit(u, y).validation_["S_p"] < 1e-3


def test_pole_zero_report_finds_cancellation_and_instability() -> None:
    report = pole_zero_report(np.array([1.0, -0.5]), np.array([-0.52]), np.array([]), np.array([-1.5]), 0.05)
    assert report["cancellations"][0]["model"] == "G"
    assert report["cancellations"][0]["distance"] == pytest.approx(0.02)
    assert not report["stable"]
    assert cancellations(np.array([0.5 + 0j]), np.array([0.9 + 0j]), 0.05) == []
    tail = reflect_into_unit_circle(np.array([-2.5, 1.0]))  # roots 2 and 0.5
    assert np.allclose(sorted(np.abs(np.roots(np.r_[1.0, tail]))), [0.5, 0.5])


def test_gpac_of_exact_sequences_shows_the_orders() -> None:
    b, f = M["b"], M["f"]
    g = impulse_response(np.r_[np.zeros(5), b], np.r_[1.0, f], 40)
    pattern = read_gpac(gpac_table(g, 12, 7, symmetric=False), min_row=5)
    assert (pattern.row, pattern.column) == (8, 4)  # Fig. 3.4: row 8, column 4 -> nb = 8 - delay
    assert pattern.value == pytest.approx(-f[-1], rel=1e-6)
    # ARMA(1, 1) autocorrelation: column 1 constant from row 1, zeros to its right
    phi, theta = 0.7, 0.4
    r1 = (1 + phi * theta) * (phi + theta) / (1 + 2 * phi * theta + theta**2)
    acf = np.r_[1.0, r1 * phi ** np.arange(20)]
    pattern = read_gpac(gpac_table(acf, 6, 4, symmetric=True))
    assert (pattern.row, pattern.column) == (1, 1)
    assert pattern.value == pytest.approx(phi)


def test_preliminary_identification_reads_delay_and_orders() -> None:
    rng = np.random.default_rng(3)
    u = rng.standard_normal(3000)
    y = simulate_box_jenkins([1.0, 0.5], [-1.2, 0.5], [0.5], [-0.8], 2, u, 0.5 * rng.standard_normal(3000))
    pre = preliminary_identification(u, y)
    assert pre.delay == 2
    assert pre.orders == {"nb": 2, "nf": 2, "nc": 1, "nd": 1}
    g_true = impulse_response(np.r_[0, 0, 0, 1.0, 0.5], [1.0, -1.2, 0.5], 51)
    assert np.mean(np.abs(pre.impulse_response - g_true) < 3 * pre.impulse_se) > 0.9
    assert pre.to_dict()["orders"] == pre.orders
    u4, y4 = study_data(10000, 0)
    assert preliminary_identification(u4, y4).delay == 4  # Fig. 3.3: a lag of 4 samples


def test_frequency_response_matches_the_model() -> None:
    rng = np.random.default_rng(4)
    u = rng.standard_normal(20000)
    y = simulate_box_jenkins([0.5], [-0.5], [], [], 0, u, 0.05 * rng.standard_normal(20000))
    f, h = frequency_response(u, y, sample_rate=200.0)
    z = np.exp(2j * np.pi * f / 200.0)
    exact = 0.5 / z / (1 - 0.5 / z)
    assert f[-1] == pytest.approx(100.0)
    assert np.max(np.abs(h - exact) / np.abs(exact)) < 0.1


def test_a_settling_filter_equals_the_whole_filter_and_stops_early_only_when_settled() -> None:
    """Pulse and step responses and a short head of noise through random stable filters (poles up to 0.97): equal
    to filtering all n samples to 1e-13 of the peak; a pole at 0.9999 or at 1 is filtered to the end, exactly."""
    from hydrowatch.sysid.polynomials import filter_settling, filter_signal

    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(60):
        k = int(rng.integers(1, 5))
        poles = rng.uniform(0.0, 0.97, k) * np.exp(1j * rng.uniform(0.0, np.pi, k))
        a = np.real(np.poly(np.concatenate([poles, poles.conj()])))
        b = rng.standard_normal(int(rng.integers(1, 5)))
        n = int(rng.integers(20, 20_000))
        for level, head in ((0.0, np.ones(1)), (1.0, np.ones(0)), (0.0, rng.standard_normal(int(rng.integers(1, 40))))):
            whole = filter_signal(b, a, np.concatenate([head[:n], np.full(max(n - head.size, 0), level)]))
            got = filter_settling(b, a, head, n, level)
            worst = max(worst, float(np.max(np.abs(got - whole)) / np.max(np.abs(whole))))
    assert worst < 1e-13
    slow = filter_settling([1.0], [1.0, -0.9999], [1.0], 5000, level=1.0)
    np.testing.assert_array_equal(slow, filter_signal([1.0], [1.0, -0.9999], np.ones(5000)))
    assert slow[-1] < 0.5 / 1e-4  # far from its final value 1e4: not settled, so never cut short
    # an integrator's step response has no final value: a ramp, all of it
    np.testing.assert_array_equal(filter_settling([1.0], [1.0, -1.0], [], 50, level=1.0), np.arange(1.0, 51.0))
