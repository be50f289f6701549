"""The scorer service with a cycles bundle over loopback: a rig's cycles published as ``rig_cycles`` messages come
back as per-component ``cycle_verdict`` messages, equal to ``hydrowatch score`` of the same cycles; a message of
another rig is skipped, not fatal; an ``import --rig`` file replayed by the replay service is judged the same way; the
recorder asked for them records the cycles, their verdicts and a machine's expected sensors."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_rig_cycles_method import RIG, write_rig_folder

from hydrowatch.bus import BusSettings, Publisher, Subscriber, free_port, key, open_session, wait_alive
from hydrowatch.errors import DataError
from hydrowatch.io.codec import encode_batch
from hydrowatch.io.mcap_io import iter_messages
from hydrowatch.io.rig_cycles import (
    read_rig_data,
    read_rig_recording,
    rig_cycles_batch,
    start_times,
    write_rig_recording,
)
from hydrowatch.methods.cycles import CyclesMethod
from hydrowatch.rig import load_rig
from hydrowatch.training import load_bundle
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.options import TrainingSettings
from hydrowatch.training.rig_pipeline import score_cycles


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cycles bundle of the tiny rig (valve 100/80 and pump 0/1 trained; valve 60 declared, never trained) and
    the folder ``new`` of 6 cycles to judge: valve 100, 80, 60, 60, 100, 80."""
    root = tmp_path_factory.mktemp("rig-scorer")
    (root / "rig.toml").write_text(RIG, encoding="utf-8")
    write_rig_folder(root / "train", np.tile([100.0, 100.0, 80.0, 80.0], 30), np.tile([0.0, 1.0, 1.0, 0.0, 0.0, 1.0],
                                                                                        20), seed=0)
    write_rig_folder(root / "new", np.array([100.0, 80.0, 60.0, 60.0, 100.0, 80.0]),
                     np.array([1.0, 0.0, 0.0, 1.0, 0.0, 1.0]), seed=1)
    rig = load_rig(root / "rig.toml")
    fitted = CyclesMethod.fit_cycles(RIG, rig, read_rig_data(root / "train", rig), TrainingSettings(method="cycles"))
    ModelBundle(fitted.method, fitted.manifest).save(root / "model")
    return root


def _scorer(model: Path, port: int) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "services.scorer", "--model", str(model), "--fleet", "lab",
                             "--bus-port", str(port)], stderr=subprocess.PIPE, text=True)


def _collect(health: Subscriber, want: int) -> list[dict[str, object]]:
    rows: list[dict[str, object]] = []
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and len(rows) < want:
        message = health.recv(timeout=0.5)
        if message is not None:
            rows += [{**row, "machine": message.key.machine} for row in message.batch.to_pylist()]
            deadline = time.monotonic() + 30  # 30 s without a message, not in all: the scorer's pace is the machine's
    return rows


def test_the_scorer_judges_published_rig_cycles_per_component(trained: Path) -> None:
    rig = load_rig(trained / "rig.toml")
    cycles = read_rig_data(trained / "new", rig)
    starts = start_times(cycles, rig)
    offline = score_cycles(load_bundle(trained / "model"), cycles)
    other = rig_cycles_batch(cycles, range(2), "another-rig", starts)
    port = free_port()
    proc = _scorer(trained / "model", port)
    try:
        with open_session(BusSettings(port=port)) as session, Publisher(session) as pub, \
                Subscriber(session, "hydro/lab/*/cycle_health") as health:
            assert wait_alive(session, "scorer", "lab", 1, timeout=90), "scorer did not come up"
            pub.put_payload(key("lab", "rig1", "cycles"), encode_batch(other))  # refused, logged, skipped
            for machine, rows in (("rig1", range(0, 3)), ("rig1", range(3, 6)), ("rig2", range(0, 6))):
                pub.put_payload(key("lab", machine, "cycles"), encode_batch(rig_cycles_batch(cycles, rows, rig.name,
                                                                                             starts)))
            got = _collect(health, 2 * 6 * 2)
    finally:
        proc.send_signal(signal.SIGTERM)
        _, log = proc.communicate(timeout=60)
    assert proc.returncode == 0
    assert log.count("rig cycles refused") == 1 and "cycles must be of rig 'tiny-cycles'" in log
    assert len(got) == 24 and {r["machine"] for r in got} == {"rig1", "rig2"}
    assert {(r["component"], r["healthy"]) for r in got} == {("valve", "100"), ("pump", "0")}  # v2: the healthy state
    for row in got:
        expected = offline["cycles"][row["cycle"]]["components"][row["component"]]
        assert row["state"] == expected["state"] and row["truth"] == expected["truth"]
        assert row["probability"] == pytest.approx(expected["probability"])
        assert row["novelty"] == pytest.approx(expected["novelty"])
        assert row["window_end"] - row["window_start"] == 20.0 and row["window_start"] == 20.0 * row["cycle"]
        assert str(row["model_version"]).startswith("sha256:")
    valve = sorted((r["cycle"], r["state"]) for r in got if r["machine"] == "rig2" and r["component"] == "valve")
    # valve 60 was never trained: the open-set rule reads it unknown; the others are named
    assert valve == [(0, "100"), (1, "80"), (2, "unknown"), (3, "unknown"), (4, "100"), (5, "80")]
    pump = [r for r in got if r["component"] == "pump"]
    assert sum(r["state"] == r["truth"] for r in pump) == 12
    assert {p["state"] for p in pump[0]["probabilities"]} == {"0", "1"}  # type: ignore[union-attr]


