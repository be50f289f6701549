"""A fit ends when its cost stops falling, a converged confirmation is not polished again (issue 12,
item 5: the analysis' time goes to simulations, one batched call per solver iteration), and an accepted
model whose fit still moves is continued before the next round (issue 12, the settle step); a continuation reuses
the simulations that ended its fit (issue 12, eighth pass; now through the recording's kept simulations), and a
fit's own cache keeps the points of the call that fills it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hydrowatch.gap import align as aligning
from hydrowatch.gap import calibrate, hypothesis
from hydrowatch.gap.align import AlignedRecording, align, simulate_sensors
from hydrowatch.gap.calibrate import fit_output_error
from hydrowatch.gap.candidates import CANDIDATES, Refit, holdout_cost
from hydrowatch.gap.simulations import Simulations
from hydrowatch.gap.space import ModelSpace
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate


def test_a_fit_stops_once_its_cost_stops_falling_and_is_then_not_polished_nor_settled() -> None:
    design = PlantParameters()
    unit = design.replace(Kq=design.Kq * 1.15, TL=design.TL * 0.85)
    aligned = align(simulate(filtered_noise(10.0, (-4.0, 4.0), seed=5), unit, None, seed=5))
    space = ModelSpace(design, {}, ("Kq", "TL"))
    fit = fit_output_error(aligned, space, max_nfev=40)
    # Two parameters from 15 % off: the stall rule ends the fit long before 40 iterations, at the unit.
    assert fit.converged
    assert fit.values["Kq"] == pytest.approx(unit.Kq, rel=0.01)
    assert fit.values["TL"] == pytest.approx(unit.TL, rel=0.02)
    cut = fit_output_error(aligned, space, max_nfev=2)
    assert not cut.converged and cut.fit_cost > fit.fit_cost
    candidate = CANDIDATES[0]
    done = Refit(candidate, fit, holdout_cost(aligned, fit.prediction))
    assert hypothesis.polish(aligned, done) is done
    polished = hypothesis.polish(aligned, Refit(candidate, cut, holdout_cost(aligned, cut.prediction)))
    assert polished.fit.converged and polished.fit.fit_cost < cut.fit_cost
    # An accepted model is settled before the next round: continued while its fit still moves, as it is
    # once converged (a later candidate must not be credited with the accepted effect's missing iterations).
    assert hypothesis.settle(aligned, fit) is fit
    settled = hypothesis.settle(aligned, cut)
    assert settled.converged and settled.fit_cost < cut.fit_cost
    assert settled.values["Kq"] == pytest.approx(unit.Kq, rel=0.01)


def test_an_accepted_model_still_moving_after_one_continuation_is_continued_again(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A fit that one continuation of a confirmation's budget leaves still moving is continued again (issue 12,
    fresh population 2061's pair: a backlash fit still fell 7× in its one settle, and round 2 credited its
    next iterations to a 0.15 ms transport delay)."""
    design = PlantParameters()
    unit = design.replace(Kq=design.Kq * 1.25, TL=design.TL * 0.75)
    aligned = align(simulate(filtered_noise(10.0, (-4.0, 4.0), seed=5), unit, None, seed=5))
    space = ModelSpace(design, {}, ("Kq", "TL"))
    monkeypatch.setattr(hypothesis, "JOINT_NFEV", 2)
    cut = fit_output_error(aligned, space, max_nfev=2)
    once = fit_output_error(aligned, space, cut.z, max_nfev=2)
    assert not once.converged
    settled = hypothesis.settle(aligned, cut)
    assert settled.fit_cost < 0.9 * once.fit_cost
    assert abs(settled.values["Kq"] / unit.Kq - 1.0) < abs(once.values["Kq"] / unit.Kq - 1.0)


def _counted(monkeypatch: pytest.MonkeyPatch) -> tuple[AlignedRecording, ModelSpace, list[int]]:
    """A 10 s record of a unit 25 % off the design in Kq and TL, the space of those two, and the list that the
    calibration's simulations append their model counts to."""
    design = PlantParameters()
    unit = design.replace(Kq=design.Kq * 1.25, TL=design.TL * 0.75)
    aligned = align(simulate(filtered_noise(10.0, (-4.0, 4.0), seed=5), unit, None, seed=5))
    models: list[int] = []

    def counted(*args: object, **kwargs: object) -> object:
        models.append(len(args[1]))  # type: ignore[arg-type]
        return simulate_sensors(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(calibrate, "simulate_sensors", counted)
    return aligned, ModelSpace(design, {}, ("Kq", "TL")), models


def test_a_continuation_reuses_the_simulations_that_ended_the_fit_it_continues(monkeypatch: pytest.MonkeyPatch) -> None:
    """A continuation (polish, settle) starts where its fit ended, in the same space: its first Jacobian is the one
    that ended that fit, and the recording's kept simulations give it (issue 12, item 5; gap/simulations.py) — the
    same fit, one simulation per coordinate and one for the point fewer. Another analysis of the same samples (its
    own recording object) simulates them again."""
    aligned, space, _ = _counted(monkeypatch)
    models: list[int] = []
    original = aligning._simulate_models

    def simulated(*args: object) -> object:
        models.append(len(args[1]))  # type: ignore[arg-type]
        return original(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(aligning, "_simulate_models", simulated)
    cut = fit_output_error(aligned, space, max_nfev=2)
    models.clear()
    continued = fit_output_error(aligned, space, cut.z, max_nfev=3)
    with_reuse = sum(models)
    other = replace(aligned, simulations=Simulations())
    models.clear()
    fresh = fit_output_error(other, space, cut.z, max_nfev=3)
    assert sum(models) == with_reuse + 3
    assert fresh.z.tobytes() == continued.z.tobytes() and fresh.fit_cost == continued.fit_cost


def test_a_full_cache_keeps_the_points_of_the_call_that_empties_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """The fit's bounded cache forgets older simulations, not those of the call that overflows it: the Jacobian at
    the solver's point finds that point cached, and the fit's prediction there is not simulated again (issue 12,
    item 5: a fit whose last Jacobian overflowed the cache simulated its end point twice)."""
    aligned, space, models = _counted(monkeypatch)
    objective = calibrate._Objective(aligned, space)
    older = [np.array([0.001 * i, 0.0]) for i in range(64)]
    objective.simulate(older)
    point, step = np.array([0.05, 0.05]), np.array([0.06, 0.05])
    objective.simulate([point])
    models.clear()
    objective.simulate([point, step])  # overflows the cache: the older points go
    assert sum(models) == 1
    objective.simulate([point, step])
    assert sum(models) == 1 and older[0].tobytes() not in objective.cache
