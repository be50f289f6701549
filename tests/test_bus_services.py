"""Services as separate processes over loopback, as in production: plant, recorder, replay, shards, up."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
import zenoh

from hydrowatch.bus import BusSettings, Subscriber, alive, free_port, open_session, wait_alive
from hydrowatch.cli import main
from hydrowatch.errors import DataError
from hydrowatch.io.codec import arrays_from_sensor_chunk
from hydrowatch.io.mcap_io import Recovery, iter_messages

FLEET = "f1"


def start(module: str, *argv: object) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", module, *map(str, argv)])


def wait_for(port: int, service: str, count: int = 1, processes: Sequence[subprocess.Popen] = ()) -> None:
    """Wait until ``count`` processes of ``service`` are up (= subscribed) on the bus at ``port``; when they are not
    within 60 s, say what the bus looked like (``processes``: the services started, whose exit codes it gives)."""
    # connect only: a short-lived session must not take the rendezvous port the services meet on
    with open_session(BusSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",))) as session:
        if not wait_alive(session, service, FLEET, count, timeout=60):
            raise AssertionError(f"{service} did not come up: {_bus_state(session, port, processes)}")


def _bus_state(session: zenoh.Session, port: int, processes: Sequence[subprocess.Popen]) -> str:
    """What tells a service that never started (exit codes), a bus nobody holds (the rendezvous port refuses) and a
    mesh this probe only partly reached (its peers) apart."""
    with socket.socket() as probe:
        probe.settimeout(2.0)
        listened = probe.connect_ex(("127.0.0.1", port)) == 0
    return (f"tokens seen {alive(session, f'hydro/{FLEET}/*/status', 2.0)}, this probe linked to "
            f"{len(list(session.info.peers_zid()))} peer(s), rendezvous port {port} "
            f"{'accepts' if listened else 'refuses'} connections, exit codes {[p.poll() for p in processes]} "
            "(None: running)")


def stop(proc: subprocess.Popen, sig: int = signal.SIGTERM) -> int:
    proc.send_signal(sig)
    return proc.wait(timeout=60)


def wait_handles_sigterm(proc: subprocess.Popen, timeout: float = 60.0) -> None:
    """Wait until ``proc`` has installed its SIGTERM handler (a service does so once it has imported what it needs and
    starts its work; Linux's ``/proc/<pid>/status`` shows the signals it catches, ``SigCgt``)."""
    deadline = time.monotonic() + timeout
    while True:
        assert proc.poll() is None, f"exited with {proc.returncode} before handling SIGTERM"
        caught = next(line.split()[1] for line in Path(f"/proc/{proc.pid}/status").read_text().splitlines()
                      if line.startswith("SigCgt:"))
        if int(caught, 16) >> (signal.SIGTERM - 1) & 1:
            return
        assert time.monotonic() < deadline, f"no SIGTERM handler after {timeout:.0f} s"
        time.sleep(0.05)


def read_machines(folder: Path) -> dict[str, tuple[np.ndarray, list[Recovery]]]:
    """Samples per machine (concatenated t of every file, in file order) and each file's recovery."""
    found: dict[str, tuple[list, list]] = {}
    for path in sorted(folder.rglob("*.mcap")):
        recovery = Recovery(str(path))
        t = [arrays_from_sensor_chunk(batch)[0] for _, batch, _ in iter_messages(path, recovery=recovery)]
        ts, recoveries = found.setdefault(path.parent.name, ([], []))
        ts.extend(t)
        recoveries.append(recovery)
    return {m: (np.concatenate(ts) if ts else np.empty(0), rec) for m, (ts, rec) in found.items()}


def assert_contiguous(t: np.ndarray, n: int | None = None) -> None:
    """Every sample from t = 0 on, in order, none missing, none twice."""
    assert t[0] == 0.0
    np.testing.assert_allclose(np.diff(t), 1 / 200.0, atol=1e-9)
    if n is not None:
        assert t.size == n


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """plant (4 machines, 3 s, as fast as possible) -> recorder, stopped by SIGTERM."""
    out = tmp_path_factory.mktemp("rec")
    port = free_port()
    recorder = start("services.recorder", "--out", out, "--fleet", FLEET, "--bus-port", port, "--chunk-size", 8192)
    try:
        wait_for(port, "record")
        plant = start("services.plant", "--fleet", FLEET, "--machines", 4, "--seconds", 3, "--speed", "inf",
                      "--states", "healthy,pump_leak_alert", "--wait-subscribers", 30, "--bus-port", port)
        assert plant.wait(timeout=120) == 0
        assert stop(recorder) == 0
    finally:
        recorder.kill()
    return out


def test_plant_to_recorder_every_sample_once(recording: Path) -> None:
    machines = read_machines(recording / FLEET)
    assert sorted(machines) == ["m000", "m001", "m002", "m003"]
    for t, recoveries in machines.values():
        assert_contiguous(t, 600)
        assert all(r.finished for r in recoveries)  # SIGTERM finished every file
    meta = machines["m001"][1][0].metadata["hydrowatch"]
    assert (meta["fleet"], meta["machine"], meta["state"], meta["schema_version"]) == (
        FLEET, "m001", "pump_leak_alert", "2")


def test_replay_publishes_the_same_samples_in_order(recording: Path) -> None:
    expected = sorted(
        (log_time, str(path), i, topic, arrays_from_sensor_chunk(batch)[0][0])
        for path in recording.rglob("*.mcap")
        for i, (topic, batch, log_time) in enumerate(iter_messages(path))
    )
    port = free_port()
    with open_session(BusSettings(port=port)) as session, Subscriber(session, f"hydro/{FLEET}/*/sensors") as sub:
        replay = start("services.replay", recording, "--speed", "inf", "--wait-subscribers", 30, "--bus-port", port)
        got = []
        deadline = time.monotonic() + 90
        while len(got) < len(expected) and time.monotonic() < deadline:
            message = sub.recv(timeout=1.0)
            if message is not None:
                got.append((str(message.key), arrays_from_sensor_chunk(message.batch)[0][0]))
        assert replay.wait(timeout=60) == 0
        assert sub.recv(timeout=0.3) is None  # nothing twice
    assert got == [(topic, t0) for _, _, _, topic, t0 in expected]


def test_recorder_killed_mid_run_keeps_every_complete_chunk(tmp_path: Path) -> None:
    port = free_port()
    recorder = start("services.recorder", "--out", tmp_path, "--fleet", FLEET, "--bus-port", port, "--flush", 0.2)
    plant = None
    try:
        wait_for(port, "record")
        plant = start("services.plant", "--fleet", FLEET, "--machines", 3, "--speed", 2, "--wait-subscribers", 30,
                      "--bus-port", port)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and sum(p.stat().st_size for p in tmp_path.rglob("*.mcap")) < 60_000:
            time.sleep(0.2)
        assert stop(recorder, signal.SIGKILL) == -signal.SIGKILL
        assert stop(plant) == 0
    finally:
        recorder.kill()
        if plant is not None:
            plant.kill()
    machines = read_machines(tmp_path / FLEET)
    assert sorted(machines) == ["m000", "m001", "m002"]
    for t, recoveries in machines.values():
        assert not recoveries[0].finished and recoveries[0].messages >= 5
        assert_contiguous(t)  # a clean prefix: the complete chunks, nothing out of order or twice


def test_two_recorder_shards_record_every_machine_exactly_once(tmp_path: Path) -> None:
    port = free_port()
    recorders = [start("services.recorder", "--out", tmp_path / f"s{i}", "--fleet", FLEET, "--shard", f"{i}/2",
                       "--bus-port", port) for i in range(2)]
    try:
        wait_for(port, "record", count=2, processes=recorders)
        plant = start("services.plant", "--fleet", FLEET, "--machines", 12, "--seconds", 1, "--speed", "inf",
                      "--wait-subscribers", 30, "--bus-port", port)
        assert plant.wait(timeout=120) == 0
        assert [stop(r) for r in recorders] == [0, 0]
    finally:
        for r in recorders:
            r.kill()
    shards = [read_machines(tmp_path / f"s{i}" / FLEET) for i in range(2)]
    assert not set(shards[0]) & set(shards[1])
    assert sorted(set(shards[0]) | set(shards[1])) == [f"m{i:03d}" for i in range(12)]
    assert min(len(s) for s in shards) >= 2  # both shards did work
    for shard in shards:
        for t, _ in shard.values():
            assert_contiguous(t, 200)


def test_up_starts_and_stops_the_services_together(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # in this process (as `hydrowatch up`): it hosts the router, the services are child processes (by default
    # plant, recorder and the web page, whose address it prints)
    code = main(["up", "--machines", "2", "--speed", "20", "--seconds", "12", "--bus-port", "0",
                 "--out", str(tmp_path), "--fleet", FLEET])
    assert code == 0
    assert "fleet page: http://127.0.0.1:" in capsys.readouterr().out
    machines = read_machines(tmp_path / FLEET)
    assert sorted(machines) == ["m000", "m001"]
    for t, recoveries in machines.values():
        assert t.size >= 200 and all(r.finished for r in recoveries)
        assert_contiguous(t)


def test_plant_declares_machine_tokens_only_when_asked() -> None:
    # per-machine tokens make every subscriber of the fleet pay per machine and message (docs/bus.md)
    port = free_port()
    plants = [start("services.plant", "--fleet", fleet, "--machines", 2, "--speed", 1, "--bus-port", port, *flag)
              for fleet, flag in (("tok", ["--machine-tokens"]), ("plain", []))]
    try:
        with open_session(BusSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",))) as session:
            for fleet in ("tok", "plain"):
                assert wait_alive(session, "plant", fleet, timeout=60)
            tokens = {fleet: [k.split("/")[2] for k in alive(session, f"hydro/{fleet}/*/status")]
                      for fleet in ("tok", "plain")}
        assert [stop(p) for p in plants] == [0, 0]
    finally:
        for p in plants:
            p.kill()
    assert sorted(tokens["tok"])[:2] == ["m000", "m001"] and len(tokens["tok"]) == 3
    assert len(tokens["plain"]) == 1 and tokens["plain"][0].startswith("plant.")


@pytest.mark.slow
def test_up_with_trainer_and_scorer_gives_every_machine_verdicts(tmp_path: Path, monkeypatch) -> None:
    # the trainer trains on the recorder's folder and registers; the scorer waits for that model, then scores
    import threading
    from contextlib import contextmanager

    import hydrowatch.bus.service as service
    from hydrowatch.report.fleet_table import verdict_rows

    monkeypatch.chdir(tmp_path)
    port, rows, ready, done = free_port(), {}, threading.Event(), threading.Event()
    enough = threading.Event()  # what Ctrl-C sets: `up` stops once every machine has verdicts enough to judge

    @contextmanager
    def stop_when_enough():
        yield enough

    monkeypatch.setattr(service, "stop_on_signals", stop_when_enough)

    def listen() -> None:
        with open_session(BusSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",))) as session, \
                Subscriber(session, f"hydro/{FLEET}/*/health") as health:
            ready.set()
            while not done.is_set():
                message = health.recv(timeout=0.5)
                if message is not None:
                    rows.setdefault(message.key.machine, []).extend(verdict_rows(message.batch))
                    if len(rows) == 2 and min(map(len, rows.values())) >= 30:
                        enough.set()

    listener = threading.Thread(target=listen, daemon=True)
    listener.start()
    assert ready.wait(30)
    try:
        code = main(["up", "--services", "plant,record,trainer,scorer", "--machines", "2", "--states",
                     "healthy,load_warning", "--speed", "20", "--seconds", "90", "--bus-port", str(port),
                     "--retrain", "10", "--method", "parity", "--fleet", FLEET,
                     "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}"])
    finally:
        done.set()
        listener.join(timeout=10)
    assert code == 0
    assert sorted(rows) == ["m000", "m001"], "every machine gets verdicts"
    for machine, truth in (("m000", "healthy"), ("m001", "load_warning")):
        states = [row["state"] for row in rows[machine]]
        assert len(states) >= 20 and states[-10:].count(truth) >= 9, (machine, states[-10:])
    assert (tmp_path / "models" / "latest").is_dir()


def wait_recorded(folder: Path, machines: list[str], until: float, timeout: float = 60) -> None:
    """Wait until ``folder`` holds a sample at plant time ``until`` s or later of each of ``machines`` (complete chunks
    of files a recorder may still be writing)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            found = read_machines(folder) if folder.is_dir() else {}
        except DataError:  # a file just created, its header not written yet
            found = {}
        if all(m in found and found[m][0].size and found[m][0][-1] >= until for m in machines):
            return
        assert time.monotonic() < deadline, f"{folder} has no sample at {until:.1f} s of every one of {machines}"
        time.sleep(0.2)


@pytest.mark.slow
def test_a_dead_recorder_shards_machines_are_taken_over_and_given_back(tmp_path: Path) -> None:
    from hydrowatch.bus import machine_hash

    port = free_port()
    args = ("--fleet", FLEET, "--bus-port", port, "--flush", 0.2)
    expected = [m for m in (f"m{i:03d}" for i in range(6)) if machine_hash(m) % 2 == 1]  # shard 1's own machines
    recorders = [start("services.recorder", "--out", tmp_path / f"s{i}", "--shard", f"{i}/2", *args) for i in range(2)]
    plant = back = None
    try:
        wait_for(port, "record", count=2)
        # runs until stopped: each step below waits for what the recorders wrote, not for a fixed time
        plant = start("services.plant", "--fleet", FLEET, "--machines", 6, "--speed", 1,
                      "--wait-subscribers", 30, "--bus-port", port)
        wait_for(port, "plant")
        began = time.monotonic()
        wait_recorded(tmp_path / "s1" / FLEET, expected, 2.0)  # shard 1 recorded its machines a while
        assert stop(recorders[1], signal.SIGKILL) == -signal.SIGKILL
        killed = time.monotonic() - began
        wait_recorded(tmp_path / "s0" / FLEET, expected, killed + 3.0)  # shard 0 has them
        back = start("services.recorder", "--out", tmp_path / "s1b", "--shard", "1/2", *args)
        wait_for(port, "record", count=2)
        returned = time.monotonic() - began
        # the plant goes on past the give-back bound below: a shard 0 that kept them would have recorded past it
        wait_recorded(tmp_path / "s1b" / FLEET, expected, returned + 10.0 + 2.0)
        assert stop(plant) == 0
        assert stop(recorders[0]) == 0 and stop(back) == 0
    finally:
        for proc in (*recorders, plant, back):
            if proc is not None:
                proc.kill()
    first, dead, again = (read_machines(tmp_path / name / FLEET) for name in ("s0", "s1", "s1b"))
    theirs = sorted(m for m in first if machine_hash(m) % 2 == 1)
    assert theirs == expected and sorted(dead) == theirs == sorted(again), "shard 1's machines: its own, then " \
        "shard 0's, back"
    for machine in theirs:
        taken = first[machine][0]
        # shard 0 began on them within 10 s of the kill (plant time ≈ wall time at speed 1, started before `began`)
        assert taken[0] <= killed + 10.0 + 1.0, (machine, taken[0], killed)
        assert taken[-1] <= returned + 10.0 + 1.0, (machine, taken[-1], returned)  # and gave them back
        assert again[machine][0][0] <= taken[-1] + 1.0  # the returned shard picked them up where shard 0 left off


def test_trainer_answers_a_stop_at_once_even_mid_training(tmp_path: Path) -> None:
    from hydrowatch.io import write_recording
    from hydrowatch.plant.fleet import simulate_states

    for rec in simulate_states(["healthy", "load_warning"], seconds=60, seed=1):
        write_recording(rec, tmp_path / f"{rec.state}.mcap")
    trainer = start("services.trainer", "--data", tmp_path, "--out", tmp_path / "model", "--every", 30,
                    "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}")
    try:
        # a fixed 4 s from the start sent SIGTERM before the handler was there when imports took longer (two test
        # workers and a benchmark on 2 cores: exit -15); training takes far longer than the 2 s after it
        wait_handles_sigterm(trainer)
        time.sleep(2)  # the stop comes mid-training
        began = time.monotonic()
        assert stop(trainer) == 0
        assert time.monotonic() - began < 5.0
    finally:
        trainer.kill()
    assert not (tmp_path / "model" / "parity").exists()  # the last method of the training never got there


def test_plant_degrade_makes_a_machine_wear_with_its_label_following() -> None:
    """``plant --degrade m001=load:0:1.2:10``: m001's load wears from new to beyond the alert over 10 s, its label
    going healthy → load_warning → load_alert; m000 stays healthy."""
    port = free_port()
    with open_session(BusSettings(port=port)) as session, Subscriber(session, f"hydro/{FLEET}/*/sensors") as sub:
        plant = start("services.plant", "--fleet", FLEET, "--machines", 2, "--seconds", 15, "--speed", "inf",
                      "--degrade", "m001=load:0:1.2:10", "--wait-subscribers", 30, "--bus-port", port)
        labels: dict[str, list[tuple[float, str]]] = {"m000": [], "m001": []}
        deadline = time.monotonic() + 90
        while sum(map(len, labels.values())) < 300 and time.monotonic() < deadline:
            message = sub.recv(timeout=1.0)
            if message is not None:
                t, channels = arrays_from_sensor_chunk(message.batch)
                labels[message.key.machine].append((float(t[0]), str(channels["state"][0])))
        assert plant.wait(timeout=60) == 0
    assert {s for _, s in labels["m000"]} == {"healthy"}
    worn = [s for _, s in sorted(labels["m001"])]
    assert len(worn) == 150 and worn[0] == "healthy" and worn[-1] == "load_alert"
    firsts = [worn.index(s) for s in ("healthy", "load_warning", "load_alert")]
    assert firsts == sorted(firsts) and worn[firsts[1]:firsts[2]] == ["load_warning"] * (firsts[2] - firsts[1])
    # the index follows the path: warning (drop 7.5-22.5 %, index 0.25-0.75) from ~2 s to ~6 s of 10
    assert 15 <= firsts[1] <= 25 and 55 <= firsts[2] <= 70, firsts


def test_watch_shows_each_machines_wear_from_the_health_and_forecast_topics() -> None:
    # and a rig's cycles machine from …/cycle_health: its verdict per cycle in the table, each component below
    import pyarrow as pa

    from hydrowatch.bus import Publisher, key
    from hydrowatch.condition.forecast import forecast_alert
    from hydrowatch.schemas import CYCLE_VERDICT, wire_schema
    from hydrowatch.training.chunks import WindowVerdict
    from hydrowatch.training.forecasts import MachineForecast
    from hydrowatch.training.messages import forecast_batch, verdict_batch
    from hydrowatch.verdict import Verdict

    t = np.arange(0.0, 1800.0, 5.0)
    index = {"load": {"value": 0.6, "ci95": [0.55, 0.65]}, "valve_coil": {"value": 0.0, "ci95": [-0.05, 0.05]}}
    health = verdict_batch(WindowVerdict("f1/m7", 1795.0, 1800.0, Verdict("load_warning", 0.9), None, index), "v")
    forecast = forecast_batch(MachineForecast("f1/m7", 1795.0, {"load": forecast_alert(t, 0.6 * t / t[-1]),
                                                               "valve_coil": forecast_alert(t, 0.0 * t)}, t.size), "v")
    cycles = pa.RecordBatch.from_pylist([
        {"cycle": c, "window_start": 60.0 * c, "window_end": 60.0 * c + 60.0, "component": component,
         "state": state, "probability": 0.9, "probabilities": [{"state": state, "probability": 0.9},
                                                               {"state": "other", "probability": 0.1}],
         "novelty": 0.4, "reason": None, "truth": None, "healthy": "100", "model_version": "v"}
        for c in range(3) for component, state in (("cooler", "100"), ("valve", "100" if c == 0 else "73"))],
        schema=wire_schema(CYCLE_VERDICT))
    port = free_port()
    watch = subprocess.Popen([sys.executable, "-m", "hydrowatch", "watch", "--fleet", FLEET, "--seconds", "8",
                              "--bus-port", str(port)], stdout=subprocess.PIPE, text=True)
    with open_session(BusSettings(port=port)) as session, Publisher(session) as publisher:
        assert publisher.wait_for_subscribers([key(FLEET, "m7", t) for t in ("health", "forecast")], timeout=30)
        while watch.poll() is None:  # as a scorer does, again and again (the first may come before all links are up)
            publisher.put(key(FLEET, "m7", "health"), health)
            publisher.put(key(FLEET, "m7", "forecast"), forecast)
            publisher.put(key(FLEET, "rig1", "cycle_health"), cycles)
            time.sleep(0.5)
        out, _ = watch.communicate(timeout=60)
    assert watch.returncode == 0
    lines = out.splitlines()
    assert any(line.startswith("f1/m7") and "load_warning" in line for line in lines), out
    worn = lines[lines.index("wear (most urgent first)") + 1]
    assert worn.startswith("f1/m7") and "load 0.60 [0.55–0.65]" in worn and "alert in 20 min" in worn, out
    assert "valve_coil" not in worn  # index 0 and no forecast: not worn
    assert any(line.startswith("f1/rig1") and "valve=73" in line and "valve 73 (p = 0.90; healthy 100) since cycle 1"
               in line for line in lines), out
    components = lines[lines.index("components (cycles machines)") + 1]
    assert components.startswith("f1/rig1") and "cooler 100 · valve 73 (p = 0.90; healthy 100) since cycle" in (
        components), out


def test_plant_answers_a_stop_while_it_waits_for_subscribers() -> None:
    """A plant waiting for subscribers (--wait-subscribers 60, nobody listening) stops at once on SIGTERM instead of
    sitting out the wait (a restarted plant in the web page's test once outlived its 30 s)."""
    port = free_port()
    plant = start("services.plant", "--fleet", FLEET, "--machines", 2, "--speed", 1, "--wait-subscribers", 60,
                  "--bus-port", port)
    try:
        wait_handles_sigterm(plant)
        time.sleep(1.0)  # inside the wait: nothing subscribes on this port
        began = time.monotonic()
        assert stop(plant) == 0
        assert time.monotonic() - began < 10.0  # measured: ~0.3 s; 60 s and more before
    finally:
        plant.kill()


def test_a_signal_that_arrives_while_the_stop_event_holds_its_lock_still_stops():
    # the handler runs in the main thread between two bytecodes; inside the stop event's own wait (its lock held on
    # the way in and out) a handler that set the event itself waited for that lock forever
    script = (
        "import os, signal\n"
        "from hydrowatch.bus.service import stop_on_signals\n"
        "with stop_on_signals() as stop:\n"
        "    with stop._cond:  # as Event.wait holds it\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "        sum(range(1000))  # the handler runs here\n"
        "    print('stopped' if stop.wait(10) else 'not stopped', flush=True)\n"
    )
    try:
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30)
    except subprocess.TimeoutExpired:
        pytest.fail("a SIGTERM inside the stop event's lock hung the process")
    assert done.stdout.strip() == "stopped", done.stderr
