"""The health states' ratios: each relation's residual inside a state's severity box over its free residual.

:func:`state_box` makes a health state's box of severities (its own fault in its level's band, the others near
nominal); :func:`state_ratios` evaluates every state's box on the windows' parity estimates
(:func:`~hydrowatch.condition.estimates.relation_mse`) per fill group of states and divides by the best free fit,
which is what the health-state features compare.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hydrowatch.condition import parity
from hydrowatch.condition.estimates import RELATIONS, ParityEstimates, WindowSignals, relation_mse
from hydrowatch.plant.faults import FAULTS, LEVEL_BANDS, level_severity, parse_state, severity_for_speed_drop
from hydrowatch.plant.parameters import PlantParameters

NO_OTHER_EXPLANATION = 1e300
"""The ratio :func:`state_ratios` gives a state's own relation when nothing but its own fault explains it (a load or
motor fault, or no valve-side alternative): finite, as evidence rows count non-finite values as invalid windows."""


def state_box(state: str, level: float, p: PlantParameters, tolerance: float, level_width: float, narrow: bool,
              band_margin: float) -> dict[str, tuple[float, float]]:
    """A health state's severity box: every fault within ``tolerance`` (``level_width`` if narrow) × its warning
    severity of nominal, the state's own fault in its level's band scaled to the fitted ``level`` (widened by
    ``band_margin``) or, if narrow, within ``level_width`` of it."""
    box = {}
    for other in FAULTS:
        tol = (level_width if narrow else tolerance) * level_severity(other, "warning", p)
        box[other] = (-tol, tol)
    own, named_level = parse_state(state)
    if own is not None and named_level is not None:
        if narrow:
            box[own] = (level * (1.0 - level_width), level * (1.0 + level_width))
        else:
            named = level_severity(own, named_level, p)
            lo, hi = (severity_for_speed_drop(own, d, p) / named for d in LEVEL_BANDS[named_level])
            box[own] = (level * lo * (1.0 - band_margin), level * hi * (1.0 + band_margin))
    return box


@dataclass(frozen=True)
class FillGroup:
    """Health states whose missing sensors are filled with the same parameters, with that fill's windows."""

    states: tuple[int, ...]
    """Indices of the states (in the features' state order)."""
    signals: WindowSignals
    estimates: ParityEstimates


Box = Mapping[str, tuple[float, float]]
"""A state's severity box: fault → (low, high), floats, or arrays (m,) of per-window bounds."""
BoxOf = Box | Callable[[ParityEstimates], Box]
"""A box, or what makes one from the windows' estimates (:mod:`hydrowatch.condition.relief`)."""


def state_ratios(groups: Sequence[FillGroup], p: PlantParameters, relations: Sequence[str],
                 box_sets: Sequence[Sequence[BoxOf]], own: Sequence[str | None] | None = None
                 ) -> tuple[list[np.ndarray], dict[str, np.ndarray], list[np.ndarray]]:
    """F[r, k] = MSE_r(state k's box, k's fill) / MSE_r(free) per set of boxes, the free MSEs, and per set each
    state's own valve relation without its own fault.

    Parameters
    ----------
    groups : sequence of FillGroup
        Every state in exactly one group (one group when no sensor is missing).
    box_sets : sequence of sequences of boxes
        Per set (band, level), each state's box, in state order; a callable box is made from each
        fill group's estimates (per-window bounds).
    own : sequence of str or None, optional
        Each state's own fault (None: healthy or untested), for the third output.

    Returns
    -------
    (list of ndarray, dict of str to ndarray, list of ndarray)
        Per box set the ratios, shape (m, n_relations · n_states) relation-major; the free
        MSE of each relation, shape (m,): the best fit of every hypothesis and fill tried (a held
        fit can beat a search stalled at a kink), so that no ratio falls below 1; and per box set,
        shape (m, n_states), the ratio of each state's valve relation explained by the other valve-side
        faults in its box (:func:`relation_mse`'s ``valve_others``; where the state's own fault is not
        valve-side or ``own`` is not given: :data:`NO_OTHER_EXPLANATION`, finite so that rows stay valid).
    """
    n_states = sum(len(g.states) for g in groups)
    m = groups[0].signals.flow.shape[0]
    held = [[{} for _ in range(n_states)] for _ in box_sets]  # type: list[list[dict[str, np.ndarray]]]
    free = {r: np.full(m, np.inf) for r in RELATIONS}
    faults = [None] * n_states if own is None else list(own)
    for g in groups:
        cache: dict[tuple[object, ...], np.ndarray] = {}
        for boxes, out in zip(box_sets, held):
            for k in g.states:
                box = boxes[k]
                out[k] = relation_mse(g.signals, g.estimates, p, box(g.estimates) if callable(box) else box, cache,
                                      faults[k])
        est = g.estimates
        free["load"] = np.minimum(free["load"], est.mse["load"])
        free["motor"] = np.minimum(free["motor"], est.mse["motor"])
        free["valve"] = np.minimum(free["valve"], np.min([est.mse[f] for f in parity.VALVE_HYPOTHESES]
                                                         + list(cache.values()), axis=0))
    ratios = []
    for mse in held:
        scores = np.stack([np.stack([mse[k][r] / np.maximum(free[r], 1e-300) for k in range(n_states)], axis=1)
                           for r in relations], axis=1)
        ratios.append(scores.reshape(m, -1))
    valve = np.maximum(free["valve"], 1e-300)
    others = [np.minimum(np.stack([mse[k].get("valve_others", np.full(m, np.inf)) / valve for k in range(n_states)],
                                  axis=1), NO_OTHER_EXPLANATION) for mse in held]
    return ratios, free, others
