"""The full calibration of a unit under one hypothesis: the current model plus one screened effect
(issue 12; used by diagnose.py to confirm a screened candidate)."""

from __future__ import annotations

from dataclasses import replace

from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.calibrate import OutputErrorFit, fit_output_error, prior_weight, static_stage
from hydrowatch.gap.candidates import Refit, holdout_cost, scan_magnitude
from hydrowatch.gap.space import ModelSpace
from hydrowatch.log import event, get_logger
from hydrowatch.plant.parameters import PlantParameters

log = get_logger(__name__)

STAGE_NFEV = 15
"""Iterations of a hypothesis's static stage; its joint fit gets twice as many (calibrate's defaults)."""


def recalibrate(aligned: AlignedRecording, current: OutputErrorFit, screened: Refit,
                nominal: PlantParameters | None, pump: float | None = None, *, design_start: bool = True) -> Refit:
    """The full calibration (calibrate.py) under the hypothesis "current model + the screened effect":
    every plant parameter and every free effect parameter estimated, with the accepted effects and the
    candidate's screened values as the effects' starting point.

    Its start is the better of two kinds, picked by a magnitude scan of the effect on the whole record
    (:func:`scan_magnitude`, one batched simulation): the design values with the static parameters
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
        start, value, _ = scan_magnitude(aligned, current, scanned, [static])
        weight = prior_weight(aligned, prediction) if prior else 0.0
    else:
        static = None
        start, value, _ = scan_magnitude(aligned, current, scanned, [design], plain_origins=False)
        weight = current.space.prior_weight
    effects[c.id] = scanned.effect(**{c.free[0]: value})
    if c.id == "stribeck_friction":
        effects[c.id]["Tc"] = min(effects[c.id]["Tc"], value)
    space = ModelSpace(start, effects, free, effect_free, design if prior else None, weight)
    fit = fit_output_error(aligned, space, max_nfev=2 * STAGE_NFEV)
    event(log, "hypothesis start", effect=c.label, start="design" if start is static else "current",
          value=round(value, 6))
    return Refit(c, fit, holdout_cost(aligned, fit.prediction))
