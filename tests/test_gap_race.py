"""A confirmation whose starts disagree on the effect's size races them (issue 12, seed 2063 units 10 and 12:
gear backlash + entrained air, the air confirmed at α 0.003–0.008 of a true 0.085–0.091 because the start the
calibration without the air had fitted — its softer oil in Vt ×2.8 — won the magnitude scan by raw cost; the
remainder was named ``unidentified``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hydrowatch.gap import hypothesis
from hydrowatch.gap.align import align, simulate_sensors
from hydrowatch.gap.calibrate import fit_output_error, prior_weight
from hydrowatch.gap.candidates import CANDIDATES, Refit, holdout_cost, scan_starts
from hydrowatch.gap.space import ModelSpace
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate

AIR = next(c for c in CANDIDATES if c.id == "entrained_air")
TRUE_ALPHA = 0.09


@pytest.fixture(scope="module")
def bent() -> tuple:
    """A recording with entrained air; the model calibrated without it from where such a calibration ends on a
    unit with more to fit (Vt ×2.8, seed 2063 unit 12: its softer oil held in the chamber volume), which stays
    there; and a screening fit of the air on that model."""
    design = PlantParameters()
    rec = simulate(filtered_noise(20.0, (-4.0, 4.0), seed=3), design, {"entrained_air": {"alpha": TRUE_ALPHA}}, seed=3)
    aligned = align(rec)
    free = ("beta_e", "Vt", "Vs", "Ctm", "Kq", "Kr", "Bm", "omega_v", "zeta_v")
    nominal = simulate_sensors(aligned, [design], [{}])[0]
    space = ModelSpace(design.replace(Vt=2.8 * design.Vt), {}, free, (), design, prior_weight(aligned, nominal))
    current = fit_output_error(aligned, space, max_nfev=15)
    small = {"entrained_air": {"alpha": 0.003, "n": 1.4}}
    screened = fit_output_error(aligned, ModelSpace(current.parameters, small, (), (("entrained_air", "alpha"),)),
                                max_nfev=4)
    return aligned, design, current, Refit(AIR, screened, holdout_cost(aligned, screened.prediction))


def test_the_calibration_without_the_air_bends_the_volumes(bent: tuple) -> None:
    _, design, current, _ = bent
    # The premise of the race: what the air does stays in the plant (the ratio βe/Vt that the sensors see).
    softness = (current.parameters.beta_e / current.parameters.Vt) / (design.beta_e / design.Vt)
    assert softness < 0.5


def test_a_refined_scan_finds_a_magnitude_between_grid_points(bent: tuple) -> None:
    aligned, design, current, _ = bent
    coarse = replace(AIR, scan=(0.01, 0.16))
    plain = scan_starts(aligned, current, coarse, [design], plain_origins=False, reset=("beta_e", "Vt", "Vs"))
    refined = scan_starts(aligned, current, coarse, [design], plain_origins=False, reset=("beta_e", "Vt", "Vs"),
                          refine=True)
    reset_start = 1
    assert plain[reset_start][1] in (0.01, 0.16)
    assert refined[reset_start][1] == pytest.approx(np.sqrt(0.01 * 0.16))
    assert refined[reset_start][2] < plain[reset_start][2]


def test_the_start_with_the_stand_ins_set_back_races_and_wins(bent: tuple, caplog: pytest.LogCaptureFixture) -> None:
    aligned, design, current, screened = bent
    refit = hypothesis.recalibrate(aligned, current, screened, design, design_start=False)
    alpha = refit.fit.effects["entrained_air"]["alpha"]
    assert alpha == pytest.approx(TRUE_ALPHA, rel=0.25)
    assert refit.fit.parameters.Vt == pytest.approx(design.Vt, rel=0.25)
    # Without the stand-ins the only starts are the bent model and βe set back: the air stays small.
    alone = replace(screened, candidate=replace(AIR, stand_ins=()))
    stuck = hypothesis.recalibrate(aligned, current, alone, design, design_start=False)
    assert stuck.fit.effects["entrained_air"]["alpha"] < 0.3 * TRUE_ALPHA
    assert stuck.fit.fit_cost > 1.4 * refit.fit.fit_cost


def test_a_start_that_loses_the_scan_by_raw_cost_but_leads_after_a_few_iterations_wins_the_race(
        bent: tuple, monkeypatch: pytest.MonkeyPatch) -> None:
    """On seed 2063 unit 12 the start with the stand-ins set back lost the scan by raw cost (0.035 against a fitted
    model's 0.005) and led after 6 iterations; here its scan cost is made to lose the same way."""
    aligned, design, current, screened = bent
    scan = hypothesis.scan_starts

    def fitted_start_ahead(*args: object, **kwargs: object) -> list:
        found = scan(*args, **kwargs)  # type: ignore[arg-type]
        return [found[0], *((params, value, found[0][2] + 1.0) for params, value, _ in found[1:])]

    monkeypatch.setattr(hypothesis, "scan_starts", fitted_start_ahead)
    raced = hypothesis.recalibrate(aligned, current, screened, design, design_start=False)
    assert raced.fit.effects["entrained_air"]["alpha"] == pytest.approx(TRUE_ALPHA, rel=0.25)
    monkeypatch.setattr(hypothesis, "RACE_RATIO", float("inf"))
    unraced = hypothesis.recalibrate(aligned, current, screened, design, design_start=False)
    assert unraced.fit.effects["entrained_air"]["alpha"] < 0.3 * TRUE_ALPHA
