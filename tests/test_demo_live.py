"""The demo's live fleet publishes through the plant service's FleetPublisher (issue 13 item 3): recorder and scorer
processes get every machine's chunks, labelled with the state its degradation path is in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hydrowatch.health.plan import DataPlan
from hydrowatch.io import read_recording
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.training.demo import FLEET, MACHINES, DemoSettings, live_fleet
from hydrowatch.training.options import TrainingSettings
from hydrowatch.training.trainer import train


def test_the_live_fleet_reaches_recorder_and_scorer_with_the_labels_of_its_paths(tmp_path: Path) -> None:
    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    states = ["healthy", "load_warning", "pump_leak_warning"]
    grouped = {r.state: [r] for r in simulate_states(states, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    model = train(grouped, TrainingSettings(method="parity", plan=plan)).bundle.save(tmp_path / "model")
    live = live_fleet(DemoSettings(out=tmp_path, training={}, live_seconds=45.0, speed=10.0), model, show=False)
    machines = [m.machine for m in MACHINES]
    assert sorted(live["timelines"]) == machines
    assert all(len(live["timelines"][m]) >= 6 for m in machines)  # 45 s: 8 windows, the last may still be open
    assert {s for _, _, s in live["timelines"]["m00"]} == {"healthy"}
    for m in machines:
        recorded = read_recording(next((tmp_path / "recordings" / FLEET / m).glob("*.mcap")))
        labels = recorded.meta.get("labels")
        labels = np.full(len(recorded), recorded.state) if labels is None else np.asarray(labels)
        sent = {round(t, 3): label for t, label in live["truth"][m]}  # each chunk's first sample -> its label
        pairs = [(sent[t], labels[20 * i]) for i, t in enumerate(np.round(recorded.t[::20], 3).tolist()) if t in sent]
        assert len(pairs) >= 100 and all(a == b for a, b in pairs), m
    assert set(read_recording(next((tmp_path / "recordings" / FLEET / "m03").glob("*.mcap"))).meta["labels"]) == {
        "healthy", "pump_leak_warning"}  # the path's fault appears: the label follows it
    assert live["truth"]["m00"][1][0] - live["truth"]["m00"][0][0] == pytest.approx(0.1)  # 0.1 s chunks
