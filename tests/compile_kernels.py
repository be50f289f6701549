"""Compile hydrowatch's numba kernels into their cache (``__pycache__``, ``@njit(cache=True)``) before the suite runs.

On a fresh checkout the first test of each pytest-xdist worker, and every service process started before the cache
exists, would compile them itself: the plant's RK4 kernel and the parity relations' supply kernels, ~50 s, on both
workers at once at the start of ``make test`` (measured: this script 45–50 s cold). ``make test`` runs it beside
ruff and mypy, before the suite. A small real workload, so that the kernels are compiled
for the types the tests use: the plant (simulation, its linear modes), a parity model trained and judging its
training recordings (the severity searches), and a unit identified from a duty cycle's healthy windows (its holds:
the supply noise variance). The few it leaves (the plant's kink search, two second signatures) compile in the tests.
"""

from __future__ import annotations

import time

from threadpoolctl import threadpool_limits


def main() -> None:
    began = time.monotonic()
    with threadpool_limits(limits=1, user_api="blas"):
        from hydrowatch.condition.layout import windows_from_recording
        from hydrowatch.condition.unit import identify_unit
        from hydrowatch.health.plan import DataPlan
        from hydrowatch.plant.excitation import duty_cycle
        from hydrowatch.plant.fleet import simulate_states
        from hydrowatch.plant.simulator import linear_modes
        from hydrowatch.training.options import TrainingSettings
        from hydrowatch.training.trainer import train

        plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
        states = ["healthy", "load_alert", "pump_leak_alert"]
        recordings = list(simulate_states(states, seconds=plan.samples_per_state / 200 + 1, seed=0))
        linear_modes(voltage=2.0)
        model = train({r.state: [r] for r in recordings}, TrainingSettings(method="parity", plan=plan)).bundle
        condition = model.condition
        for recording in recordings:
            windows = windows_from_recording(recording, condition.features_.window, condition.features_.hop)
            condition.predict(windows, 1)
        duty = next(simulate_states(["healthy"], seconds=40, seed=1, command=duty_cycle(40, (0.5, 3.5), seed=1)))
        identify_unit(windows_from_recording(duty, 1000, 1000))
    print(f"numba kernels compiled or loaded from their cache in {time.monotonic() - began:.0f} s")


if __name__ == "__main__":
    main()