def test_an_imported_rig_file_replayed_on_the_bus_is_judged(trained: Path) -> None:
    rig = load_rig(trained / "rig.toml")
    recording = write_rig_recording(trained / "new.mcap", read_rig_data(trained / "new", rig), rig, RIG,
                                    fleet="lab", machine="rig3", per_message=4)
    port = free_port()
    proc = _scorer(trained / "model", port)
    try:
        with open_session(BusSettings(port=port)) as session, \
                Subscriber(session, "hydro/lab/*/cycle_health") as health:
            assert wait_alive(session, "scorer", "lab", 1, timeout=90), "scorer did not come up"
            replay = subprocess.run([sys.executable, "-m", "services.replay", str(recording), "--speed", "inf",
                                     "--bus-port", str(port), "--linger", "1"], timeout=120)
            got = _collect(health, 12)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=60)
    assert replay.returncode == 0 and proc.returncode == 0
    assert sorted(r["cycle"] for r in got if r["component"] == "valve") == list(range(6))
    assert [r["state"] for r in sorted(got, key=lambda r: r["cycle"]) if r["component"] == "valve"] == [
        "100", "80", "unknown", "unknown", "100", "80"]


def test_a_scorer_refuses_a_model_made_for_another_rig_naming_the_model_and_what_differs(trained: Path) -> None:
    """Issue 17: a plant scorer never silently serves a rig's model, nor a rig's scorer the plant's (at start: an
    error; on a followed alias: the version refused, the model in use kept)."""
    import argparse

    from services.scorer import _Model, add_arguments, served_rig

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    plant_bundle = Path(__file__).parent / "bundles" / "main-68a3627" / "parity"
    # the plant's scorer by default: its registered name, and the plant served
    default = parser.parse_args([])
    assert served_rig(default).name == "plant" and default.model == "models:/hydrowatch@champion"
    as_rig = parser.parse_args(["--rig", str(trained / "rig.toml")])
    assert served_rig(as_rig).name == "tiny-cycles" and as_rig.model == "models:/hydrowatch-tiny-cycles@champion"

    plant = parser.parse_args(["--rig", "plant", "--model", str(trained / "model")])
    with pytest.raises(DataError, match=r"model/?: the model must be made for rig 'plant'.* cycles bundle .* of rig "
                                        r"'tiny-cycles': its rig is 'tiny-cycles', not 'plant'; it reads channels "
                                        r"\['P', 'Q', 'T'\] that 'plant' does not have"):
        _Model(plant, served_rig(plant))
    # --model alone serves the model's own rig; a followed version made for the plant is refused, the model kept
    rig = parser.parse_args(["--model", str(trained / "model")])
    model = _Model(rig, served_rig(rig))
    in_use = model.bundle.version
    assert model.served.name == "tiny-cycles" and not model.take(load_bundle(plant_bundle))
    assert not model.moved() and model.bundle.version == in_use


