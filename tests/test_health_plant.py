"""End to end on the plant simulator: 7 states from simulated sensors, with a throw-away ARX reference model.

The ARX least-squares fit below exists only in this test (the library's reference models live in
hydrowatch.sysid); it is enough to turn sensor data into prediction errors (Eq. 5.1).
"""

import numpy as np
import pytest

from hydrowatch.health import DataPlan, HealthModel, RelativeEntropyFeatures, accuracy, split_state

simulator = pytest.importorskip("hydrowatch.plant.simulator")
faults = pytest.importorskip("hydrowatch.plant.faults")
excitation = pytest.importorskip("hydrowatch.plant.excitation")

SENSORS = ("flow", "speed", "torque")
NA, NB, DELAY = 4, 6, 1
PLAN = DataPlan(reference_samples=10_000, base_samples=20_000, classifier_windows=40)


def _regressors(y: np.ndarray, u: np.ndarray) -> np.ndarray:
    start = max(NA, NB + DELAY - 1)
    rows = [y[start - i : y.size - i] for i in range(1, NA + 1)]
    rows += [u[start - DELAY - j : u.size - DELAY - j] for j in range(NB)]
    return np.column_stack([*rows, np.ones(y.size - start)])


def _record(state: str, seconds: float, seed: int):
    u = excitation.filtered_noise(seconds, (0.5, 3.5), seed=seed)
    return simulator.simulate(u, faults.state_parameters(state), seed=seed)


def _errors(rec, thetas) -> np.ndarray:
    """One-step prediction errors (Eq. 5.1) of every sensor, shape (n - start, 3)."""
    start = max(NA, NB + DELAY - 1)
    u = rec["voltage"]
    return np.column_stack([rec[s][start:] - _regressors(rec[s], u) @ th for s, th in zip(SENSORS, thetas)])


def test_seven_states_from_simulated_plant():
    seconds = (PLAN.samples_per_state + 200) / 200.0
    records = {s: _record(s, seconds, seed=10 + i) for i, s in enumerate(faults.STUDY_STATES)}
    healthy = records["healthy"]
    ref = split_state(len(healthy), PLAN).reference
    thetas = []
    for s in SENSORS:
        y, u = healthy[s][ref], healthy["voltage"][ref]
        thetas.append(np.linalg.lstsq(_regressors(y, u), y[max(NA, NB + DELAY - 1):], rcond=None)[0])
    base, windows = {}, {}
    for state, rec in records.items():
        e = _errors(rec, thetas)
        split = split_state(e.shape[0], PLAN)
        base[state], windows[state] = e[split.base], e[split.classifier]
    model = HealthModel(features=RelativeEntropyFeatures()).fit(base, windows)
    assert model.report_["test_accuracy"] >= 0.9, model.report_
    truth, pred = [], []
    for i, state in enumerate(faults.STUDY_STATES):  # fresh recordings, another command and noise
        _, verdicts = model.score(_errors(_record(state, 51.0, seed=500 + i), thetas))
        pred += [v.state for v in verdicts]
        truth += [state] * len(verdicts)
    assert len(pred) == 70
    fresh = accuracy(truth, pred)
    print(f"simulated 7 states: test accuracy {model.report_['test_accuracy']:.3f}, fresh recordings {fresh:.3f}")
    assert fresh >= 0.85, list(zip(truth, pred))
