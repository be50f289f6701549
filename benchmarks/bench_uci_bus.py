"""The real UCI hydraulic rig through a recording and the bus (issue 17): import, the honest split streamed.

Reads ../shared/data/uci-hydraulic (or $HYDROWATCH_DATA/uci-hydraulic) through the description ``uci-hydraulic``
and prints:

1. import: the folder read (``read_rig_data``), written as an MCAP recording of ``rig_cycles`` messages
   (``write_rig_recording``, what ``hydrowatch import --rig`` does), read back (equal values and labels checked);
   times and sizes;
2. a cycles bundle whose component models are each fitted on that component's honest-split training cycles only
   (each class's first 70 % in recording order; the feature set chosen inside them, as ``train --rig`` does), saved
   (``model.json`` size) and loaded;
3. the bus: the scorer service (a separate process, Zenoh peer mode on loopback) with that bundle, the replay
   service publishing the recording as fast as it can; every ``cycle_verdict`` row collected; per component the
   accuracy on its *test* cycles (each class's last 30 %, never seen by that component's model), the share of rows
   equal to ``score`` of the same cycles offline, and the wall time from the replay's start to the last verdict.

    OMP_NUM_THREADS=1 python benchmarks/bench_uci_bus.py
"""

from __future__ import annotations

import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hydrowatch.bus import BusSettings, Subscriber, free_port, open_session, wait_alive
from hydrowatch.cycles import ordered_split
from hydrowatch.io.rig_cycles import read_rig_data, read_rig_recording, write_rig_recording
from hydrowatch.methods.cycles import CyclesMethod
from hydrowatch.methods.cycles.train import component_data, fit_component
from hydrowatch.rig import data_root
from hydrowatch.rig.description import rig_text
from hydrowatch.training import load_bundle
from hydrowatch.training.bundle import ModelBundle
from hydrowatch.training.rig_pipeline import score_cycles


def main() -> int:
    folder = data_root() / "uci-hydraulic"
    if not (folder / "profile.txt").is_file():
        print(f"the UCI hydraulic data is not at {folder}; nothing measured")
        return 0
    rig, text = rig_text("uci-hydraulic")
    with tempfile.TemporaryDirectory(prefix="bench-uci-bus-") as tmp:
        out = Path(tmp)
        clock = time.perf_counter()
        cycles = read_rig_data(folder, rig)
        read_s = time.perf_counter() - clock
        clock = time.perf_counter()
        recording = write_rig_recording(out / "uci.mcap", cycles, rig, text, fleet="uci", machine="rig")
        write_s = time.perf_counter() - clock
        clock = time.perf_counter()
        _, back = read_rig_recording(recording)
        back_s = time.perf_counter() - clock
        same = np.array_equal(back.values, cycles.values) and all(
            np.array_equal(back.labels[k], v) for k, v in cycles.labels.items())
        print(f"import: {len(cycles)} cycles, {len(cycles.channels)} channels x {rig.window.samples} samples; folder "
              f"read {read_s:.1f} s, MCAP written {write_s:.1f} s ({recording.stat().st_size / 1e6:.1f} MB), read "
              f"back {back_s:.1f} s, identical: {same}")

        clock = time.perf_counter()
        models, features, tests = {}, {}, {}
        for c in rig.components:
            data = component_data(rig, cycles.values, cycles.labels, c)
            train, tests[c] = ordered_split(data.states)
            models[c], features[c], _ = fit_component(rig, data.part(train))
        method = CyclesMethod(text, models, features)
        bundle = ModelBundle(method, {"method": "cycles", "rig": rig.name, "states": method.states,
                                      "sensors": method.sensors, "window": method.window, "hop": method.hop})
        bundle.save(out / "model")
        fit_s = time.perf_counter() - clock
        size = (out / "model" / "cycles" / "model.json").stat().st_size
        offline = score_cycles(load_bundle(out / "model"), cycles)
        print(f"bundle: fitted per component on its honest training cycles in {fit_s:.1f} s; features {features}; "
              f"model.json {size / 1e6:.2f} MB")

        port = free_port()
        scorer = subprocess.Popen([sys.executable, "-m", "services.scorer", "--model", str(out / "model"),
                                   "--fleet", "uci", "--bus-port", str(port)], stderr=subprocess.DEVNULL)
        rows: list[dict[str, object]] = []
        try:
            with open_session(BusSettings(port=port)) as session, \
                    Subscriber(session, "hydro/uci/*/cycle_health") as health:
                if not wait_alive(session, "scorer", "uci", 1, timeout=120):
                    print("the scorer did not come up")
                    return 1
                clock = time.perf_counter()
                replay = subprocess.Popen([sys.executable, "-m", "services.replay", str(recording), "--speed", "inf",
                                           "--bus-port", str(port), "--linger", "2"], stderr=subprocess.DEVNULL)
                want = len(cycles) * len(models)
                deadline = time.monotonic() + 300
                while len(rows) < want and time.monotonic() < deadline:
                    message = health.recv(timeout=1.0)
                    if message is not None:
                        rows += message.batch.to_pylist()
                bus_s = time.perf_counter() - clock
                replay.wait(timeout=60)
        finally:
            scorer.send_signal(signal.SIGTERM)
            scorer.wait(timeout=60)
        print(f"bus: {len(rows)} of {len(cycles) * len(models)} verdict rows in {bus_s:.1f} s from the replay's "
              f"start ({len(cycles) / bus_s:.0f} cycles/s, the replay's and scorer's start-up included)")
        print("| component | features | honest test cycles | accuracy on the bus | read unknown | rows = offline "
              "score |")
        print("|---|---|---|---|---|---|")
        for c in models:
            mine = {int(r["cycle"]): r for r in rows if r["component"] == c}  # type: ignore[call-overload]
            test = [i for i in tests[c] if i in mine]
            right = np.mean([mine[i]["state"] == mine[i]["truth"] for i in test])
            unknown = np.mean([mine[i]["state"] == "unknown" for i in test])
            agree = np.mean([mine[i]["state"] == offline["cycles"][i]["components"][c]["state"] for i in mine])
            print(f"| {c} | {features[c]} | {len(test)} of {len(tests[c])} | {right:.1%} | {unknown:.1%} | "
                  f"{agree:.1%} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
