"""Greedy selection of missing physics: add the effect that pays most, while effects pay.

Each round screens every remaining candidate on the first SCREEN_SECONDS of the record (a
magnitude scan in one batched simulation, then a short fit of the effect's parameters and its
partner plant parameters; an effect without partners is dropped when no magnitude helps),
refits the best ``confirm`` of them on the whole record jointly with the plant parameters, and
accepts the best one only if all of these hold (gap-method.md, step 4):

* the held-out cost falls by at least ``min_gain`` (relative), or the effect removes ``majority`` of the error
  above the noise ceiling (:func:`~hydrowatch.gap.judge.pays`), and consistently: the mean over 1 s
  held-out blocks of ln(J₁/J₀) lies more than ``n_se`` standard errors below zero (a real effect
  lowers the cost in every block, by much where the record excites it and by little elsewhere; a
  test on the raw cost difference is dominated by the few blocks that excite a local effect —
  the stops for friction — and rejected true effects);
* it removes at least ``min_explained`` of the held-out error above the noise ceiling, and no
  sensor's held-out error rises by more than ``max_worse`` (a real effect helps where the catalog
  says it shows and hurts nowhere; a sensor fault or unknown physics is not bent into an effect);
* the information criterion agrees: ΔBIC = n_eff·ln(J₁/J₀) + Δk·ln(n_eff) < −``min_bic`` on the
  fitting blocks, n_eff the sample count shrunk by the residual's lag-1 autocorrelation
  (a prewhitening correction).

* the 95 % interval of the effect's main parameter excludes the value at which the effect vanishes
  (a dead time or sensor lag: every value below a quarter of a sample interval, candidates.RESOLVABLE_SAMPLES),
  and the recording reaches the fitted effect (:meth:`Candidate.exercised`: a travel limit above
  every command is rejected);
* from the second round on, the sensor whose held-out error falls most is one the catalog says the
  effect shows in (plant-model.md, "where it shows").

An accepted model is polished (its joint fit continued to convergence) before the next round, so a
later candidate is not credited with what more iterations of the earlier fit would have found
(the false second effects of round 1: quadratic drag "explaining" an unconverged backlash fit); the
winner's fit, if still moving after the polish, is continued as many iterations at a time as a later
confirmation gets until it stops moving, at most hypothesis.SETTLE_RUNS times (:func:`hypothesis.settle`).
When no candidate passes but one paid only through the plant parameters refitted with it (its
effect indistinguishable from absent), the current model takes those values (:func:`_absorb`) and,
since that round was judged against an unconverged model, the candidates get another round.
After an effect joins a model that holds others, an earlier one that it makes redundant is dropped
(:func:`~hydrowatch.gap.backward.prune`, the backward step of a stepwise selection); the candidates that
passed beside a dropped effect in the round it won are confirmed in the next round wherever they screen
(:func:`~hydrowatch.gap.backward.owed`).
When a round passes nothing and absorbs nothing while the model still fails the discovery test, the
candidates it did not confirm get a **second look** before the remainder is left to ``unidentified``:
screened again with every calibrated plant parameter free, against the current model refitted the same
way (screen.py), and the best ``confirm`` of those that beat it by ``min_gain`` are confirmed and judged as above.
The loop stops when no candidate passes, none was absorbed and the second look passes none, when the
model passes the discovery test (discovery.py), or when ``max_effects`` are in the model (at most
2·``max_effects`` rounds, a second look counted as one).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.backward import owed, prune
from hydrowatch.gap.calibrate import OutputErrorFit, fit_output_error
from hydrowatch.gap.candidates import Candidate, Refit, Scan, untestable
from hydrowatch.gap.discovery import residual_test
from hydrowatch.gap.hypothesis import polish, recalibrate, settle
from hydrowatch.gap.judge import judge, pays
from hydrowatch.gap.locate import whiteness
from hydrowatch.gap.screen import Screened, screen
from hydrowatch.gap.side_by_side import side_by_side
from hydrowatch.log import event, get_logger
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.recording import SENSORS

log = get_logger(__name__)

ABSORB_NFEV = 10
"""Solver iterations of :func:`_absorb`'s refit."""

WHITE_LIMIT = 3.0
"""Normalised Ljung–Box statistic below which a held-out residual counts as white noise."""


