"""The full calibration of a unit under one hypothesis: the current model plus one screened effect
(issue 12; used by diagnose.py to confirm a screened candidate), and the continuation of an accepted
hypothesis's fit (polish, settle)."""

from __future__ import annotations

from dataclasses import replace
from functools import partial

from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.calibrate import OutputErrorFit, fit_output_error, prior_weight, static_stage
from hydrowatch.gap.candidates import Refit, Scan, holdout_cost, scan_magnitude, scan_starts
from hydrowatch.gap.side_by_side import side_by_side
from hydrowatch.gap.space import ModelSpace
from hydrowatch.log import event, get_logger
from hydrowatch.plant.parameters import PlantParameters

log = get_logger(__name__)

STAGE_NFEV = 15
"""Iterations of a hypothesis's static stage; its joint fit gets twice as many (calibrate's defaults)."""

JOINT_NFEV = 2 * STAGE_NFEV
"""Solver iterations of a hypothesis's joint fit (every plant and effect parameter free)."""

SETTLE_RUNS = 3
"""Most continuations of JOINT_NFEV iterations that an accepted model still moving after its polish gets
(:func:`settle`); the stall rule (calibrate.STALL_DROP) ends them as soon as its cost stops falling."""

RACE_NFEV = 6
"""Solver iterations each start of a race gets (:func:`recalibrate`) before the better one is continued."""

RACE_RATIO = 2.0
"""Starts whose best magnitudes differ by more than this factor hold different explanations and race."""

POLISH_NFEV = 20
"""Solver iterations that continue an accepted model's joint fit before the next round (fewer when its
cost stops falling first, calibrate.STALL_DROP; none when the confirmation converged)."""


def recalibrate(aligned: AlignedRecording, current: OutputErrorFit, screened: Refit,
                nominal: PlantParameters | None, pump: float | None = None, *, design_start: bool = True) -> Refit:
    """The full calibration (calibrate.py) under the hypothesis "current model + the screened effect":
    every plant parameter and every free effect parameter estimated, with the accepted effects and the
    candidate's screened values as the effects' starting point.

    Its start is the better of two kinds, picked by a magnitude scan of the effect on the whole record
    (:func:`scan_starts`, one batched simulation): the design values with the static parameters
    fitted (stage 1 of the calibration, the effect held at its screened value), or the current model
    (as it is, and with the candidate's partner parameters set to stage 1's values). The design start
    matters when the calibration without the effect bent several parameters to mimic it (a dead time
    into a slow spool, a low brake torque and a high viscous load: a local refit from there stayed in
    that valley); the current start when the effect's fit needs the dynamics right to move at all (gear
    backlash on dev seed 7: from the design values b crawled 0.0095 → 0.012 in 30 iterations, cost
    0.254; from the calibrated model it reached 0.0289 of the true 0.0287, cost 0.0055). The pump
    displacement starts at ``pump`` (m³/rad; the null calibration's) instead of the calibration's pump
    scan and restart (its first stage refits it with the other static parameters).

    ``design_start=False`` leaves the design start out (no static stage; the partners of the third start
    are set to their design values, the prior keeps the current model's weight): diagnose.py does so
    once the model holds an accepted effect (issue 12, item 5: a static stage is 92–135 simulations of
    120 s, and in every later-round confirmation logged on populations 7 and 2035 — 11 of 11, on three
    recordings — the current start won; the design start won only in round 1, gear backlash on 2035).
    The start that undoes the mimicry is then the current model with the partners *and the stand-ins*
    (``Candidate.stand_ins``) at their design values, and the scan compares it by raw cost with a model fitted
    without the effect, which favours the fitted one: each start's best magnitude is refined (its grid
    neighbours' geometric midpoints), and when the starts disagree on the magnitude by more than RACE_RATIO
    both fits run RACE_NFEV iterations and the lower cost is continued to JOINT_NFEV in all (issue 12, seed
    2063 units 10 and 12, backlash + air: the fitted start won the scan at α 0.002, its fit stopped at α
    0.0035 with Vt ×2.9 — the air held in the chamber volume — cost 0.0018, and the remainder was named
    ``unidentified``; the start with βe, Vt, Vs set back, at α 0.118, led after 6 iterations, 0.0013
    against 0.0023, and reached α 0.093 of a true 0.091 with Vt ×1.10 of ×1.12).
    """
    c = screened.candidate
    screened_effect = screened.fit.effects[c.id]
    effects = {**{k: dict(v) for k, v in current.effects.items()}, c.id: dict(screened_effect)}
    effect_free = tuple((e, p) for e, p in current.space.effect_free if e != c.id) + tuple((c.id, p) for p in c.free)
    design = nominal or current.space.prior or current.parameters
    free = current.space.plant_free
    scanned = replace(c, scan=(*c.scan, screened_effect[c.free[0]]),
                      fixed={**c.fixed, **{k: v for k, v in screened_effect.items() if k != c.free[0]}})
    prior = current.space.prior is not None
    if design_start:
        static, prediction = static_stage(aligned, design, free=free, effects=effects, max_nfev=STAGE_NFEV,
                                          pump=pump if "Dp" in free else None)
        scans = [scan_magnitude(aligned, current, scanned, [static])]
        weight = prior_weight(aligned, prediction) if prior else 0.0
    else:
        static = None
        scans = scan_starts(aligned, current, scanned, [design], plain_origins=False,
                            reset=c.partners + c.stand_ins, refine=True)
        weight = current.space.prior_weight
    best = min(scans, key=lambda sc: sc[2])
    racers = [best, *(sc for sc in scans if sc is not best and _disagree(sc[1], best[1]))]

    def space_from(scan: Scan) -> ModelSpace:
        start_effects = {**effects, c.id: scanned.starting_effect(scan[1])}
        return ModelSpace(scan[0], start_effects, free, effect_free, design if prior else None, weight)

    start, value = best[0], best[1]
    if len(racers) == 1:
        fit = fit_output_error(aligned, space_from(best), max_nfev=JOINT_NFEV)
    else:
        heats = side_by_side([partial(fit_output_error, aligned, space_from(sc), max_nfev=RACE_NFEV) for sc in racers])
        k = min(range(len(heats)), key=lambda i: heats[i].fit_cost)
        event(log, "race", effect=c.label, values=[round(sc[1], 6) for sc in racers],
              costs=[h.fit_cost for h in heats], winner=k)
        start, value, fit = racers[k][0], racers[k][1], heats[k]
        if not fit.converged:
            fit = fit_output_error(aligned, fit.space, fit.z, max_nfev=JOINT_NFEV - RACE_NFEV)
    event(log, "hypothesis start", effect=c.label, start="design" if start is static else "current",
          value=round(value, 6))
    return Refit(c, fit, holdout_cost(aligned, fit.prediction))


