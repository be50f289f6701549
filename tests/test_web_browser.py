"""The live fleet page in a real browser: plant, scorer and web on loopback, headless Chromium over DevTools.

Every machine appears with the state the plant gives it, a fault that appears in the fleet (the plant
restarted with one machine faulty) shows up without a reload, and a machine page opens from the fleet page
with its verdict, timeline, evidence, its sensors against what the model expected, and its measured sensors.
Skipped where no Chromium is installed (``make test`` installs Debian's ``chromium`` where apt is available).
Set ``HYDROWATCH_SCREENSHOTS=docs`` to write the screenshots of docs/web.md.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from hydrowatch.web.browser import Chromium, find_chromium

pytestmark = pytest.mark.skipif(find_chromium() is None,
                                reason="no Chromium installed (apt-get install chromium; `make test` does it where "
                                       "apt is available)")
FLEET = "wf"
STATES = ["healthy", "load_alert", "pump_leak_alert"]


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A parity bundle of three states, trained on a small plan (as tests/test_pipeline_online.py)."""
    from hydrowatch.health.plan import DataPlan
    from hydrowatch.plant.fleet import simulate_states
    from hydrowatch.training.options import TrainingSettings
    from hydrowatch.training.trainer import train

    plan = DataPlan(reference_samples=2000, base_samples=2000, classifier_windows=12, window=1000, hop=1000)
    grouped = {r.state: [r] for r in simulate_states(STATES, seconds=plan.samples_per_state / 200 + 1, seed=0)}
    return train(grouped, TrainingSettings(method="parity", plan=plan)).bundle.save(
        tmp_path_factory.mktemp("web") / "model")


def start(module: str, *argv: object) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", module, *map(str, argv)])


def stop(proc: subprocess.Popen) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def plant(port: int, states: list[str], seed: int) -> subprocess.Popen:
    return start("services.plant", "--fleet", FLEET, "--machines", len(states), "--states", ",".join(states),
                 "--speed", 20, "--seed", seed, "--wait-subscribers", 30, "--linger", 0.2, "--bus-port", port)


@pytest.fixture
def services(bundle_dir: Path) -> Iterator[tuple[int, str, list[subprocess.Popen]]]:
    """Web and scorer on a private loopback bus; the test adds plants to the list it gets."""
    from hydrowatch.bus import free_port

    port = free_port()
    http = free_port(avoid={port})
    running = [start("services.web", "--fleet", FLEET, "--port", http, "--bus-port", port),
               start("services.scorer", "--model", bundle_dir, "--fleet", FLEET, "--smoothing", 3, "--bus-port", port)]
    try:
        yield port, f"http://127.0.0.1:{http}/", running
    finally:
        codes = [stop(p) for p in reversed(running)]
        assert codes == [0] * len(codes)


def page_states(browser: Chromium) -> dict[str, str]:
    return browser.evaluate(
        "Object.fromEntries([...document.querySelectorAll('#rows tr[data-id]')].map(tr => "
        "[tr.cells[0].textContent, tr.querySelector('.badge').textContent]))") or {}


def wait_states(browser: Chromium, want: dict[str, str], timeout: float) -> dict[str, str]:
    deadline = time.monotonic() + timeout
    while (seen := page_states(browser)) != want and time.monotonic() < deadline:
        time.sleep(0.1)
    return seen


