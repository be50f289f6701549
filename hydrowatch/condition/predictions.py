"""What the healthy unit's component relations expect each sensor of a window to read (the machine page's chart).

The parity method tests a window by asking how far each relation's parameter moved
(:mod:`hydrowatch.condition.parity`); the same relations with the unit's own nominal parameters
(``ConditionFeatures.nominal_``: the healthy unit, identified at training or commissioning) predict each
sensor from the others and the command, so an operator sees *where* a window departs from the healthy unit:

- **flow** from the **valve relation** (Eqs. 1, 2, 4, 5): the command through the nominal spool, supply
  line and orifice, against the load pressure P̂L: QL − Cvx·P̂L, output error (the measured flow does not
  enter). A pump, relief, coil or valve-leak fault shows here.
- **torque** from the **load relation** (Eq. 7): JL·ω̇ + BL·ω + TL·tanh(ω/ωs) of the measured speed. A load
  fault shows here.
- **speed** from the **motor relation** (Eqs. 6, 8): (Q − Ctm·P̂L − (Vt/4βe)·dP̂L/dt)/(N·Dm) of the measured
  flow. A motor leak shows here.

A sensor a sparse machine lacks is filled from the relations (:func:`~hydrowatch.condition.estimates.
window_signals`), and a relation used to fill tests nothing: a sensor whose relation was used to fill, or that
the machine lacks, has no expectation. Windows that cannot be judged (NaN, a stuck sensor) have none either.
Measured on 12 s per state (seed 3, 3 sensors, nominal parameters): on healthy windows the 0.1 s means of the
expected signals are within 1–5 % (RMS, of the measured signal's standard deviation) of the measured ones; a
load alert puts the torque 8–9 standard deviations off, a motor leak the speed 1.1–1.3, a pump leak the flow
3.0–3.1, each in its own sensor only. Cost: 0.22–0.27 ms per window in batches of 64, 8–10 % of judging it
(``benchmarks/bench_expected.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from hydrowatch.channels import M3S_TO_LPM
from hydrowatch.condition import load_fill, parity
from hydrowatch.condition.estimates import WindowSignals, window_signals
from hydrowatch.condition.layout import WIDTH, invalid_reasons
from hydrowatch.condition.oil import oil_parts
from hydrowatch.expected import POINT_SAMPLES, ExpectedWindow, expected_windows
from hydrowatch.plant.parameters import PlantParameters

if TYPE_CHECKING:
    from hydrowatch.condition.features import ConditionFeatures

SOURCES: dict[str, tuple[str, str]] = {"flow": ("valve", "valve relation"), "torque": ("load", "load relation"),
                                       "speed": ("motor", "motor relation")}
"""Sensor → the relation that predicts it and how the page names it."""


def relation_predictions(sig: WindowSignals, p: PlantParameters,
                         sensors: Sequence[str]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Measured and expected signals (m, n) of the ``sensors`` the relations of ``sig`` can predict (module
    docstring), flow in L/min, speed in rad/s, torque in N·m; ``p`` are the healthy unit's parameters."""
    measured = {"flow": sig.flow * M3S_TO_LPM, "speed": sig.speed, "torque": sig.torque}
    pl = sig.load_pressure
    expected: dict[str, np.ndarray] = {}
    for sensor in sensors:
        relation = SOURCES[sensor][0]
        if relation not in sig.relations:
            continue
        if sensor == "flow":
            expected[sensor] = parity.valve_flow_prediction(sig.spool, pl, p, None, np.zeros(pl.shape[0]),
                                                            sig.leak) * M3S_TO_LPM
        elif sensor == "torque":
            expected[sensor] = load_fill.load_torque(sig.speed, p)
        else:
            expected[sensor] = (sig.flow - p.Ctm * sig.leak * pl
                                - p.Vt / (4.0 * p.beta_e) * parity.derivative(pl)) / (p.N * p.Dm)
    return {s: measured[s] for s in expected}, expected


def expected_sensors(features: ConditionFeatures, windows: np.ndarray,
                     step: int = POINT_SAMPLES) -> list[ExpectedWindow | None]:
    """Per raw window (m, n, 4 or 5; :data:`~hydrowatch.condition.layout.CHANNELS` [+ temperature]) what the
    fitted ``features``' healthy unit expected each sensor to read, beside what it read, in points of ``step``
    samples (:func:`hydrowatch.expected.expected_windows`); None for a window that cannot be judged."""
    out: list[ExpectedWindow | None] = [None] * windows.shape[0]
    sensors = list(features.sensors)
    for mask, w, _known in oil_parts(windows, WIDTH):
        at = np.flatnonzero(mask)
        ok = np.array([why is None for why in invalid_reasons(w, sensors)], dtype=bool)
        if not ok.any():
            continue
        sig = window_signals(w[ok], sensors, features.nominal_, features.viscosity_coefficient)
        measured, expected = relation_predictions(sig, features.nominal_, sensors)
        found = expected_windows(measured, expected, {s: SOURCES[s][1] for s in expected}, step)
        for i, window in zip(at[ok].tolist(), found):
            out[i] = window
    return out
