"""Screening: the quick ranking of candidate effects against the current model (issue 12; used by
diagnose.py, which gives the best-ranked a full calibration under their hypothesis)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from typing import cast

from hydrowatch.gap.align import AlignedRecording
from hydrowatch.gap.calibrate import OutputErrorFit, fit_output_error
from hydrowatch.gap.candidates import (
    SCREEN_SECONDS,
    SLOW_EFFECTS,
    Candidate,
    Refit,
    Scan,
    holdout_cost,
    refit,
    scan_magnitude,
)
from hydrowatch.gap.side_by_side import side_by_side
from hydrowatch.gap.space import ModelSpace
from hydrowatch.log import event, get_logger
from hydrowatch.plant.parameters import PlantParameters

log = get_logger(__name__)

SCREEN_NFEV = 6
"""Solver iterations of a screening fit."""

Screened = tuple[float, Refit, AlignedRecording, OutputErrorFit]
"""A screened candidate: its screening gain, its screening fit, the data it was fitted on, the current model there."""


def screen(aligned: AlignedRecording, current: OutputErrorFit, pool: Sequence[Candidate],
            origins: Sequence[PlantParameters], plant_free: tuple[str, ...] | None = None,
            scans: dict[str, Scan] | None = None) -> tuple[list[Screened], list[str]]:
    """The candidates of ``pool`` ranked by their quick fit's held-out gain against ``current``, best first,
    and the labels of those no magnitude of which lowered the fitting cost (an effect without partners).

    Each is fitted for SCREEN_NFEV iterations on the first SCREEN_SECONDS (a slow effect on the whole record)
    with its partner plant parameters free (``plant_free=None``: the first look of every round), or with
    ``plant_free`` (the second look: every calibrated parameter). The second look's gain is matched: the
    current model refitted the same way without a candidate (the same plant parameters free on the same data,
    as many iterations) sets its zero, so a candidate is credited only with what the plant alone cannot reach
    there. Issue 12 (dev population 2035, backlash + entrained air): against the settled backlash model the air
    screened at −20 % with βe alone free and was never confirmed, while its full calibration passed every rule
    (gain 0.74): the calibration without the air had held its softness in βe ×0.5 and Vt ×3 and had bent ωv,
    ζv, Kr, Ctm, so a little air on that plant with only βe free only added softness; with every plant
    parameter free it screened at +24 % (matched +30 %), first of the remaining candidates, all others ≤ +3 %.

    ``scans``: each candidate's magnitude scan (:func:`scan_magnitude`) by label, filled here and reused when
    present. Both looks of a round scan the same grids on the same data against the same model, so the
    second look takes the first's (issue 12, item 5: 18 simulations of the whole record for thermal drift
    and ≈ 24 of the head for each other candidate, per second look).
    """
    head = aligned.head(SCREEN_SECONDS)
    datas = [aligned if c.id in SLOW_EFFECTS else head for c in pool]
    bases = {d.t.size: replace(current, prediction=current.prediction[:, : d.t.size]) for d in datas}

    def look(c: Candidate, data: AlignedRecording) -> tuple[Scan, Refit | None]:
        base, free = bases[data.t.size], c.partners if plant_free is None else plant_free
        scan = scans.get(c.label) if scans is not None else None
        if scan is None:
            scan = scan_magnitude(data, base, c, origins)
        return scan, refit(data, base, c, plant_free=free, max_nfev=SCREEN_NFEV, require_gain=not free, scanned=scan)

    def alone(data: AlignedRecording) -> float:
        """The matched zero: the gain of the current model refitted without a candidate."""
        base = bases[data.t.size]
        fit = fit_output_error(data, ModelSpace(base.parameters, {k: dict(v) for k, v in base.effects.items()},
                                                plant_free or (), base.space.effect_free), max_nfev=SCREEN_NFEV)
        return 1.0 - holdout_cost(data, fit.prediction) / holdout_cost(data, base.prediction)

    # The looks and the second look's plant-alone fits (one per data length; a second look's refit never returns
    # None, so each is used) need none of each other's results: side by side, the whole-record ones first.
    lengths = {} if plant_free is None else {d.t.size: d for d in datas}
    Looked = tuple[Scan, Refit | None] | float
    steps: list[Callable[[], Looked]] = [partial(look, c, d) for c, d in zip(pool, datas)]
    steps += [partial(alone, d) for d in lengths.values()]
    sizes = [d.t.size for d in datas] + list(lengths)
    first = sorted(range(len(steps)), key=lambda k: -sizes[k])
    done = dict(zip(first, side_by_side([steps[k] for k in first])))
    zero = {n: cast(float, done[len(pool) + k]) for k, n in enumerate(lengths)}
    for n, gain in zero.items():
        event(log, "second look", seconds=round(float(lengths[n].duration), 1), plant_alone_gain=round(gain, 4))
    screened: list[Screened] = []
    out = []
    for k, (c, data) in enumerate(zip(pool, datas)):
        scan, r = cast(tuple[Scan, Refit | None], done[k])
        if scans is not None:
            scans.setdefault(c.label, scan)
        if r is None:
            out.append(c.label)
            continue
        j0 = holdout_cost(data, bases[data.t.size].prediction)
        screened.append((1.0 - r.holdout_cost / j0 - zero.get(data.t.size, 0.0), r, data, bases[data.t.size]))
    screened.sort(key=lambda item: -item[0])
    return screened, out
