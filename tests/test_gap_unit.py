"""The gap analyser on a unit whose every parameter differs from the design (issue 12, short form).

Each recording: a random unit (every calibrated parameter × U(0.7, 1.3)), default sensor noise,
filtered noise over −4…4 V. benchmarks/bench_gap_population.py runs the long form (120 s, a
population, every effect).
"""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.gap import CALIBRATED, GapAnalyser
from hydrowatch.gap.align import align, simulate_sensors, simulation_threads
from hydrowatch.gap.discovery import FALSE_ALARM, residual_test
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate
from hydrowatch.recording import Recording


def random_unit(seed: int) -> PlantParameters:
    """Every calibrated parameter of the design × U(0.7, 1.3)."""
    rng = np.random.default_rng(seed)
    p = PlantParameters()
    return p.replace(**{k: getattr(p, k) * float(rng.uniform(0.7, 1.3)) for k in CALIBRATED})


def unit_recording(seed: int, effects: dict | None, seconds: float = 30.0) -> tuple[Recording, PlantParameters]:
    unit = random_unit(seed)
    return simulate(filtered_noise(seconds, (-4.0, 4.0), seed=seed), unit, effects, seed=seed), unit


def test_a_unit_with_nothing_concealed_calibrates_to_the_noise_and_stays_clean() -> None:
    rec, unit = unit_recording(3, None, seconds=60.0)
    analyser = GapAnalyser(candidates=("transport_delay", "quadratic_drag")).fit(rec)
    report = analyser.report_
    assert report["mismatch"] is False and report["effects"] == []
    for sensor, value in report["fit"]["calibrated"].items():
        assert value <= 1.1 * report["noise"][sensor]
    # Pump and valve leakage act alike (both leak supply → tank): only their sum is determined, which
    # leaves the smaller of the two (Cvl) to the prior.
    undetermined = report["identifiability"]["not_determined"]
    assert "Cvl" in undetermined and "flow meter" in undetermined["Cvl"]["experiment"]
    assert report["calibrated_parameters"]["Cvl"]["determined"] is False
    values = {k: row["value"] for k, row in report["calibrated_parameters"].items()}
    assert values["Cp"] + values["Cvl"] == pytest.approx(unit.Cp + unit.Cvl, rel=0.1)
    # βe, Vs and Vt scaled together leave βe/Vs and βe/Vt as they are.
    assert values["beta_e"] / values["Vt"] == pytest.approx(unit.beta_e / unit.Vt, rel=0.03)
    for name in report["identifiability"]["determined"]:
        lo, hi = report["calibrated_parameters"][name]["ci95"]
        assert lo < values[name] < hi
    for name in ("Kq", "Dm", "JL", "TL"):
        assert name in report["identifiability"]["determined"]
        assert values[name] == pytest.approx(getattr(unit, name), rel=0.03)
    assert report["discovery_test"]["calibrated"]["beyond"] == []
    assert "Not determined by this recording" in report["summary"]


def test_one_effect_on_a_random_unit_is_named_alone() -> None:
    rec, _ = unit_recording(4, {"transport_delay": {"tau": 0.012}}, seconds=20.0)
    report = GapAnalyser(candidates=("transport_delay", "quadratic_drag")).fit(rec).report_
    assert [e["id"] for e in report["effects"]] == ["transport_delay"]
    assert report["effects"][0]["parameters"]["tau"] == pytest.approx(0.012, rel=0.1)
    assert report["discovery_test"]["calibrated"]["beyond"]
    assert report["discovery_test"]["final"]["beyond"] == []
    assert report["dropped"] == []


def test_the_discovery_test_passes_white_noise_and_fails_an_unexplained_error() -> None:
    rec, _ = unit_recording(5, None, seconds=120.0)  # only its time base and held-out layout are used
    aligned = align(rec)
    rng = np.random.default_rng(0)
    sigma = np.array([0.05, 0.04, 0.2])
    t = aligned.t
    truth = np.vstack([np.sin(t), np.cos(0.7 * t), np.sin(1.3 * t)])
    measured = truth + sigma[:, None] * rng.standard_normal(truth.shape)
    clean = residual_test(type(aligned)(t, aligned.voltage, measured, aligned.scale, aligned.fit_mask,
                                       aligned.holdout_mask, "test"), truth, 10)
    assert not clean.fails
    assert all(0.9 < v < 1.1 for v in clean.statistic.values())
    assert all(1.03 < v < 1.12 for v in clean.threshold.values())  # ≈ 1.07 on 120 s
    # a slow error of 0.4 σ RMS in speed (16 % more mean square than the noise) is beyond it
    drifted = measured.copy()
    drifted[1] += 0.4 * np.sqrt(2) * sigma[1] * np.sin(2 * np.pi * 0.5 * t)
    found = residual_test(type(aligned)(t, aligned.voltage, drifted, aligned.scale, aligned.fit_mask,
                                        aligned.holdout_mask, "test"), truth, 10)
    assert found.beyond == ("speed",)
    assert found.as_dict()["false_alarm"] == FALSE_ALARM


def test_batched_simulations_shared_out_over_threads_give_the_same_sensors(monkeypatch: pytest.MonkeyPatch) -> None:
    rec, unit = unit_recording(6, None, seconds=10.0)
    aligned = align(rec)
    models = [unit, PlantParameters(), unit.replace(JL=unit.JL * 1.2)]
    effects = [None, {"gear_backlash": {"b": 0.02}}, {"transport_delay": {"tau": 0.01}}]
    monkeypatch.setenv("HYDROWATCH_THREADS", "1")
    one = simulate_sensors(aligned, models, effects)
    monkeypatch.setenv("HYDROWATCH_THREADS", "2")
    assert simulation_threads() == 2
    np.testing.assert_array_equal(simulate_sensors(aligned, models, effects), one)