@pytest.mark.slow
def test_the_fleet_page_shows_every_machine_and_a_new_fault_without_reload(
        services: tuple[int, str, list[subprocess.Popen]], tmp_path: Path) -> None:
    port, url, running = services
    shots = Path(os.environ.get("HYDROWATCH_SCREENSHOTS") or tmp_path)
    with Chromium(width=1100, height=420) as browser:
        running.append(plant(port, ["healthy", "load_alert", "healthy"], seed=1))
        browser.navigate(url)
        before = {"m000": "healthy", "m001": "load_alert", "m002": "healthy"}
        assert wait_states(browser, before, timeout=60) == before
        # the order is the server's: most urgent first
        assert browser.evaluate("document.querySelector('#rows tr[data-id]').cells[0].textContent") == "m001"
        browser.evaluate("window.noReload = true")
        browser.screenshot(shots / "web-fleet.png", palette=True)

        # the plant restarts with m002 faulty: its verdicts turn to the fault, the page follows in place
        assert stop(running.pop()) == 0
        running.append(plant(port, ["healthy", "load_alert", "pump_leak_alert"], seed=2))
        after = {**before, "m002": "pump_leak_alert"}
        assert wait_states(browser, after, timeout=60) == after
        assert browser.evaluate("window.noReload === true && window.hw.snapshots === 1")
        assert browser.evaluate("[...document.querySelectorAll('#rows tr[data-id]')].slice(0, 2).map(tr => "
                                "tr.cells[0].textContent).sort().join()") == "m001,m002"

        # a machine page opens from its link
        browser.evaluate("document.querySelector('#rows a[href*=\"m001\"]').click()")
        browser.wait_for("location.pathname === '/machine' && window.hw && window.hw.updates > 0", timeout=20)
        assert browser.evaluate("document.querySelector('#verdict .badge').textContent") == "load_alert"
        # the scorer's degradation index (health_verdict v2) is shown beside the verdict
        assert browser.wait_for("document.querySelector('#verdict').textContent.includes('degradation')", timeout=10)
        assert browser.evaluate("document.querySelectorAll('#states rect').length") > 0
        assert browser.wait_for("document.querySelectorAll('#evidence table.heat td').length", timeout=10) > 0
        # its sensors are followed while the page is open: measured samples arrive on the page
        assert browser.wait_for("document.querySelectorAll('#sensors svg path').length", timeout=20) >= 4
        # and what the model expected of its last windows, beside what was measured (…/expected): a chart per sensor
        # with two lines, the load alert's torque far above what the healthy unit's load relation asks
        assert browser.wait_for("document.querySelectorAll('#expected svg').length", timeout=30) == 3
        assert browser.evaluate("[...document.querySelectorAll('#expected .sensor')].map(e => e.dataset.sensor)"
                                ".join()") == "flow,speed,torque"
        assert browser.evaluate("[...document.querySelectorAll('#expected svg')].map(s => [...s.querySelectorAll("
                                "'path')].filter(p => (p.getAttribute('d').match(/L/g) || []).length >= 40).length)"
                                ) == [2, 2, 2]
        assert browser.evaluate("document.getElementById('x-legend').textContent") == "measuredexpected"
        lines = json.loads(urllib.request.urlopen(url + "api/machine?id=wf/m001", timeout=10).read())["expected"]
        assert {n: line["source"] for n, line in lines.items()} == {
            "flow": "valve relation", "speed": "motor relation", "torque": "load relation"}
        torque, flow = lines["torque"], lines["flow"]
        assert np.nanmean(np.array(torque["measured"], dtype=float)) > 1.5 * np.nanmean(
            np.array(torque["expected"], dtype=float))
        assert np.nanmean(np.abs(np.array(flow["measured"], dtype=float) - np.array(flow["expected"], dtype=float))
                          ) < 0.1 * np.nanmean(np.array(flow["measured"], dtype=float))
        browser.screenshot(shots / "web-machine.png", full_page=True, palette=True)
        assert browser.exceptions() == []


def test_a_thousand_machines_are_all_reachable_and_filtered_on_the_server(tmp_path: Path) -> None:
    """1000 machines: the page draws the rows in view only, scrolling brings the last one, a state filter
    shows exactly that state's machines (and goes into the address), markup in a message is shown as text,
    and the pages raise no JavaScript error."""
    from hydrowatch.bus import BusSettings, Publisher, free_port, key, open_session
    from hydrowatch.training.chunks import WindowVerdict
    from hydrowatch.training.messages import verdict_batch
    from hydrowatch.verdict import Verdict

    port = free_port()
    http = free_port(avoid={port})
    machines = [f"m{i:04d}" for i in range(1000)]
    truth = {m: "load_alert" if i % 50 == 7 else "healthy" for i, m in enumerate(machines)}
    truth["m0500"] = "<img src=x onerror=window.pwned=1>"  # what comes off the bus is shown, never run
    web = start("services.web", "--fleet", "big", "--port", http, "--bus-port", port)
    try:
        with open_session(BusSettings(port=port)) as session, Publisher(session) as publisher, \
                Chromium(width=1000, height=600) as browser:
            assert publisher.wait_for_subscribers([key("big", machines[0], "health")], timeout=60)
            for m in machines:
                publisher.put(key("big", m, "health"),
                              verdict_batch(WindowVerdict(m, 0.0, 5.0, Verdict(truth[m], 0.9)), "t/v1"))
            browser.navigate(f"http://127.0.0.1:{http}/")
            browser.wait_for("window.hw.shown === 1000", timeout=30)
            drawn = browser.evaluate("document.querySelectorAll('#rows tr[data-id]').length")
            assert 20 < drawn < 200
            assert browser.evaluate("document.querySelector('#rows tr[data-id]').dataset.id") == "big/m0007"
            browser.evaluate("window.scrollTo(0, document.body.scrollHeight)")
            browser.wait_for("document.querySelector('#rows tr[data-id=\"big/m0999\"]') !== null", timeout=10)
            browser.evaluate("const s = document.getElementById('state'); s.value = 'load_alert';"
                             "s.dispatchEvent(new Event('change'))")
            browser.wait_for("window.hw.shown === 20 && window.hw.snapshots === 2", timeout=10)
            assert browser.evaluate("location.search") == "?state=load_alert"
            badges = browser.evaluate("[...document.querySelectorAll('#rows .badge')].map(b => b.textContent)")
            assert badges == ["load_alert"] * 20
            browser.evaluate("const box = document.getElementById('machine'); box.value = 'M095';"
                             "box.dispatchEvent(new Event('input'))")  # and only ids with 'm095' in them
            browser.wait_for("window.hw.shown === 1 && window.hw.snapshots === 3", timeout=10)
            assert browser.evaluate("location.search") == "?state=load_alert&machine=M095"  # m0957
            assert browser.exceptions() == []
            browser.navigate(f"http://127.0.0.1:{http}/?state=warning")
            browser.wait_for("window.hw.shown === 1", timeout=10)
            assert browser.evaluate("document.querySelector('#rows .badge').textContent") == truth["m0500"]
            browser.navigate(f"http://127.0.0.1:{http}/machine?id=big/m0500")
            browser.wait_for("window.hw.updates > 0", timeout=10)
            assert browser.evaluate("typeof window.pwned") == "undefined" and browser.exceptions() == []
    finally:
        assert stop(web) == 0


