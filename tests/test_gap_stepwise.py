"""The backward step of the greedy diagnosis (issue 12): an effect accepted in an earlier round is dropped
when the one added later makes it redundant, and kept when the model still needs it.

Synthetic predictions on a 24 s time base (the judge test's layout in test_gap_analysis.py): the
"truth" is three smooth signals, the measured ones add white noise of 5 % and a torque ripple.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from hydrowatch.gap import diagnose as stepwise
from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.candidates import CANDIDATES, Refit
from hydrowatch.gap.diagnose import Diagnosis, Trial

N = 24 * 200
T = np.arange(N) / 200.0
TRUTH = np.vstack([np.sin(T), np.cos(0.7 * T), np.sin(1.3 * T)])
RIPPLE = np.vstack([0 * T, 0 * T, 0.2 * np.sin(2 * np.pi * 3.1 * T)])


def _aligned() -> AlignedRecording:
    rng = np.random.default_rng(11)
    measured = TRUTH + RIPPLE + 0.05 * rng.standard_normal(TRUTH.shape)
    block = np.maximum(np.arange(N) - 200, 0) // 600
    holdout = (np.arange(N) >= 200) & (block % 3 == 1)
    return AlignedRecording(T, np.ones(N), measured, measured.std(axis=1), (np.arange(N) >= 200) & ~holdout,
                            holdout, "synthetic")


def _model(aligned: AlignedRecording, prediction: np.ndarray, k: int, effects: tuple[str, ...]) -> SimpleNamespace:
    r = (aligned.measured - prediction) / aligned.scale[:, None]
    return SimpleNamespace(prediction=prediction, z=np.zeros(k), effects=dict.fromkeys(effects, {}),
                           fit_cost=float(np.sum(r[:, aligned.fit_mask] ** 2) / aligned.fit_mask.sum()))


def _trial(effect: str, fit: SimpleNamespace) -> Trial:
    candidate = next(c for c in CANDIDATES if c.id == effect)
    return Trial(Refit(candidate, fit, 0.0), 0.5, 0.01, 5.0, -100.0, 0.9, 0.0, "torque", True, True)


def test_an_effect_the_later_one_explains_is_dropped_and_one_still_needed_is_kept(
        monkeypatch: pytest.MonkeyPatch) -> None:
    aligned = _aligned()
    current = _model(aligned, TRUTH + RIPPLE, 22, ("shaft_compliance", "gear_backlash"))
    # Without compliance the model is as good as with it (backlash explains the ripple): 2 fewer parameters.
    redundant = _model(aligned, TRUTH + RIPPLE + 0.002 * np.sin(0.3 * T), 20, ("gear_backlash",))
    needed, j = stepwise._still_needed(aligned, redundant, current, _trial("shaft_compliance", current).refit.candidate,
                                       0.03, 2.0, 10.0)
    assert not needed and abs(j["gain"]) < 0.03
    # Without the ripple's effect the held-out cost rises by far more than 3 %, consistently.
    lacking = _model(aligned, TRUTH, 21, ("shaft_compliance",))
    needed, j = stepwise._still_needed(aligned, lacking, current, _trial("gear_backlash", current).refit.candidate,
                                       0.03, 2.0, 10.0)
    assert needed and j["gain"] > 0.3 and j["delta_bic"] < -100

    calls = []

    def without(aligned_: AlignedRecording, fit: SimpleNamespace, effect_id: str) -> SimpleNamespace:
        calls.append(effect_id)
        return redundant if effect_id == "shaft_compliance" else lacking

    monkeypatch.setattr(stepwise, "_without", without)
    diagnosis = Diagnosis(current, accepted=[_trial("shaft_compliance", current), _trial("gear_backlash", current)])
    final = stepwise._prune(aligned, diagnosis, current, 0.03, 2.0, 10.0)  # type: ignore[arg-type]
    assert final is redundant
    assert [t.refit.candidate.id for t in diagnosis.accepted] == ["gear_backlash"]
    assert diagnosis.dropped == ["shaft_compliance"]
    assert calls == ["shaft_compliance"]  # the effect added last is not judged against itself

    # With compliance needed too, nothing is dropped.
    monkeypatch.setattr(stepwise, "_without", lambda *args: lacking)
    diagnosis = Diagnosis(current, accepted=[_trial("shaft_compliance", current), _trial("gear_backlash", current)])
    assert stepwise._prune(aligned, diagnosis, current, 0.03, 2.0, 10.0) is current  # type: ignore[arg-type]
    assert len(diagnosis.accepted) == 2 and diagnosis.dropped == []


def test_a_round_judged_against_an_unconverged_model_is_judged_again_after_the_absorb(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """When no candidate passes but one paid through the plant alone (_absorb: the current fit had not
    converged), the candidates get another round against the absorbed model; when nothing is absorbed the
    diagnosis ends (issue 12, dev population 2035: the round after a backlash fit still moving was the
    last, and the air it had screened against that fit was never tried again)."""
    @dataclass(frozen=True)
    class Fit:  # what diagnose reads of a model before any candidate is refitted
        prediction: np.ndarray
        effects: dict
        z: np.ndarray

    aligned = _aligned()
    unconverged = Fit(TRUTH, {"gear_backlash": {}}, np.zeros(20))
    absorbed = Fit(TRUTH + 0.5 * RIPPLE, {"gear_backlash": {}}, np.zeros(20))
    candidates = [c for c in CANDIDATES if c.id in ("entrained_air", "transport_delay")]
    screened = []

    def scanned_out(data: AlignedRecording, base: Fit, c: object, **kwargs: object) -> None:
        screened.append(base.prediction[2, 10])
        return None  # no magnitude lowers the cost: no trial, nothing passes

    monkeypatch.setattr(stepwise, "refit", scanned_out)
    monkeypatch.setattr(stepwise, "residual_test", lambda *args: SimpleNamespace(fails=True))
    monkeypatch.setattr(stepwise, "_absorb", lambda a, current, *args: absorbed if current is unconverged else current)
    diagnosis = stepwise.diagnose(aligned, unconverged, candidates)  # type: ignore[arg-type]
    assert diagnosis.final is absorbed
    assert len(diagnosis.rounds) == 2
    # Round 2 screened against the absorbed model (its own prediction), round 1 against the unconverged one.
    assert screened == [unconverged.prediction[2, 10]] * 2 + [absorbed.prediction[2, 10]] * 2

    monkeypatch.setattr(stepwise, "_absorb", lambda a, current, *args: current)
    diagnosis = stepwise.diagnose(aligned, unconverged, candidates)  # type: ignore[arg-type]
    assert diagnosis.final is unconverged and len(diagnosis.rounds) == 1