def residual_is_white(aligned: AlignedRecording, prediction: np.ndarray) -> bool:
    """True when every sensor's held-out residual is white (below WHITE_LIMIT): nothing left to explain."""
    residual = aligned.measured[:, aligned.holdout_mask] - prediction[:, aligned.holdout_mask]
    return all(whiteness(r) < WHITE_LIMIT for r in residual)


@dataclass(frozen=True)
class Trial:
    """One candidate judged in one round.

    Attributes
    ----------
    refit : Refit
    gain : float
        Relative drop of the held-out cost against the current model (negative: worse).
    gain_se : float
        Block-bootstrap standard error of that drop (relative).
    consistency : float
        −mean(ln J₁/J₀) over 1 s held-out blocks divided by its standard error (a z-score).
    delta_bic : float
        BIC of the candidate minus BIC of the current model (negative favours the candidate).
    explained : float
        Share of the held-out cost above the noise ceiling the candidate removes.
    worst_sensor : float
        Largest relative rise of one sensor's held-out mean square error.
    improved : str
        Sensor whose held-out error falls most.
    distinct : bool
        The 95 % interval of the effect's main parameter excludes the value at which it vanishes.
    passed : bool
        Whether it met every acceptance rule (the round adds the passing trial with the largest gain).
    """

    refit: Refit
    gain: float
    gain_se: float
    consistency: float
    delta_bic: float
    explained: float
    worst_sensor: float
    improved: str
    distinct: bool
    passed: bool


@dataclass
class Diagnosis:
    """Outcome of :func:`diagnose`.

    Attributes
    ----------
    final : OutputErrorFit
        The calibrated model with every accepted effect.
    accepted : list of Trial
        Accepted effects, in the order they were added (most important first).
    rounds : list of list of Trial
        Every trial per round (screened candidates carry their screening fit).
    unrevealable : dict of str to str
        Candidates this recording cannot show, with the experiment that would.
    scanned_out : list of list of str
        Per round, the candidates no magnitude of which lowered the fitting cost (not fitted further).
    dropped : list of str
        Effects accepted in an earlier round and dropped once a later one made them redundant
        (:func:`~hydrowatch.gap.backward.prune`).
    """

    final: OutputErrorFit
    accepted: list[Trial] = field(default_factory=list)
    rounds: list[list[Trial]] = field(default_factory=list)
    unrevealable: dict[str, str] = field(default_factory=dict)
    scanned_out: list[list[str]] = field(default_factory=list)
    dropped: list[str] = field(default_factory=list)


def _trial(refit: Refit, j: dict[str, float], passed: bool) -> Trial:
    return Trial(refit, j["gain"], j["gain_se"], j["consistency"], j["delta_bic"], j["explained"], j["worst_sensor"],
                 SENSORS[int(j["improved"])], refit.candidate.distinct_from_absence(refit.fit), passed)


def _absorb(aligned: AlignedRecording, current: OutputErrorFit, trials: list[Trial], min_gain: float, n_se: float
            ) -> OutputErrorFit:
    """The current model refitted from the plant parameters of the best trial that paid only through them.

    A confirmed candidate whose effect came out indistinguishable from absent but which still lowered
    the held-out cost clearly shows that the current model's joint fit had not converged: keep its plant
    (and accepted effects') values, drop the candidate, and refit briefly (else that remainder would be
    reported as unidentified physics).
    """
    confirmed = [t for t in trials if _is_confirmation(t, current)]
    absorbed = [t for t in confirmed if not t.distinct and t.gain >= min_gain and t.consistency > n_se]
    if not absorbed:
        return current
    best = max(absorbed, key=lambda t: t.gain).refit
    effects = {k: dict(v) for k, v in best.fit.effects.items() if k != best.candidate.id}
    space = replace(current.space, base=best.fit.parameters, effects=effects)
    refitted = fit_output_error(aligned, space, max_nfev=ABSORB_NFEV)
    event(log, "absorbed", effect=best.candidate.label, before=current.fit_cost, after=refitted.fit_cost)
    return refitted if refitted.fit_cost < current.fit_cost else current


CONFIRM_SHARE = 0.5
"""A runner-up is confirmed after a passing leader only when its screening gain is at least this share
of the leader's (issue 12, item 5: each confirmation is a full calibration, 40 % of the CPU time of a
strong effect's analysis before this rule; the winner is the passing confirmation with the largest
held-out gain, which a runner-up screened at under half the leader's gain is unlikely to be)."""


