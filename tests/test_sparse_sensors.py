"""Any subset of the sensors (issue 13 item 2): every method trains on the sensors its recordings have, records
them, scores and streams recordings of them, and refuses data that lacks one naming it; the services carry a
subset and the extra channels from import through MCAP, replay and the recorder to export."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from test_bus_services import FLEET, start, stop, wait_for
from test_pipeline_online import scorer_round_trip

from hydrowatch.bus import free_port
from hydrowatch.cli import main
from hydrowatch.errors import DataError
from hydrowatch.health.plan import DataPlan
from hydrowatch.io import read_recording
from hydrowatch.io.codec import sensor_chunk_from_arrays
from hydrowatch.plant.fleet import simulate_states
from hydrowatch.recording import Recording
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.online import Chunk, OnlineScorer, chunks_from_batches
from hydrowatch.training.options import TrainingSettings
from hydrowatch.training.scoring import score_recording
from hydrowatch.training.trainer import train

STATES = ["healthy", "load_alert", "pump_leak_alert"]
PLAN = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
SUBSETS = {"parity": ("speed", "torque"), "entropy": ("torque",), "stats": ("flow",)}
"""The sensors each method is trained on here: a machine without a flow meter, with a torque sensor alone, with a
flow meter alone."""


def only(recording: Recording, sensors: tuple[str, ...], extra: tuple[str, ...] = ("temperature",)) -> Recording:
    """The recording with the command, ``sensors`` and ``extra`` only (what a sparse rig records)."""
    keep = ("voltage", *sensors, *extra)
    return Recording(recording.t, {c: v for c, v in recording.channels.items() if c in keep}, dict(recording.meta))


@pytest.fixture(scope="module")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each method trained on its subset of seed 0's recordings (``SUBSETS``), saved."""
    root = tmp_path_factory.mktemp("sparse")
    runs = list(simulate_states(STATES, seconds=PLAN.samples_per_state / 200 + 1, seed=0))
    out = {}
    for method, sensors in SUBSETS.items():
        settings = TrainingSettings(method=method, reference="bj", plan=PLAN)
        out[method] = train({r.state: [only(r, sensors)] for r in runs}, settings).bundle.save(root / method)
    return out


@pytest.fixture(scope="module")
def later() -> list[Recording]:
    """40 s per state of another seed, every channel."""
    return list(simulate_states(STATES, seconds=40, seed=9))


@pytest.mark.parametrize("method", list(SUBSETS))
def test_a_method_trained_on_a_subset_records_it_scores_it_and_refuses_data_without_it(
        bundles: dict[str, Path], later: list[Recording], method: str) -> None:
    sensors = SUBSETS[method]
    bundle = ModelBundle.load(bundles[method])
    assert bundle.manifest["sensors"] == list(sensors) and bundle.health_method.channels == ["voltage", *sensors]
    accuracy = []
    for r in later:
        sparse = score_recording(bundle, only(r, sensors))
        accuracy.append(sparse["summary"]["accuracy"])
        # the sensors the model does not read change nothing when a recording has them
        assert [w["state"] for w in score_recording(bundle, r)["windows"]] == [w["state"] for w in sparse["windows"]]
    assert np.mean(accuracy) >= 0.8, accuracy
    other = next(s for s in ("flow", "speed", "torque") if s not in sensors)
    lacking = only(later[0], (other,))
    lacking.meta["source"] = "rig7.csv"
    with pytest.raises(DataError, match=re.escape(f"rig7.csv: recording must have the channel(s) {list(sensors)}: "
                                                  f"this {method} model was trained on {['voltage', *sensors]}")):
        score_recording(bundle, lacking)


def test_commissioning_a_unit_without_a_sensor_the_model_reads_names_it(bundles: dict[str, Path],
                                                                       later: list[Recording]) -> None:
    method = ModelBundle.load(bundles["parity"]).health_method  # reads speed and torque
    with pytest.raises(DataError, match=re.escape("recording must have the channel(s) ['torque']")):
        method.commission([only(later[0], ("flow", "speed"))])


def test_training_recordings_that_share_no_sensor_are_refused(later: list[Recording]) -> None:
    grouped = {"healthy": [only(later[0], ("flow",))], "load_alert": [only(later[1], ("torque",))]}
    with pytest.raises(DataError, match=r"must share at least one sensor .*Got recordings with \[\['flow'\], "
                                        r"\['torque'\]\]"):
        train(grouped, TrainingSettings(method="stats", plan=PLAN))


@pytest.mark.parametrize("method", list(SUBSETS))
def test_a_sparse_fleet_streams_as_it_scores(bundles: dict[str, Path], later: list[Recording], method: str) -> None:
    """Chunks with the subset and the temperature only, as sensor_chunk messages, in 0.5 s steps: the scorer's
    verdicts are the offline ones."""
    sensors = SUBSETS[method]
    bundle = ModelBundle.load(bundles[method])
    scorer = OnlineScorer(bundle)
    fleet = [only(r, sensors) for r in later]
    got: list = []
    for a in range(0, len(fleet[0]), 100):
        batches = [sensor_chunk_from_arrays(r.t[a:a + 100], {c: v[a:a + 100] for c, v in r.channels.items()})
                   for r in fleet]
        got += scorer.update(chunks_from_batches([r.state for r in fleet], batches, scorer.columns))
    for r in fleet:
        offline = [w["state"] for w in score_recording(bundle, r)["windows"]]
        online = [v.verdict.state for v in got if v.machine == r.state]
        assert online == offline and len(online) >= 6
        assert online.count(r.state) > len(online) / 2  # a baseline on one flow meter errs more