def _disagree(a: float, b: float) -> bool:
    """Whether two starting magnitudes differ by more than RACE_RATIO (either one zero: when they differ)."""
    lo, hi = sorted((abs(a), abs(b)))
    return hi > RACE_RATIO * lo if lo > 0 else hi > 0


def polish(aligned: AlignedRecording, refit: Refit) -> Refit:
    """The confirmed fit continued for POLISH_NFEV more solver iterations; as it is when its fit
    converged already (its cost stopped falling, calibrate.STALL_DROP: polishing only continues a fit
    its iteration limit cut short)."""
    if refit.fit.converged:
        return refit
    fit = fit_output_error(aligned, refit.fit.space, refit.fit.z, max_nfev=POLISH_NFEV)
    return Refit(refit.candidate, fit, holdout_cost(aligned, fit.prediction))


def settle(aligned: AlignedRecording, fit: OutputErrorFit) -> OutputErrorFit:
    """The accepted model's joint fit continued, JOINT_NFEV solver iterations at a time (the budget a later
    round's confirmation gets from it), until its cost stops falling (the stall rule) or for SETTLE_RUNS such
    runs; as it is when it converged.

    A later candidate is judged against the current model and its confirmation continues that model's
    fit: while the current fit still moves, the candidate is credited with what more iterations of the
    accepted effect would have found. Issue 12 (dev population 2035, backlash + entrained air): the
    backlash fit, from b 0.004 (true 0.024), still fell 5 % per iteration after its polish; round 2 then
    passed a transport delay (τ 0.7 ms) with a held-out gain of 0.81 where the delay stood in for the backlash
    fit's remaining iterations (its fit reached a cost of 0.0012; the backlash model alone, continued as
    long, 0.00074), and the rest went to ``unidentified``. Continued for JOINT_NFEV iterations only (the budget a
    later confirmation gets from it), the backlash fit of the fresh population 2061's pair still fell 7× in them
    (fitting cost 0.0163 → 0.0024); round 2 then credited a quadratic drag (gain 0.50) and a 0.15 ms transport
    delay (0.41, accepted) with the next 29 iterations, and the delay's model, polished and settled, converged
    only at 0.0011 (docs/gap.md, "Seventh pass"): a fit is settled until it stops moving.
    """
    for _ in range(SETTLE_RUNS):
        if fit.converged:
            break
        continued = fit_output_error(aligned, fit.space, fit.z, max_nfev=JOINT_NFEV)
        event(log, "accepted model settled", before=fit.fit_cost, after=continued.fit_cost,
              converged=continued.converged)
        if continued.fit_cost >= fit.fit_cost:
            break
        fit = continued
    return fit