def _worth_confirming(trials: list[Trial], screen_gain: float, lead: float, candidate: Candidate) -> bool:
    """Whether a screened candidate gets its full calibration: always when no earlier confirmation
    passed; after a passing one when its screening gain is ≥ CONFIRM_SHARE of the leader's, or when it
    shares a partner parameter with the passing leader (effects that bend the same plant parameters
    stand in for each other, and the screening's short fits rank them poorly: shaft compliance
    screened ahead of gear backlash at more than twice its gain on populations 2031, 2034 and 2035,
    and a calibration with compliance alone then passed)."""
    passed = [t for t in trials if t.passed]
    if not passed:
        return True
    shared = any(set(candidate.partners) & set(t.refit.candidate.partners) for t in passed)
    return shared or screen_gain >= CONFIRM_SHARE * lead


def _sure_to_confirm(screened: list[Screened], confirm: int, floor: float) -> list[int]:
    """The ranks among the first ``confirm`` screened that get their full calibration whatever the confirmations
    before them find (:func:`_worth_confirming` holds for every outcome of theirs: a gain above ``floor`` and at least
    CONFIRM_SHARE of the leader's, or a partner shared with every candidate ranked before): these run side by side."""
    lead = screened[0][0] if screened else 0.0
    sure = []
    for rank, (gain, s, _, _) in enumerate(screened[:confirm]):
        before = [set(e[1].candidate.partners) for e in screened[:rank]]
        if gain > floor and (gain >= CONFIRM_SHARE * lead or all(set(s.candidate.partners) & b for b in before)):
            sure.append(rank)
    return sure


def _is_confirmation(trial: Trial, current: OutputErrorFit) -> bool:
    """Whether a first-look trial carries a full calibration (every plant parameter, whole record), not a screen."""
    return (trial.refit.fit.space.plant_free == current.space.plant_free
            and trial.refit.fit.prediction.shape == current.prediction.shape)