def test_a_degradation_index_shows_when_a_verdict_carries_one() -> None:
    """A verdict's index (health_verdict v2) and the machine's forecast (…/forecast), fed here directly: each part's
    index, trend and time to alert, the soonest alert first, on the fleet page and the machine page."""
    import threading

    from hydrowatch.web.live import FleetLive
    from services.web.server import WebServer

    live = FleetLive()
    index = {"load": {"value": 0.4, "ci95": [0.3, 0.5], "rate_per_h": 0.1, "alert_in_s": 21600.0}}
    live.add_verdict("f1", "m0", {"window_start": 0.0, "window_end": 5.0, "state": "healthy", "probability": 0.9,
                                  "probabilities": {"healthy": 0.9}, "reason": None, "degradation": index})
    live.add_verdict("f1", "m1", {"window_start": 0.0, "window_end": 5.0, "state": "healthy", "probability": 0.9,
                                  "probabilities": {"healthy": 0.9}, "reason": None})
    live.add_forecast("f1", "m0", {"motor_leak": {"alert_in_s": 900.0, "ci95": [600.0, 1500.0], "rate_per_h": 2.0,
                                                  "level": 0.5}})
    with WebServer(live, threading.Condition()) as server, Chromium(width=1000, height=400) as browser:
        browser.navigate(server.url)
        browser.wait_for("window.hw.shown === 2", timeout=10)
        assert browser.evaluate("document.querySelector('th.degcol').hidden") is False
        shown = ["motor_leak 0.50 ↑2.00/h alert in 15 min", "load 0.40 [0.30–0.50] ↑0.10/h alert in 6.0 h"]
        assert browser.evaluate("Array.from(document.querySelectorAll('#rows tr[data-id=\"f1/m0\"] td.degcol .deg'))"
                                ".map((e) => e.textContent)") == shown
        browser.navigate(server.url + "machine?id=f1/m0")
        browser.wait_for("window.hw.updates > 0", timeout=10)
        assert "".join(shown) in browser.evaluate("document.getElementById('verdict').textContent")
        assert browser.exceptions() == []


def test_a_cycles_machine_shows_each_components_verdict() -> None:
    """A rig's cycles machine (…/cycle_health, fed here directly): its row with a chip per component coloured by its
    level, and on its page the components' table and each component's probability of its healthy state."""
    import threading

    from hydrowatch.web.live import FleetLive
    from services.web.server import WebServer

    live = FleetLive()
    live.add_verdict("f1", "m0", {"window_start": 0.0, "window_end": 5.0, "state": "healthy", "probability": 0.9,
                                  "probabilities": {"healthy": 0.9}, "reason": None})
    rows = [{"cycle": c, "window_start": 60.0 * c, "window_end": 60.0 * c + 60.0, "component": name, "state": state,
             "probability": 0.9, "probabilities": {healthy: 0.9 if state == healthy else 0.1, "x": 0.1},
             "novelty": 0.3, "reason": None, "truth": None, "healthy": healthy, "model_version": "v"}
            for c in range(2) for name, healthy, state in (("cooler", "100", "100"),
                                                           ("valve", "100", "100" if c == 0 else "73"))]
    live.add_cycle_verdicts("lab", "rig1", rows)
    with WebServer(live, threading.Condition()) as server, Chromium(width=1200, height=400) as browser:
        browser.navigate(server.url)
        browser.wait_for("window.hw.shown === 2", timeout=10)
        assert browser.evaluate("document.querySelector('th.compcol').hidden") is False
        chips = "Array.from(document.querySelectorAll('#rows tr[data-id=\"lab/rig1\"] td.compcol .comp'))"
        assert browser.evaluate(f"{chips}.map((e) => e.textContent + ' ' + e.className)") == [
            "cooler 100 comp healthy", "valve 73 comp warning"]
        assert browser.evaluate("document.querySelector('#rows tr').dataset.id") == "lab/rig1"  # warning first
        browser.navigate(server.url + "machine?id=lab/rig1")
        browser.wait_for("window.hw.updates > 0", timeout=10)
        table = "Array.from(document.querySelectorAll('#components tbody tr'))"
        assert browser.evaluate(f"{table}.map((r) => r.dataset.component + ' ' + r.className)") == [
            "cooler lvl-healthy", "valve lvl-warning"]
        assert browser.evaluate("document.getElementById('p-title').textContent") == (
            "Probability of each component's healthy state")
        assert "cycles machine" in browser.evaluate("document.getElementById('evidence').textContent")
        assert browser.exceptions() == []
