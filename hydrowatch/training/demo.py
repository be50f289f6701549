"""The embedded end-to-end run behind ``hydrowatch demo``.

1. identification recordings per health state (filtered noise 0-4 V, like the study);
2. training of a parity bundle (component relations) and of the study's method with Box-Jenkins
   and with NARX reference models, each tracked in MLflow and registered;
3. accuracy of each on recordings of another seed, with the training command, a working duty
   cycle and a narrow range (logged as MLflow metrics); the alias ``champion`` goes to the one
   with the best duty-cycle accuracy (ties: parity, then NARX);
4. a live fleet on the bus: machines with faults appearing (degradation paths) simulated in-process
   and published through the plant service's :class:`~hydrowatch.bus.fleet_publisher.FleetPublisher`
   (each machine's label follows its path), a recorder and a scorer as separate processes, the live
   table fed by the health topic, each machine's wear (index, trend, time to alert) by the health and
   forecast topics;
5. an HTML report with the plots, confusion matrices and per-machine timelines.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hydrowatch.bus import BusSettings, Publisher, Subscriber, alive, free_port, key_expr, open_session
from hydrowatch.bus.fleet_publisher import FleetPublisher
from hydrowatch.channels import STUDY_RIG
from hydrowatch.io import write_recording
from hydrowatch.log import event, get_logger
from hydrowatch.plant.excitation import FilteredNoiseCommand
from hydrowatch.plant.faults import LEVELS, STUDY_STATES
from hydrowatch.plant.fleet import DegradationPath, Fleet, MachineSpec, simulate_states
from hydrowatch.recording import SAMPLE_RATE_HZ
from hydrowatch.report.fleet_table import FleetTable, FleetWear, forecast_parts, verdict_rows
from hydrowatch.results import TrainingResult
from hydrowatch.training.options import DEFAULT_ALIAS, TrainingSettings, mlflow_name
from hydrowatch.training.pipeline import train_and_track
from hydrowatch.training.tracking import set_alias
from hydrowatch.web import web_port

_log = get_logger(__name__)
FLEET = "demo"
WEAR_S = 900.0
"""Seconds the demo's wearing machine (m06) takes from new to index 1.3."""
MACHINES = (
    MachineSpec("m00"),
    MachineSpec("m01", state="load_warning"),
    MachineSpec("m02", path=DegradationPath("load", 20.0, 60.0)),
    MachineSpec("m03", path=DegradationPath("pump_leak", 20.0, 60.0)),
    MachineSpec("m04", path=DegradationPath("motor_leak", 20.0, 60.0)),
    MachineSpec("m05", path=DegradationPath("valve_leak", 20.0, 60.0)),
    MachineSpec("m06", path=DegradationPath("motor_leak", 0.0, WEAR_S, final_drop=1.3 * LEVELS["alert"])),
)
"""The live fleet: healthy, a fixed fault, three study faults appearing, one fault never trained (valve leak), and
one motor leak wearing slowly from new (index 0 → 1.3 over 15 min: 0.48 after the default 330 s, the alert at
692 s), whose forecast the scorer publishes."""
FORECAST_EVERY = 3
"""Windows between two forecasts of a machine in the demo (15 s; the scorer's default is 60: the demo is short, and
a forecast needs 300 s of history, so every machine's last one must come in the last windows of the 330 s)."""


@dataclass
class DemoSettings:
    """Sizes of the demo (defaults finish in a few minutes on 2 cores); ``training`` maps run names to settings."""

    out: Path
    training: dict[str, TrainingSettings]
    tracking: str | None = None
    seed: int = 0
    accuracy_seconds: float = 60.0
    live_seconds: float = 330.0
    """Simulated seconds of the live fleet: faults appear from 20 s to 60 s, and the scorer pools 12 windows; m06's
    forecast needs 300 s of its history."""
    speed: float = 10.0
    web_port: int | None = None
    """Port of the live fleet page (None: 8050 when free, else any free port)."""


def identification_data(folder: Path, settings: TrainingSettings, seed: int) -> list[Path]:
    """Simulate one recording per study state, as long as the data plan needs."""
    folder.mkdir(parents=True, exist_ok=True)
    seconds = settings.plan.samples_per_state / SAMPLE_RATE_HZ + 1.0
    return [write_recording(r, folder / f"{r.state}.mcap") for r in simulate_states(STUDY_STATES, seconds=seconds,
                                                                                     seed=seed)]


def _spawn(module: str, argv: list[str], log_file: Path) -> subprocess.Popen:
    with open(log_file, "ab") as fh:
        return subprocess.Popen([sys.executable, "-m", module, *argv], stdout=fh, stderr=subprocess.STDOUT)


