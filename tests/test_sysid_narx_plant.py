"""NARX against linear reference models on the simulated plant over the full 0-4 V range (study 4.7)."""

from __future__ import annotations

import numpy as np
import pytest

from hydrowatch.sysid.narx import NARX
from hydrowatch.sysid.narx_lines import linear_one_step

simulator = pytest.importorskip("hydrowatch.plant.simulator")
excitation = pytest.importorskip("hydrowatch.plant.excitation")


def nrmse(y: np.ndarray, y_hat: np.ndarray) -> float:
    return float(np.sqrt(np.mean((y - y_hat) ** 2)) / np.std(y))


@pytest.fixture(scope="module")
def record() -> tuple[np.ndarray, np.ndarray]:
    command = excitation.filtered_noise(25.0, (0.0, 4.0), seed=3)  # Table 4.1: 0-4 V, 200 Hz
    rec = simulator.simulate(command, seed=4)
    return rec.channels["voltage"], rec.channels["speed"]


def test_narx_beats_linear_models_over_the_full_range(record: tuple[np.ndarray, np.ndarray]) -> None:
    u, y = record
    u_fit, y_fit, u_test, y_test = u[:4000], y[:4000], u[4000:], y[4000:]
    model = NARX(input_delays=5, output_delays=5, hidden=8, max_iter=60).fit(u_fit, y_fit)
    narx = nrmse(y_test[5:], model.predict(u_test, y_test)[5:])
    arx = nrmse(y_test[5:], linear_one_step(u_fit, y_fit, u_test, y_test, 5, 5)[5:])
    assert narx < 0.6 * arx
    assert nrmse(y_test[5:], model.predict(u_test, y_test, steps_ahead=None)[5:]) < 0.1  # it simulates, too
    boxjenkins = pytest.importorskip("hydrowatch.sysid.boxjenkins")
    # The study's Table 3.11 orders at the plant's own delay (it answers after one sample: delay 0).
    bj = boxjenkins.BoxJenkins(nb=4, nf=4, nc=4, nd=5, delay=0).fit(u_fit, y_fit)
    assert narx < 0.6 * nrmse(y_test[20:], bj.predict(u_test, y_test, steps_ahead=1)[20:])
