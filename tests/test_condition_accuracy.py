"""Accuracy of the condition model on severities spread inside their bands (issue 5, round 4).

Two causes of the 13-state duty-cycle errors are pinned here: the level prior was averaged over
pooled windows like evidence (so a machine away from its state's trained severity lost to a
look-alike), and the relief_spring fit stepped over its narrow valley near pump saturation.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_condition_model import CHANNELS

from hydrowatch.condition import ConditionFeatures, ConditionModel, EvidenceLayout, pooled_windows, trailing_evidence
from hydrowatch.condition import estimates as E
from hydrowatch.condition.evidence import operating_points, trailing_count, trailing_spans, trailing_support
from hydrowatch.condition.ratios import NO_OTHER_EXPLANATION
from hydrowatch.plant import PlantSimulator
from hydrowatch.plant.excitation import duty_cycle, filtered_noise
from hydrowatch.plant.faults import fault_parameters, severity_for_speed_drop, state_parameters
from hydrowatch.plant.parameters import PlantParameters

STATES = ("healthy", "valve_coil_warning", "relief_spring_warning", "valve_coil_alert", "relief_spring_alert",
          "pump_leak_warning")
EDGES = {"warning": (0.125, 0.175), "alert": (0.27, 0.33)}
"""Speed drops near both edges of each band (warning 12–18 %, alert 26–34 %)."""


def run(params: list[PlantParameters], command: np.ndarray, seed: int) -> list[np.ndarray]:
    """Raw 4-channel windows (n, 1000, 4) of each machine under one command."""
    sim = PlantSimulator(params, seed=seed)
    sim.settle(float(command[0]))
    out = sim.step(command)
    n = command.size // 1000 * 1000
    return [np.stack([np.atleast_2d(out[c])[i, :n].reshape(-1, 1000) for c in CHANNELS], axis=-1)
            for i in range(len(params))]


def test_the_level_prior_enters_a_pool_once():
    # 2 states, 1 relation; state 1's own fault in column 1; its level box ratio is 4 in both windows.
    layout = EvidenceLayout(columns=np.array([-1, 1]), bounds=np.array([[[0, 0], [0.2, 0.4]], [[0, 0], [0.29, 0.31]]]))
    rows = np.array([[2.0, 1.0, 1.0, 4.0, 0.0, 0.30, 0.0, 100.0] + [NO_OTHER_EXPLANATION] * 4] * 2)
    g, a = trailing_evidence(rows, 2, layout)
    np.testing.assert_allclose(g[0], [2.0, 1.0, 1.0, 4.0])  # one window: the per-window rule
    np.testing.assert_allclose(g[1], [2.0, 1.0, 1.0, 2.0])  # two: evidence averaged, the prior 4^(1/2)
    np.testing.assert_allclose(a[1], [2.0, 1.0, 1.0, 4.0])  # the open-set means are untouched
    sparse = EvidenceLayout(layout.columns, layout.bounds, prior_once=False)  # a sensor missing: level is evidence
    np.testing.assert_allclose(trailing_evidence(rows, 2, sparse)[0][1], [2.0, 1.0, 1.0, 4.0])


def test_a_relief_fit_near_pump_saturation_finds_its_valley():
    p = PlantParameters()
    severity = severity_for_speed_drop("relief_spring", 0.125, p)
    command = np.concatenate([np.full(1000, 1.7), np.full(2000, 3.9)])  # a step to the pump limit, then a hold
    w = run([fault_parameters(p, "relief_spring", severity)], command, seed=3)[0]
    est = E.parity_estimates(E.window_signals(w, ("flow", "speed", "torque"), p), p)
    # The 7-point coarse grid alone stopped on the shut-relief plateau in the hold: s = -0.5, MSE 0.041.
    np.testing.assert_allclose(est.severity["relief_spring"], severity, atol=0.005)
    assert np.all(est.mse["relief_spring"] < 1e-3)
    assert est.mse["relief_spring"][2] < 2.0 * est.mse["valve_coil"][2]  # explained as well as its look-alike


@pytest.fixture(scope="module")
def spread_machines():
    train = dict(zip(STATES, run([state_parameters(s) for s in STATES], filtered_noise(40, (0, 4), seed=7), 8)))
    p = PlantParameters()
    machines = [(f"{f}_{level}", fault_parameters(p, f, severity_for_speed_drop(f, drop, p)))
                for f in ("valve_coil", "relief_spring") for level, drops in EDGES.items() for drop in drops]
    windows = run([m[1] for m in machines], duty_cycle(120, (0, 4), seed=41), seed=42)
    return ConditionModel().fit(train), [(m[0], w) for m, w in zip(machines, windows)], train


def test_the_prior_counts_once_only_when_every_relation_is_tested(spread_machines):
    model, _, train = spread_machines
    assert model.features_.evidence_layout().prior_once
    sparse = ConditionFeatures(sensors=("speed", "torque")).fit({s: train[s] for s in STATES[:2]})
    assert not sparse.evidence_layout().prior_once  # flow filled per state: the level half is evidence


def test_band_edge_severities_settle_when_pooled(spread_machines):
    model, machines, _ = spread_machines
    n = 6
    layout = model.features_.evidence_layout()
    width = 2 * len(model.features_.feature_names_)
    hits: dict[str, list[np.ndarray]] = {"window": [], "pooled": [], "prior per window": []}
    for state, w in machines:
        rows = model.features_.transform_evidence(w)
        ratios = rows[:, :width]
        hits["window"].append(np.array([v.state == state for v in model.judge_evidence(ratios, ratios)]))
        g, a = trailing_evidence(rows, n, layout)
        pooled = {"windows": pooled_windows(rows, n), "support": trailing_count(model.alone_unknown(ratios), rows, n),
                  "supported": trailing_support(model.alone_leads(ratios), operating_points(w), rows, n),
                  "spans": trailing_spans(operating_points(w), rows, n)}
        hits["pooled"].append(np.array([v.state == state for v in model.judge_pooled(g, a, ratios, **pooled)])[n - 1:])
        each = g.copy()  # round 3: the level prior averaged over the pool like evidence
        each[:, width // 2:] **= np.minimum(np.arange(1, len(rows) + 1), n)[:, None]
        judged = model.judge_pooled(each, a, ratios, **pooled)
        hits["prior per window"].append(np.array([v.state == state for v in judged])[n - 1:])
    acc = {k: float(np.mean(np.concatenate(v))) for k, v in hits.items()}
    # Measured: 55 % per window (holds cannot tell a spring from a coil), 98 % pooled once the pool
    # is full, 83 % with the prior counted per window.
    assert acc["window"] < 0.7
    assert acc["pooled"] >= 0.95
    assert acc["prior per window"] < 0.9