def diagnose(
    aligned: AlignedRecording,
    calibrated: OutputErrorFit,
    candidates: list[Candidate],
    *,
    max_effects: int = 3,
    confirm: int = 2,
    min_gain: float = 0.03,
    n_se: float = 2.0,
    min_bic: float = 10.0,
    min_explained: float = 0.2,
    majority: float = 0.5,
    max_worse: float = 0.1,
    origins: Sequence[PlantParameters] = (),
    nominal: PlantParameters | None = None,
) -> Diagnosis:
    """Add catalog effects greedily to the calibrated model while they pay (see module docstring).

    Parameters
    ----------
    aligned : AlignedRecording
    calibrated : OutputErrorFit
        The nominal structure with calibrated parameters.
    candidates : list of Candidate
        Hypotheses to try.
    max_effects : int, default 3
    confirm : int, default 2
        How many of the best screened candidates get the joint refit with the plant parameters (in a round and
        in its second look).
    min_gain : float, default 0.03
        Smallest relative drop of the held-out cost that counts.
    n_se : float, default 2.0
        The mean per-block log drop of the held-out cost must exceed this many standard errors.
    min_bic : float, default 10.0
        Required BIC decrease.
    min_explained : float, default 0.2
        Smallest share of the held-out error above the noise ceiling the effect must remove.
    majority : float, default 0.5
        A share of that error whose removal passes the gain rule whatever the total's drop (:func:`pays`).
    max_worse : float, default 0.1
        Largest relative rise of any one sensor's held-out error the effect may cause.
    origins : sequence of PlantParameters, default ()
        Other starting plant parameters for the candidates' scans (the nominal ones).
    nominal : PlantParameters, optional
        The design values a confirmed candidate's calibration starts from (default: ``origins[0]``,
        else the calibrated parameters).
    """
    nominal = nominal or (origins[0] if origins else None)
    diagnosis = Diagnosis(calibrated, unrevealable=untestable(candidates, aligned, calibrated.prediction[1]))
    testable = [c for c in candidates if c.label not in diagnosis.unrevealable]
    current = calibrated
    owing: frozenset[str] = frozenset()

    def confirm_ranked(screened: list[Screened], floor: float = 0.0, due: frozenset[str] = frozenset()
                       ) -> list[Trial]:
        """The round's trials: the best ``confirm`` screened at a gain > ``floor`` get the full calibration under
        their hypothesis (:func:`_worth_confirming`) and the acceptance rules, and so do the labels in ``due``
        (backward.owed) wherever they rank; the others keep their screening fit."""
        trials: list[Trial] = []
        lead = screened[0][0] if screened else 0.0

        def full_calibration(s: Refit) -> Refit:
            return recalibrate(aligned, current, s, nominal, calibrated.parameters.Dp,
                               design_start=not diagnosis.accepted)

        sure = _sure_to_confirm(screened, confirm, floor) if len(screened) > 1 else []
        ahead = dict(zip(sure, side_by_side([partial(full_calibration, screened[r][1]) for r in sure])))
        for rank, (screen_gain, s, data, base) in enumerate(screened):
            if s.candidate.label in due or (rank < confirm and screen_gain > floor
                                            and _worth_confirming(trials, screen_gain, lead, s.candidate)):
                full = ahead[rank] if rank in ahead else full_calibration(s)
                j = judge(aligned, current, full)
                trial = _trial(full, j, False)
                ok = (pays(j, min_gain, majority) and j["consistency"] > n_se and j["delta_bic"] < -min_bic
                      and j["explained"] >= min_explained and j["worst_sensor"] <= max_worse and trial.distinct
                      and full.candidate.exercised(full.fit, aligned.voltage[aligned.used_mask])
                      and (not diagnosis.accepted or trial.improved in full.candidate.sensors))
                trial = replace(trial, passed=bool(ok))
            else:
                trial = _trial(s, judge(data, base, s), False)
            trials.append(trial)
            event(log, "candidate judged", effect=s.candidate.label, passed=trial.passed, gain=round(trial.gain, 4),
                  explained=round(trial.explained, 3), delta_bic=round(trial.delta_bic, 1),
                  screen_gain=round(screen_gain, 4))
        return trials

    while len(diagnosis.accepted) < max_effects and len(diagnosis.rounds) < 2 * max_effects:
        if diagnosis.rounds and not residual_test(aligned, current.prediction, len(current.z)).fails:
            break
        present = set(current.effects) | {c.id for c in testable if c.label in diagnosis.dropped}
        pool = [c for c in testable if c.id not in present]
        if not pool:
            break
        scans: dict[str, Scan] = {}
        screened, out = screen(aligned, current, pool, origins, scans=scans)
        diagnosis.scanned_out.append(out)
        trials = confirm_ranked(screened, due=owing)
        owing = frozenset()
        diagnosis.rounds.append(trials)
        passed = [t for t in trials if t.passed]
        if not passed:
            absorbed = _absorb(aligned, current, trials, min_gain, n_se)
            if absorbed is not current:
                # The round was judged against a model whose fit had not converged (a confirmation paid through
                # the plant alone): judge the remaining candidates again against the absorbed model.
                current = absorbed
                continue
            if not residual_test(aligned, current.prediction, len(current.z)).fails:
                break
            # Second look: the quick screen refits only the candidates' partners, and a plant calibrated
            # without the effect can hold it in parameters that are no partner (screen.py).
            confirmed = {t.refit.candidate.label for t in trials if _is_confirmation(t, current)}
            screened, _ = screen(aligned, current, [c for c in pool if c.label not in confirmed], origins,
                                  plant_free=current.space.plant_free, scans=scans)
            diagnosis.scanned_out.append([])
            # Its screen refits what the confirmation refits: one that gains less than an effect must is not
            # confirmed (2035 entrained air alone: valve hysteresis at +0.02 %, 40 s of CPU, failed).
            trials = confirm_ranked(screened, floor=min_gain)
            diagnosis.rounds.append(trials)
            passed = [t for t in trials if t.passed]
            if not passed:
                break
        polished = dict(zip(map(id, passed), side_by_side([partial(polish, aligned, t.refit) for t in passed])))
        if len(passed) > 1:
            # Rivals are compared polished: an unconverged confirmation (a backlash fit that used every
            # iteration) lost to compliance on dev population 7, and won the next round by 98 %.
            gains = {id(t): judge(aligned, current, polished[id(t)])["gain"] for t in passed}
            winner = max(passed, key=lambda t: gains[id(t)])
        else:
            winner = passed[0]
        diagnosis.accepted.append(winner)
        dropped = len(diagnosis.dropped)
        current = prune(aligned, diagnosis, settle(aligned, polished[id(winner)].fit), min_gain, n_se, min_bic,
                        majority)
        owing = frozenset(owed(diagnosis, diagnosis.dropped[dropped:], current))
        if owing:
            event(log, "owed a confirmation", effects=sorted(owing), dropped=diagnosis.dropped[dropped:])
    diagnosis.final = current
    return diagnosis

