"""Which of a relation's parameters a recording can move from the given nominal (:mod:`hydrowatch.condition.unit`).

A parameter that acts only in a regime the recording never visits cannot be identified from it, however much a fit
may move it to absorb something else; it keeps the given nominal and is reported as left to its prior.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hydrowatch.plant.parameters import PlantParameters

STANDSTILL = 3.0
"""The brake's sign term TL·tanh(ω/ωs) (Eq. 7) differs from ±TL by more than 0.5 % only within 3 ωs of standstill ..."""
MIN_STANDSTILL = 200
"""... so ωs is identified only from a recording with at least this many samples (1 s) of |ω| < :data:`STANDSTILL` × ωs;
otherwise it keeps the given nominal (:func:`free_parameters`). A healthy duty cycle of 0.5–3.5 V never comes near
standstill (its slowest sample 0.1–5 rad/s, 0–4 samples within 3 ωs; 300 s of filtered noise 0–4 V: 800–1300), yet its
fit moved ωs to the search limit (× 4.5) on 7 of 19 units of seed 2039, buying 1–2 % of the load relation's residual
with a term that only acts near standstill, where the model then failed: a motor leak's stall in a 0.5 V hold read
``unknown`` (load severity 2.0, the brake torque thrice the unit's; docs/unseen-units.md)."""

def free_parameters(relation: str, names: Sequence[str], speed: np.ndarray, p: PlantParameters) -> tuple[str, ...]:
    """The parameters of ``relation`` that a recording of gearbox speeds ``speed`` (rad/s) can move from ``p``:
    ``names`` without ωs unless the recording comes near standstill (:data:`MIN_STANDSTILL`)."""
    if relation != "load" or "omega_s" not in names:
        return tuple(names)
    if int(np.sum(np.abs(speed) < STANDSTILL * p.omega_s)) >= MIN_STANDSTILL:
        return tuple(names)
    return tuple(n for n in names if n != "omega_s")