def test_a_chunk_without_a_channel_the_model_reads_is_invalid_and_says_which(bundles: dict[str, Path],
                                                                            later: list[Recording]) -> None:
    bundle = ModelBundle.load(bundles["parity"])  # reads speed and torque
    scorer = OnlineScorer(bundle)
    r = later[1]
    got = []
    for a in range(0, 4000, 100):
        lose = 1500 <= a < 2500  # 5 s without the torque sensor
        got += scorer.update([Chunk("m", r.t[a:a + 100], {c: r[c][a:a + 100] for c in
                                                          (("voltage", "speed") if lose else ("voltage", "speed",
                                                                                              "torque"))})])
    states = [(v.verdict.state, round(v.start_s, 3), round(v.end_s, 3)) for v in got]
    # window 1 (5-10 s) is cut short at 7.5 s, once; the stream starts again when torque is back, at 12.5 s
    assert states == [("load_alert", 0.0, 5.0), ("invalid", 5.0, 7.5), ("load_alert", 12.5, 17.5)]
    assert got[1].verdict.reason == ("no 'torque' in the chunk: the model reads ['voltage', 'speed', 'torque'] "
                                     "(trained on them)")
    # a machine that never had it: said once, on its first chunk
    fresh = [v for a in range(0, 2000, 100)
             for v in scorer.update([Chunk("n", r.t[a:a + 100], {c: r[c][a:a + 100] for c in ("voltage", "flow")})])]
    assert [(v.verdict.state, v.start_s, v.end_s) for v in fresh] == [("invalid", 0.0, 0.5)]
    assert "no 'speed', 'torque' in the chunk" in str(fresh[0].verdict.reason)


def test_the_scorer_service_judges_machines_without_a_flow_meter(bundles: dict[str, Path],
                                                                later: list[Recording]) -> None:
    code, got, first_kl = scorer_round_trip(bundles["parity"], later[:2], ("voltage", "speed", "torque"), 2200, 4)
    assert code == 0 and set(got) == set(STATES[:2])
    for machine, rows in got.items():
        assert [row["state"] for row in rows].count(machine) >= len(rows) - 1
    assert first_kl is not None


def test_a_plant_without_a_flow_meter_and_extra_channels_survive_import_mcap_replay_export(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """plant --channels → recorder; and CSV (flow, load pressure, temperature) → import → MCAP → replay → recorder →
    export: the channels and values of each, none added, none lost."""
    port = free_port()
    recorded = tmp_path / "rec"
    recorder = start("services.recorder", "--out", recorded, "--fleet", FLEET, "--bus-port", port)
    try:
        wait_for(port, "record")
        plant = start("services.plant", "--fleet", FLEET, "--machines", 1, "--seconds", 1, "--speed", "inf",
                      "--channels", "voltage,speed,torque,temperature", "--wait-subscribers", 30, "--bus-port", port)
        assert plant.wait(timeout=120) == 0
        r = Recording.from_columns({"t": np.arange(600) / 200.0, "voltage": np.linspace(0, 3, 600),
                                    "flow": 20 + np.sin(np.arange(600) / 9.0), "load_pressure": np.linspace(5, 9, 600),
                                    "temperature": np.full(600, 41.5)}, {"state": "healthy"})
        csv = tmp_path / "rig.csv"
        columns = [r[c].tolist() for c in ("t", "voltage", "flow", "load_pressure", "temperature")]
        csv.write_text("t,voltage,flow,load_pressure [bar],temperature\n"
                       + "\n".join(f"{t:.3f},{u!r},{q!r},{p!r},{T!r}" for t, u, q, p, T in zip(*columns)) + "\n")
        (tmp_path / "in").mkdir()
        assert main(["import", str(csv), "--out", str(tmp_path / "in" / "rig.mcap"), "--fleet", FLEET,
                     "--machine", "rig", "--label", "healthy"]) == 0
        replay = start("services.replay", tmp_path / "in", "--speed", "inf", "--wait-subscribers", 30, "--bus-port",
                       port)
        assert replay.wait(timeout=120) == 0
        assert stop(recorder) == 0
    finally:
        recorder.kill()
    plant_rec = read_recording(next((recorded / FLEET / "m000").glob("*.mcap")))
    assert sorted(plant_rec.channels) == ["speed", "temperature", "torque", "voltage"] and len(plant_rec) == 200
    out = tmp_path / "back.csv"
    assert main(["export", str(next((recorded / FLEET / "rig").glob("*.mcap"))), "--out", str(out)]) == 0
    back = read_recording(out)
    assert sorted(back.channels) == ["flow", "load_pressure", "temperature", "voltage"] and back.state == "healthy"
    for name in r.channels:
        np.testing.assert_array_equal(back[name], r[name])
    np.testing.assert_allclose(back.t, r.t, atol=1e-9)
    capsys.readouterr()