def test_the_recorder_records_cycles_their_verdicts_and_expected_sensors_when_asked(trained: Path) -> None:
    import pyarrow as pa

    from hydrowatch.schemas import EXPECTED_WINDOW, wire_schema

    rig = load_rig(trained / "rig.toml")
    cycles = read_rig_data(trained / "new", rig)
    starts = start_times(cycles, rig)
    expected = pa.RecordBatch.from_pylist([{
        "window_start": 5.0, "window_end": 10.0, "sensor": "flow", "unit": "L/min", "step": 0.1,
        "measured": [1.0, 2.0], "expected": [1.5, 2.5], "source": "valve relation", "model_version": "sha256:abc"}],
        schema=wire_schema(EXPECTED_WINDOW))
    out, port = trained / "recorded", free_port()
    scorer = _scorer(trained / "model", port)
    recorder = subprocess.Popen([sys.executable, "-m", "services.recorder", "--out", str(out), "--fleet", "lab",
                                 "--topics", "cycles,cycle_health,expected", "--rig", str(trained / "rig.toml"),
                                 "--flush", "0.2", "--bus-port", str(port)], stderr=subprocess.PIPE, text=True)
    try:
        with open_session(BusSettings(port=port)) as session, Publisher(session) as pub, \
                Subscriber(session, "hydro/lab/*/cycle_health") as health:
            assert wait_alive(session, "scorer", "lab", 1, timeout=90), "scorer did not come up"
            assert wait_alive(session, "record", "lab", 1, timeout=90), "recorder did not come up"
            for rows in (range(0, 3), range(3, 6)):
                pub.put_payload(key("lab", "rig1", "cycles"), encode_batch(rig_cycles_batch(cycles, rows, rig.name,
                                                                                            starts)))
            pub.put_payload(key("lab", "m1", "expected"), encode_batch(expected))
            got = _collect(health, 12)
            time.sleep(1.0)  # the recorder's verdicts arrive as the test's did
    finally:
        for proc in (recorder, scorer):
            proc.send_signal(signal.SIGTERM)
        _, log = recorder.communicate(timeout=60)
        scorer.communicate(timeout=60)
    assert recorder.returncode == 0, log
    (rig1,) = (out / "lab" / "rig1").glob("*.mcap")
    text, recorded = read_rig_recording(rig1)  # the recorder's file reads as import --rig's: description kept
    assert text == (trained / "rig.toml").read_text(encoding="utf-8")
    np.testing.assert_array_equal(recorded.values, cycles.values)
    assert {k: list(v) for k, v in recorded.labels.items()} == {k: list(v) for k, v in cycles.labels.items()}
    messages = list(iter_messages(rig1))
    assert [k for k, _, _ in messages].count("hydro/lab/rig1/cycles") == 2
    verdicts = [row for k, batch, _ in messages if k.endswith("/cycle_health") for row in batch.to_pylist()]
    received = [{k: v for k, v in row.items() if k != "machine"} for row in got]
    assert len(verdicts) == 12 and sorted(verdicts, key=str) == sorted(received, key=str)
    ((topic, batch, _),) = list(iter_messages(next((out / "lab" / "m1").glob("*.mcap"))))
    assert topic == "hydro/lab/m1/expected" and batch.to_pylist() == expected.to_pylist()


def test_the_recorder_records_sensors_unless_given_topics_or_keys() -> None:
    import argparse

    from services.recorder import add_arguments, recorder_keys

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert recorder_keys(parser.parse_args([])) == ["hydro/*/*/sensors"]
    assert recorder_keys(parser.parse_args(["--fleet", "lab", "--topics", "cycles,cycle_health"])) == [
        "hydro/lab/*/cycles", "hydro/lab/*/cycle_health"]
    assert recorder_keys(parser.parse_args(["--keys", "hydro/lab/m1/expected"])) == ["hydro/lab/m1/expected"]
    with pytest.raises(ValueError, match="with --keys give whole key expressions"):
        recorder_keys(parser.parse_args(["--keys", "hydro/lab/m1/expected", "--topics", "health"]))
    with pytest.raises(SystemExit):
        parser.parse_args(["--topics", "cycle"])
