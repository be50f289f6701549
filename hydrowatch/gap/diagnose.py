"""Greedy selection of missing physics: add the effect that pays most, while effects pay.

Each round screens every remaining candidate on the first SCREEN_SECONDS of the record (a
magnitude scan in one batched simulation, then a short fit of the effect's parameters and its
partner plant parameters; an effect without partners is dropped when no magnitude helps),
refits the best ``confirm`` of them on the whole record jointly with the plant parameters, and
accepts the best one only if all of these hold (gap-method.md, step 4):

* the held-out cost falls by at least ``min_gain`` (relative) and by more than ``n_se`` block
  bootstrap standard errors of the per-sample cost difference;
* it removes at least ``min_explained`` of the held-out error above the noise ceiling, and no
  sensor's held-out error rises by more than ``max_worse`` (a real effect helps where the catalog
  says it shows and hurts nowhere; a sensor fault or unknown physics is not bent into an effect);
* the information criterion agrees: ΔBIC = n_eff·ln(J₁/J₀) + Δk·ln(n_eff) < −``min_bic`` on the
  fitting blocks, n_eff the sample count shrunk by the residual's lag-1 autocorrelation
  (a prewhitening correction).

The loop stops when no candidate passes, when the held-out residual of every sensor is white, or
when ``max_effects`` are in the model.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.calibrate import CALIBRATED, OutputErrorFit, _effective_fraction
from hydrowatch.gap.candidates import (
    SCREEN_SECONDS,
    SLOW_EFFECTS,
    Candidate,
    Refit,
    holdout_cost,
    refit,
    untestable,
)
from hydrowatch.gap.locate import noise_std, whiteness
from hydrowatch.log import event, get_logger
from hydrowatch.plant.parameters import PlantParameters

log = get_logger(__name__)

BLOCK_SAMPLES = 200
"""Block length of the held-out bootstrap, samples (1 s)."""

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
    delta_bic : float
        BIC of the candidate minus BIC of the current model (negative favours the candidate).
    explained : float
        Share of the held-out cost above the noise ceiling the candidate removes.
    worst_sensor : float
        Largest relative rise of one sensor's held-out mean square error.
    passed : bool
        Whether it met every acceptance rule (the round adds the passing trial with the largest gain).
    """

    refit: Refit
    gain: float
    gain_se: float
    delta_bic: float
    explained: float
    worst_sensor: float
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
    """

    final: OutputErrorFit
    accepted: list[Trial] = field(default_factory=list)
    rounds: list[list[Trial]] = field(default_factory=list)
    unrevealable: dict[str, str] = field(default_factory=dict)
    scanned_out: list[list[str]] = field(default_factory=list)


def _normalised_sq_error(aligned: AlignedRecording, prediction: np.ndarray, mask: np.ndarray) -> np.ndarray:
    e = (aligned.measured[:, mask] - prediction[:, mask]) / aligned.scale[:, None]
    return np.sum(e**2, axis=0)


def judge(aligned: AlignedRecording, current: OutputErrorFit, candidate: Refit) -> dict[str, float]:
    """How much ``candidate`` improves on ``current``.

    Returns
    -------
    dict
        ``gain`` (relative drop of the held-out cost), ``gain_se`` (its block-bootstrap standard
        error), ``delta_bic`` (fitting blocks, n_eff-corrected), ``explained`` (share of the held-out
        cost above the noise ceiling that the candidate removes) and ``worst_sensor`` (largest
        relative rise of one sensor's held-out mean square error; a real effect does not make a
        sensor worse).
    """
    mask = aligned.holdout_mask
    e0 = _normalised_sq_error(aligned, current.prediction, mask)
    e1 = _normalised_sq_error(aligned, candidate.fit.prediction, mask)
    d = e0 - e1
    j0 = holdout_cost(aligned, current.prediction)
    n_blocks = max(d.size // BLOCK_SAMPLES, 2)
    blocks = np.array([b.mean() for b in np.array_split(d, n_blocks)])
    se = float(blocks.std(ddof=1) / math.sqrt(n_blocks)) / j0
    fm = aligned.fit_mask
    r = ((aligned.measured[:, fm] - current.prediction[:, fm]) / aligned.scale[:, None]).ravel()
    n_eff = r.size * _effective_fraction(r, aligned.measured.shape[0])
    dk = len(candidate.fit.z) - len(current.z)
    delta_bic = n_eff * math.log(candidate.fit.fit_cost / current.fit_cost) + dk * math.log(n_eff)
    used = aligned.used_mask
    noise = sum(
        min(noise_std(aligned.measured[i, used] - p[i, used]) for p in (current.prediction, candidate.fit.prediction))
        ** 2 / aligned.scale[i] ** 2 for i in range(aligned.measured.shape[0]))
    per0 = np.mean(((aligned.measured[:, mask] - current.prediction[:, mask]) / aligned.scale[:, None]) ** 2, axis=1)
    per1 = np.mean(((aligned.measured[:, mask] - candidate.fit.prediction[:, mask]) / aligned.scale[:, None]) ** 2,
                   axis=1)
    return {"gain": float(d.mean()) / j0, "gain_se": se, "delta_bic": float(delta_bic),
            "explained": float(d.mean() / max(j0 - noise, 1e-12)), "worst_sensor": float(np.max(per1 / per0 - 1.0))}


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
    max_worse: float = 0.1,
    origins: Sequence[PlantParameters] = (),
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
        How many of the best screened candidates get the joint refit with the plant parameters.
    min_gain : float, default 0.03
        Smallest relative drop of the held-out cost that counts.
    n_se : float, default 2.0
        The drop must exceed this many bootstrap standard errors.
    min_bic : float, default 10.0
        Required BIC decrease.
    min_explained : float, default 0.2
        Smallest share of the held-out error above the noise ceiling the effect must remove.
    max_worse : float, default 0.1
        Largest relative rise of any one sensor's held-out error the effect may cause.
    origins : sequence of PlantParameters, default ()
        Other starting plant parameters for the candidates' scans (the nominal ones).
    """
    diagnosis = Diagnosis(calibrated, unrevealable=untestable(candidates, aligned, calibrated.prediction[1]))
    testable = [c for c in candidates if c.label not in diagnosis.unrevealable]
    current = calibrated
    while len(diagnosis.accepted) < max_effects:
        if diagnosis.accepted and residual_is_white(aligned, current.prediction):
            break
        present = set(current.effects)
        pool = [c for c in testable if c.id not in present]
        if not pool:
            break
        head = aligned.head(SCREEN_SECONDS)
        screened: list[tuple[float, Refit, AlignedRecording, OutputErrorFit]] = []
        out = []
        for c in pool:
            data = aligned if c.id in SLOW_EFFECTS else head
            base = replace(current, prediction=current.prediction[:, : data.t.size])
            r = refit(data, base, c, plant_free=c.partners, max_nfev=6, origins=origins,
                      require_gain=not c.partners)
            if r is None:
                out.append(c.label)
                continue
            screen_gain = 1.0 - r.holdout_cost / holdout_cost(data, base.prediction)
            screened.append((screen_gain, r, data, base))
        diagnosis.scanned_out.append(out)
        screened.sort(key=lambda item: -item[0])
        trials = []
        for rank, (screen_gain, s, data, base) in enumerate(screened):
            if rank < confirm and screen_gain > 0:
                full = refit(aligned, replace(current, parameters=s.fit.parameters), s.candidate,
                             plant_free=CALIBRATED, max_nfev=10, start_effect=s.fit.effects[s.candidate.id])
                assert full is not None
                j = judge(aligned, current, full)
                ok = (j["gain"] >= min_gain and j["gain"] > n_se * j["gain_se"] and j["delta_bic"] < -min_bic
                      and j["explained"] >= min_explained and j["worst_sensor"] <= max_worse)
                trial = Trial(full, j["gain"], j["gain_se"], j["delta_bic"], j["explained"], j["worst_sensor"],
                              bool(ok))
            else:
                j = judge(data, base, s)
                trial = Trial(s, j["gain"], j["gain_se"], j["delta_bic"], j["explained"], j["worst_sensor"], False)
            trials.append(trial)
            event(log, "candidate judged", effect=s.candidate.label, passed=trial.passed, gain=round(j["gain"], 4),
                  explained=round(j["explained"], 3), delta_bic=round(j["delta_bic"], 1))
        diagnosis.rounds.append(trials)
        passed = [t for t in trials if t.passed]
        if not passed:
            break
        winner = max(passed, key=lambda t: t.gain)
        diagnosis.accepted.append(winner)
        current = winner.refit.fit
    diagnosis.final = current
    return diagnosis

