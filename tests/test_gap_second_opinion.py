"""The sparse-regression second opinion (issue 6): stability selection over the regressor library, its
map from terms to catalog effects, and its place in the gap report."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.errors import NotFittedError, ParameterError
from hydrowatch.gap import TERM_EFFECTS, GapAnalyser, StabilitySelection
from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.correction import Library, build_library
from hydrowatch.gap.html import render_html
from hydrowatch.gap.second_opinion import SecondOpinion, second_opinion, unique_shares
from hydrowatch.plant.effects import EFFECT_IDS
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate

N = 20 * 200


@pytest.fixture(scope="module")
def operating_point() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A noise-free nominal simulation on 20 s of filtered noise: t, u, simulated (3, n), masks."""
    u = filtered_noise(20.0, (0.0, 4.0), seed=4)
    rec = simulate(u, noise=False)
    simulated = np.vstack([rec["flow"], rec["speed"], rec["torque"]])
    block = np.maximum(np.arange(N) - 200, 0) // 600
    holdout = (np.arange(N) >= 200) & (block % 3 == 1)
    fit = (np.arange(N) >= 200) & ~holdout
    return rec.t, u, simulated, np.vstack([fit, holdout])


def test_every_term_points_at_catalog_effects() -> None:
    library = build_library(np.zeros(8), np.zeros((3, 8)), np.arange(8.0), pump_speed=1.0)
    assert set(TERM_EFFECTS) <= set(library.names)
    assert {e for effects in TERM_EFFECTS.values() for e in effects} <= set(EFFECT_IDS)
    # the nominal structure's own terms point at nothing: a parameter change is not missing physics
    assert not {"1", "u", "ω", "T", "Q"} & set(TERM_EFFECTS)


def test_stable_terms_find_drag_and_not_the_noise(operating_point) -> None:
    t, u, simulated, (fit, holdout) = operating_point
    library = build_library(u, simulated, t, pump_speed=183.26)
    speed = simulated[1]
    rng = np.random.default_rng(2)
    residual = 0.01 * speed * np.abs(speed) + 0.2 * rng.standard_normal(N)
    sel = StabilitySelection(n_fits=40).fit(library, residual, fit, holdout)
    assert "ω·|ω|" in sel.stable_ and sel.frequency_[library.names.index("ω·|ω|")] >= 0.95
    assert sel.stable_["ω·|ω|"] == pytest.approx(0.01, rel=0.15)
    assert sel.implicated == {"quadratic_drag"}
    assert sel.importance_["ω·|ω|"] > 0.1
    noise_only = StabilitySelection(n_fits=40).fit(library, 0.2 * rng.standard_normal(N), fit, holdout)
    assert noise_only.implicated == set()
    assert max(noise_only.frequency_) < 0.8


def test_stability_selection_checks_its_parameters(operating_point) -> None:
    t, u, simulated, (fit, holdout) = operating_point
    library = build_library(u, simulated, t, pump_speed=183.26)
    with pytest.raises(ParameterError, match="n_fits must be >= 2"):
        StabilitySelection(n_fits=1).fit(library, u, fit, holdout)
    with pytest.raises(NotFittedError, match="must be fitted first"):
        _ = StabilitySelection().implicated


def test_unique_shares_split_what_each_term_alone_explains() -> None:
    rng = np.random.default_rng(0)
    x = rng.standard_normal((1000, 2))
    names = ("1", "a", "b")
    lib = Library(names, np.column_stack([np.ones(1000), x]))
    y = 2.0 * x[:, 0] + 0.5 * x[:, 1]
    shares = unique_shares(lib, y, np.arange(1000), ["a", "b"])
    assert shares["a"] == pytest.approx(4.0 / 4.25, abs=0.05) and shares["b"] == pytest.approx(0.25 / 4.25, abs=0.02)


def test_verdict_of_a_dead_time(operating_point) -> None:
    """A dead time shows as the delayed command and the rate terms in every coloured sensor."""
    t, u, simulated, (fit, holdout) = operating_point
    late = simulate(np.concatenate([np.full(3, u[0]), u[:-3]]), noise=False)
    measured = np.vstack([late["flow"], late["speed"], late["torque"]])
    measured = measured + 0.01 * measured.std(axis=1, keepdims=True) * np.random.default_rng(1).standard_normal(
        measured.shape)
    aligned = AlignedRecording(t, u, measured, measured.std(axis=1), fit, holdout, "synthetic")
    opinion = second_opinion(aligned, simulated, pump_speed=PlantParameters().omega_p, n_fits=30)
    assert isinstance(opinion, SecondOpinion) and set(opinion.selections) == {"flow", "speed", "torque"}
    verdict = opinion.verdict("transport_delay")
    assert verdict["agrees"] and verdict["specific"]
    assert any(item.endswith("u(t−20 ms)") for item in verdict["supporting"])
    assert not opinion.verdict("pump_ripple")["agrees"]
    assert set(verdict) == {"agrees", "specific", "supporting", "share", "rank", "terms", "selection_frequency",
                            "implicated", "residual"}
    assert verdict["rank"] >= 1 and verdict["share"] > 0.05


def test_report_carries_the_second_opinion_of_a_named_effect() -> None:
    rng = np.random.default_rng(7)
    nominal = PlantParameters()
    plant = nominal.replace(Kq=nominal.Kq * 1.1, TL=nominal.TL * 0.9)
    rec = simulate(filtered_noise(15.0, (0.0, 4.0), seed=7), plant, {"valve_deadband": {"d": 0.12}},
                   seed=int(rng.integers(100)))
    analyser = GapAnalyser(candidates=("valve_deadband",)).fit(rec)
    report = analyser.report_
    assert [e["id"] for e in report["effects"]] == ["valve_deadband"]
    so = report["effects"][0]["second_opinion"]
    assert so["agrees"] is True and so["residual"] == "calibrated"
    assert any("max(0.5 V − u, 0)" in item for item in so["supporting"])
    sensor, term = so["supporting"][0].split(": ")
    assert so["selection_frequency"][sensor][term] >= 0.8
    assert report["second_opinion"]["implicated"] == so["implicated"]
    assert "Second opinion" in report["summary"] and "agrees on valve_deadband" in report["summary"]
    assert "second opinion (sparse regression): agrees (" in render_html(analyser)