def _stop(processes: list[subprocess.Popen], grace_s: float = 20.0) -> None:
    for proc in processes:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def live_fleet(s: DemoSettings, bundle_dir: Path, show: bool) -> dict[str, Any]:
    """Run the fleet on a private loopback bus with recorder and scorer processes; returns verdicts and truth."""
    port = free_port()
    bus = ["--bus-port", str(port)]
    logs = s.out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    http_port = web_port(s.web_port)
    web = f"http://127.0.0.1:{http_port}/"
    processes = [
        _spawn("services.recorder", ["--out", str(s.out / "recordings"), "--fleet", FLEET, *bus],
               logs / "recorder.log"),
        _spawn("services.scorer", ["--model", str(bundle_dir), "--fleet", FLEET, "--forecast-every",
                                   str(FORECAST_EVERY), *bus], logs / "scorer.log"),
        _spawn("services.web", ["--fleet", FLEET, "--port", str(http_port), *bus], logs / "web.log"),
    ]
    print(f"live fleet page (while the live fleet runs): {web}", file=sys.stderr, flush=True)
    fleet = Fleet(list(MACHINES), fleet=FLEET, seed=s.seed + 1)
    command = FilteredNoiseCommand(fleet.n_machines, seed=s.seed + 2)
    table = FleetTable()
    wear = FleetWear()
    timelines: dict[str, list[tuple[float, float, str]]] = {m: [] for m in fleet.machine_ids}
    truth: dict[str, list[tuple[float, str]]] = {m: [] for m in fleet.machine_ids}
    n = int(0.1 * SAMPLE_RATE_HZ)
    try:
        with open_session(BusSettings(port=port)) as session, Publisher(session) as publisher, \
                Subscriber(session, [key_expr(FLEET, "*", "health"), key_expr(FLEET, "*", "forecast")]) as health:
            deadline = time.monotonic() + 120.0
            while not any(k.split("/")[2].startswith("scorer.") for k in alive(session)):
                if time.monotonic() > deadline or any(p.poll() is not None for p in processes):
                    raise RuntimeError(f"the scorer did not come up; see {logs / 'scorer.log'}")
                time.sleep(0.5)
            fleet.settle(2.0)
            sensors = FleetPublisher(publisher, FLEET, fleet.machine_ids, STUDY_RIG, fleet.states)
            wall0, last_draw = time.monotonic(), 0.0
            while fleet.time < s.live_seconds:
                out = fleet.step(command.next(n))
                labels = fleet.states
                sensors.publish(out, labels)
                for i, machine in enumerate(fleet.machine_ids):
                    truth[machine].append((float(out["t"][i][0]), labels[i]))
                _receive(health, table, timelines, wear)
                ahead = wall0 + fleet.time / s.speed - time.monotonic()
                if ahead > 0:
                    time.sleep(ahead)
                if show and time.monotonic() - last_draw > 2.0:
                    print("\x1b[2J\x1b[H" + table.render(), file=sys.stderr, flush=True)
                    last_draw = time.monotonic()
            _stop(processes[1:])  # the scorer drains and publishes its last verdicts
            quiet = time.monotonic() + 2.0
            while time.monotonic() < quiet:
                _receive(health, table, timelines, wear, wait=0.2)
    finally:
        _stop(processes)
    return {"table": table, "timelines": timelines, "truth": truth, "web": web, "wear": wear.by_machine()}


def _receive(health: Subscriber, table: FleetTable, timelines: dict[str, list], wear: FleetWear,
             wait: float = 0.0) -> None:
    while (message := health.recv(timeout=wait)) is not None:
        if message.key.topic == "forecast":
            wear.add_forecast(message.key.machine, forecast_parts(message.batch)[1])
            wait = 0.0
            continue
        for row in verdict_rows(message.batch):
            wear.add_verdict(message.key.machine, row)
            table.update(message.key.machine, row)
            timelines.setdefault(message.key.machine, []).append(
                (row["window_start"], row["window_end"], row["state"]))
        wait = 0.0


def run_demo(s: DemoSettings, *, show: bool = False) -> dict[str, Any]:
    """The whole demo; returns the summary (paths, accuracies, final table) and writes ``report.html``."""
    from hydrowatch.report.demo import write_demo_report

    s.out.mkdir(parents=True, exist_ok=True)
    first = next(iter(s.training.values()))
    t0 = time.monotonic()
    identification_data(s.out / "identification", first, s.seed)
    event(_log, "identification data simulated", seconds=round(time.monotonic() - t0, 1))
    results: dict[str, TrainingResult] = {}
    summaries: dict[str, dict[str, Any]] = {}
    for kind, settings in s.training.items():
        results[kind], summaries[kind] = train_and_track(
            s.out / "identification", s.out / "models" / kind, settings, tracking=s.tracking, alias=None,
            check_seconds=s.accuracy_seconds, check_seed=s.seed + 100)
    accuracy = {kind: list(r.evaluation["checks"]) for kind, r in results.items()}
    champion = max(results, key=lambda k: (summaries[k]["checks"]["duty_cycle"] or 0.0, k == "parity", k == "narx"))
    set_alias(mlflow_name(), DEFAULT_ALIAS, str(summaries[champion]["registered_version"]), s.tracking)
    live = live_fleet(s, s.out / "models" / champion, show)
    report = write_demo_report(s.out / "report.html", results, accuracy, live, champion)
    return {
        "out": str(s.out), "report": str(report), "champion": champion,
        "training": summaries,
        "accuracy": {k: summaries[k]["checks"] for k in accuracy},
        "fleet": {m: r.state for m, r in live["table"].rows().items()},
        "attention": live["table"].attention(),
        "wear": {m: parts for m, parts in live["wear"].items() if any("alert_in_s" in p for p in parts.values())},
        "web": live["web"],
        "seconds": round(time.monotonic() - t0, 1),
    }
