"""Independent steps of an analysis run side by side, and a fit's single simulations take some of its Jacobian's
along, with the same numbers (issue 12, item 5: "under 5 minutes on 2 cores")."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from hydrowatch.gap import align as aligning
from hydrowatch.gap.align import align
from hydrowatch.gap.calibrate import OutputErrorFit, fit_output_error
from hydrowatch.gap.side_by_side import side_by_side
from hydrowatch.gap.space import ModelSpace
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate

DESIGN = PlantParameters()
UNIT = DESIGN.replace(Kq=DESIGN.Kq * 1.15, TL=DESIGN.TL * 0.85, BL=DESIGN.BL * 1.2)


def test_steps_run_at_the_same_time_on_two_threads_and_one_after_the_other_on_one(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HYDROWATCH_THREADS", "2")
    meet = threading.Barrier(2, timeout=10.0)  # broken (an error) unless both steps wait at once

    def step(value: int) -> tuple[int, str]:
        meet.wait()
        return value, threading.current_thread().name

    done = side_by_side([lambda: step(1), lambda: step(2)])
    assert [v for v, _ in done] == [1, 2] and done[0][1] != done[1][1]
    monkeypatch.setenv("HYDROWATCH_THREADS", "1")
    ran: list[int] = []
    assert side_by_side([lambda: ran.append(1) or 1, lambda: ran.append(2) or 2]) == [1, 2]
    assert ran == [1, 2]


def test_a_failing_step_raises_its_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HYDROWATCH_THREADS", "2")

    def fails() -> int:
        raise ValueError("step failed")

    with pytest.raises(ValueError, match="step failed"):
        side_by_side([lambda: 1, fails])


def _fit(monkeypatch: pytest.MonkeyPatch, threads: str) -> tuple[OutputErrorFit, list[int]]:
    """A three-parameter fit on a fresh 10 s recording, and the models of each batched simulation it made."""
    monkeypatch.setenv("HYDROWATCH_THREADS", threads)
    aligned = align(simulate(filtered_noise(10.0, (-4.0, 4.0), seed=8), UNIT, None, seed=8))
    models: list[int] = []
    original = aligning._simulate_models

    def counted(aligned: aligning.AlignedRecording, params: list, effects: list, stop: int | None) -> np.ndarray:
        models.append(len(params))
        return original(aligned, params, effects, stop)

    monkeypatch.setattr(aligning, "_simulate_models", counted)
    fit = fit_output_error(aligned, ModelSpace(DESIGN, {}, ("Kq", "TL", "BL")), max_nfev=8)
    monkeypatch.setattr(aligning, "_simulate_models", original)
    return fit, models


def test_a_fit_takes_its_jacobian_along_with_the_same_numbers(monkeypatch: pytest.MonkeyPatch) -> None:
    """The start's residuals come with its whole Jacobian (the solver asks for it next), a trial step's with the
    one perturbation (3 mod 2) that the next Jacobian's batch would leave one thread to run alone; the fit is the
    same bit for bit as on one thread."""
    alone, one = _fit(monkeypatch, "1")
    fit, two = _fit(monkeypatch, "2")
    assert one[0] == 4 and set(one[1:]) <= {1, 3} and 3 in one  # on one thread: a trial alone, then its Jacobian
    # On two threads: the start's 4 models, then every trial and every Jacobian two models, one per thread.
    assert two[0] == 4 and set(two[1:]) == {2} and len(two) >= 6
    assert np.array_equal(fit.z, alone.z) and np.array_equal(fit.prediction, alone.prediction)
    assert np.array_equal(fit.covariance, alone.covariance) and fit.fit_cost == alone.fit_cost
    assert fit.values["Kq"] == pytest.approx(UNIT.Kq, rel=0.02)
