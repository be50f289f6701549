"""The live fleet page with 1000 machines in a real browser: first paint and update latency.

The web service runs as its own process on a private loopback bus; this process publishes synthetic
``health_verdict`` messages (1000 machines, one in ten not healthy) as a scorer would, and drives
headless Chromium over the DevTools protocol (hydrowatch.web.browser).

* **first paint**: the fleet page loaded ``--loads`` times; for each, the time from navigation start to
  the first rows drawn and painted (the page's own ``performance.now()``, taken in the animation frame
  after the snapshot's rows were put in the table) and, from this process, the time until the page
  knows all 1000 rows (it draws those in view: services/web/static/fleet.js). The machine page (360
  verdicts of history, 12 windows of evidence) likewise.
* **update latency**: every machine gets a verdict every ``--window`` seconds (as the scorer publishes
  them: 1000 / 5 s = 200 verdicts/s), a tenth of them with a changed state (so rows move); for every
  verdict the page shows, its publish time (attached on the bus) to the animation frame after the row
  was redrawn (the page's ``Date.now()``; same clock). Targets (issue 16): first paint < 1 s, updates
  < 200 ms.

Usage: python benchmarks/bench_web.py [--machines 1000] [--seconds 15] [--loads 5] [--screenshots DIR]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa

from hydrowatch.bus import BusSettings, Publisher, free_port, key, open_session
from hydrowatch.training.chunks import WindowVerdict
from hydrowatch.training.messages import kl_batch, verdict_batch
from hydrowatch.verdict import Verdict
from hydrowatch.web.browser import Chromium, find_chromium

TARGET_FIRST_PAINT_MS = 1000.0
TARGET_UPDATE_MS = 200.0
FLEET = "bench"
STATES = ("healthy", "load_warning", "load_alert", "pump_leak_warning", "pump_leak_alert", "unknown")


KNOWN = [s for s in STATES if s != "unknown"]
RELATIONS = ("load", "motor", "valve")


def verdict(machine: str, t: float, state: str, window: float) -> pa.RecordBatch:
    """A ``health_verdict`` message as the scorer builds it (p = 0.9 for a trained state, 0 for unknown)."""
    p = 0.0 if state == "unknown" else 0.9
    probabilities = {s: p if s == state else (1 - p) / len(KNOWN) for s in KNOWN}
    return verdict_batch(WindowVerdict(machine, t, t + window, Verdict(state, p or None, probabilities)), "bench/v1")


def evidence(machine: str, t: float, window: float, rng: np.random.Generator) -> pa.RecordBatch:
    """A ``kl_window`` message as the scorer builds it (random relation scores)."""
    scores = rng.uniform(1.0, 20.0, (len(RELATIONS), len(KNOWN)))
    item = WindowVerdict(machine, t, t + window, Verdict("healthy", 0.9), scores)
    batch = kl_batch(item, RELATIONS, KNOWN, "bench/v1")
    assert batch is not None
    return batch


def stats(values: list[float]) -> str:
    a = np.asarray(values)
    return (f"n={a.size} p50={np.percentile(a, 50):.0f} p95={np.percentile(a, 95):.0f} "
            f"p99={np.percentile(a, 99):.0f} max={a.max():.0f} ms")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=1000)
    parser.add_argument("--seconds", type=float, default=15.0, help="wall-clock seconds of updates measured")
    parser.add_argument("--window", type=float, default=5.0, help="seconds between two verdicts of a machine")
    parser.add_argument("--loads", type=int, default=5, help="page loads measured for the first paint")
    parser.add_argument("--screenshots", type=Path, default=None, help="write the pages' screenshots here")
    args = parser.parse_args()
    if find_chromium() is None:
        print("skipped: no Chromium installed (apt-get install chromium)")
        return 0
    load_before = os.getloadavg()[0]
    rng = np.random.default_rng(0)
    machines = [f"m{i:04d}" for i in range(args.machines)]
    state = {m: ("healthy" if rng.random() > 0.1 else str(rng.choice(STATES[1:]))) for m in machines}
    port = free_port()
    http = free_port(avoid={port})
    web = subprocess.Popen([sys.executable, "-m", "services.web", "--fleet", FLEET, "--port", str(http),
                            "--bus-port", str(port)])
    url = f"http://127.0.0.1:{http}/"
    try:
        with open_session(BusSettings(port=port)) as session, Publisher(session) as publisher, \
                Chromium(width=1280, height=900) as browser:
            keys = [key(FLEET, m, "health") for m in machines]
            if not publisher.wait_for_subscribers(keys[:1], timeout=60):
                print("the web service did not come up")
                return 1
            # history: 360 windows of the first machine (its page's timeline), then one verdict of every machine
            for k in range(360):
                publisher.put(keys[0], verdict(machines[0], args.window * k, STATES[(k // 60) % len(STATES)],
                                               args.window))
                if k >= 348:
                    publisher.put(key(FLEET, machines[0], "kl"), evidence(machines[0], args.window * k, args.window,
                                                                          rng))
            t = 360 * args.window
            for m, k in zip(machines, keys):
                publisher.put(k, verdict(m, t, state[m], args.window))
            browser.navigate(url)
            browser.wait_for(f"window.hw.shown === {args.machines}", timeout=60)

            page_ms, rows_ms = [], []
            for _ in range(args.loads):
                t0 = time.monotonic()
                browser.navigate(url)
                browser.wait_for(f"window.hw.shown === {args.machines}", timeout=30,
                                 poll=0.005)
                rows_ms.append((time.monotonic() - t0) * 1000)
                page_ms.append(browser.wait_for("window.hw.firstRowsMs", timeout=10))
            if args.screenshots:
                args.screenshots.mkdir(parents=True, exist_ok=True)
                browser.screenshot(args.screenshots / "web-fleet-1000.png", palette=True)
            machine_ms = []
            for _ in range(args.loads):
                browser.navigate(f"{url}machine?id={FLEET}/{machines[0]}")
                machine_ms.append(browser.wait_for("window.hw.firstRowsMs", timeout=10))

            browser.navigate(url)
            browser.wait_for(f"window.hw.shown === {args.machines}", timeout=30)
            per_tick = max(1, round(args.machines * 0.05 / args.window))  # verdicts every 50 ms
            start, sent, i = time.monotonic(), 0, 0
            while time.monotonic() - start < args.seconds:
                tick = time.monotonic()
                for _ in range(per_tick):
                    m = machines[i % args.machines]
                    if rng.random() < 0.1:  # a tenth change state: their rows move
                        state[m] = "healthy" if state[m] != "healthy" else str(rng.choice(STATES[1:]))
                    publisher.put(keys[i % args.machines], verdict(m, t + args.window * (1 + i // args.machines),
                                                                   state[m], args.window))
                    i += 1
                    sent += 1
                time.sleep(max(0.0, 0.05 - (time.monotonic() - tick)))
            time.sleep(1.0)
            lags = browser.evaluate("window.hw.lags")
            counts = browser.evaluate("[window.hw.applied, window.hw.snapshots]")
    finally:
        web.send_signal(signal.SIGTERM)
        web.wait(timeout=30)
    load_after = os.getloadavg()[0]
    print(f"machines={args.machines} load average (1 min) before={load_before:.2f} after={load_after:.2f} "
          f"cores={os.cpu_count()}")
    print(f"fleet page first paint (navigation -> rows painted, in the page): {stats(page_ms)} "
          f"target < {TARGET_FIRST_PAINT_MS:.0f} ms: {'ok' if max(page_ms) < TARGET_FIRST_PAINT_MS else 'MISSED'}")
    print(f"fleet page load -> its {args.machines} rows known, the first drawn (seen over DevTools): "
          f"{stats(rows_ms)}")
    print(f"machine page first paint (360 verdicts, 12 windows of evidence): {stats(machine_ms)}")
    p95 = float(np.percentile(lags, 95)) if lags else float("nan")
    print(f"updates: {sent} verdicts published in {args.seconds:.0f} s ({sent / args.seconds:.0f}/s), "
          f"{len(lags)} shown in {counts[0]} page messages ({counts[1]} snapshot)")
    print(f"update latency (publish -> row redrawn and painted): {stats(lags)} "
          f"target p95 < {TARGET_UPDATE_MS:.0f} ms: {'ok' if p95 < TARGET_UPDATE_MS else 'MISSED'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
