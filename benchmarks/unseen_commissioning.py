"""The commissioning section of ``bench_unseen_units.py`` (``--commission``, ``--commission-only``; issue 11).

The 7- and 13-state models of the population's *first* unit are commissioned on each other unit's healthy recording
(300 s of its training day: a duty cycle 0.5–3.5 V, then filtered noise 0–4 V) and score that unit's later day on
working commands (duty cycle and slow noise) and, for 7 states, the open set. Beside it, on the same later-day
recordings: the fleet model without commissioning, and **each unit's own model** (trained on its own identification
recordings, as the own-unit section): what the test recordings let any model of this kind tell, so that a commissioned
unit's misses can be split into what commissioning cost and what the recording cannot tell (a hold at one operating
point cannot tell the valve-side faults apart, docs/unseen-units.md).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np
from bench_unseen_units import Tally, open_set, score_working, side_by_side, simulate, summarise, train
from threadpoolctl import threadpool_limits

from hydrowatch.condition import ConditionModel
from hydrowatch.condition.commission import WHOLE_FIT, CommissioningError, commission
from hydrowatch.plant import PlantParameters
from hydrowatch.plant.excitation import duty_cycle, filtered_noise

COMMISSIONING_RUNS: dict[str, Callable[[int], np.ndarray]] = {
    "duty cycle 0.5-3.5 V": lambda seed: duty_cycle(300.0, (0.5, 3.5), seed=seed),
    "filtered noise 0-4 V": lambda seed: filtered_noise(300.0, (0, 4), seed=seed)}
"""The commissioning recordings: 300 s of each unit's healthy self on its training day."""


def commission_unit(base: ConditionModel, states: tuple[str, ...], unit: PlantParameters, day: PlantParameters,
                    j: int, how: str, plain: bool, args: argparse.Namespace) -> tuple[Tally, list[Tally], str]:
    """Unit ``j`` commissioned from the fleet model ``base`` on its ``how`` recording and scored on its later day's
    working commands (and the open set for 7 states); with ``plain`` also the fleet model alone and the unit's own
    model (the own-unit section's: same training seed) on the same recordings. The outcome: "refused", or the supply
    commissioning chose."""
    with threadpool_limits(1):
        seed = 50_000 + 1000 * j + args.seed
        healthy = simulate([unit], COMMISSIONING_RUNS[how](seed + 1), seed)[0]
        try:
            done = commission(base, healthy)
            model, outcome = done.model, done.supply
        except CommissioningError as exc:  # the unit keeps the fleet model
            print(f"unit {j + 1}: commissioning refused: {exc}")
            model, outcome = base, "refused"
        tallies: list[Tally] = []
        others = (base, train(unit, states, args.train_seconds, 1000 * (j + 1) + args.seed)) if plain else ()
        for m in (model, *others):
            tally = Tally()
            score_working(m, day, states, np.random.default_rng(seed), args.test_seconds, seed, tally)
            if len(states) == 7:  # the 6 faults the model never saw, on the commissioned unit: right = unknown
                open_set(m, day, args.test_seconds, seed, tally)
            tallies.append(tally)
        return tallies[0], tallies[1:], outcome


def commissioning(first: dict[int, ConditionModel], units: list[tuple[PlantParameters, PlantParameters]],
                  sets: tuple[tuple[str, ...], ...], args: argparse.Namespace) -> dict[str, object]:
    """The first unit's models on every other unit, commissioned on its healthy duty cycle or not."""
    out: dict[str, object] = {}
    for states in sets:
        base, k = first[len(states)], len(states)
        for n, how in enumerate(COMMISSIONING_RUNS):
            work = [(base, states, unit, day, j, how, n == 0, args) for j, (unit, day) in enumerate(units[1:], start=1)]
            results = list(side_by_side(commission_unit, work, args.jobs))
            commissioned = [r[0] for r in results]
            accepted = [r[0] for r in results if r[2] != "refused"]
            refused = sum(r[2] == "refused" for r in results)
            supply = sum(r[2] == "identified" for r in results)
            whole = sum(r[2] == WHOLE_FIT for r in results)
            if n == 0:
                out[f"{k} states, not commissioned"] = summarise([r[1][0] for r in results],
                                                                 f"{k} states, first unit's model, not commissioned")
                out[f"{k} states, each unit's own model"] = summarise(
                    [r[1][1] for r in results], f"{k} states, each unit's own model on the same later-day recordings")
            out[f"{k} states, commissioned on {how}"] = summarise(
                commissioned, f"{k} states, first unit's model, commissioned on 300 s of healthy {how}")
            if refused and accepted:  # a refused unit keeps the fleet model and is the worst unit: show the rest too
                out[f"{k} states, commissioned on {how}, the commissioned units"] = summarise(
                    accepted, f"{k} states, commissioned on {how}, the {len(accepted)} units commissioned")
            out[f"{k} states, commissioned on {how}, refused"] = refused
            out[f"{k} states, commissioned on {how}, whole-recording fit"] = whole
            print(f"commissioning on {how}: refused on {refused} of {len(units) - 1} healthy units, supply "
                  f"identified on {supply}, the whole recording's fit (halves disagree) kept on {whole}")
    return out


