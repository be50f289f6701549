"""The live fleet page's library (hydrowatch.web.live) and its HTTP side (services.web.server), without a browser."""

from __future__ import annotations

import json
import threading
import urllib.error
import urllib.request
from typing import Any

import pytest

from hydrowatch.errors import ParameterError
from hydrowatch.web.live import FleetLive, PageView, counts, select

STATES = ("healthy", "load_warning", "load_alert")


def verdict(t: float, state: str, p: float = 0.9, reason: str | None = None, **extra: Any) -> dict[str, Any]:
    probabilities = {s: (p if s == state else (1 - p) / 2) for s in STATES} if state in STATES else {}
    return {"window_start": t, "window_end": t + 5.0, "state": state, "probability": p, "probabilities": probabilities,
            "reason": reason, "model_version": "parity/v3", **extra}


def kl_rows(t: float, value: float) -> list[dict[str, Any]]:
    return [{"window_start": t, "window_end": t + 5.0, "sensor": s, "state": k, "relative_entropy": value,
             "model_version": "parity/v3"} for s in ("load", "motor") for k in STATES]


@pytest.fixture
def live() -> FleetLive:
    live = FleetLive(history=4)
    live.add_verdict("f1", "m0", verdict(0.0, "healthy"), received=100.0)
    live.add_verdict("f1", "m1", verdict(0.0, "load_warning"), received=100.0)
    live.add_verdict("f2", "m2", verdict(0.0, "healthy"), received=100.0)
    live.add_verdict("f2", "m2", verdict(5.0, "load_alert"), received=105.0)
    live.add_verdict("f2", "m2", verdict(10.0, "load_alert"), received=110.0)
    live.add_verdict("f1", "m3", verdict(5.0, "unknown", 0.0, "no trained state explains the window"), received=105.0)
    return live


def test_rows_come_most_urgent_first_with_since_when(live: FleetLive) -> None:
    rows = live.rows()
    assert [r["id"] for r in rows] == ["f2/m2", "f1/m3", "f1/m1", "f1/m0"]
    alert = rows[0]
    assert (alert["state"], alert["level"], alert["rank"]) == ("load_alert", "alert", 0)
    assert (alert["since_s"], alert["since_wall"], alert["last_s"], alert["windows"]) == (5.0, 105.0, 15.0, 3)
    assert rows[1]["why"] == "no trained state explains the window" and rows[1]["level"] == "unknown"
    assert len(live) == 4 and live.row("f9/none") is None


def test_filters_by_state_level_attention_and_fleet(live: FleetLive) -> None:
    rows = live.rows()
    ids = lambda **kw: [r["id"] for r in select(rows, **kw)]  # noqa: E731
    assert ids() == ids(state="", fleet="") == [r["id"] for r in rows]
    assert ids(state="attention") == ["f2/m2", "f1/m3", "f1/m1"]
    assert ids(state="alert") == ids(state="load_alert") == ["f2/m2"]
    assert ids(state="warning") == ["f1/m1"]
    assert ids(fleet="f1") == ["f1/m3", "f1/m1", "f1/m0"]
    assert ids(state="healthy", fleet="f2") == []
    assert ids(machine="M1") == ["f1/m1"] and ids(machine="m", state="alert") == ["f2/m2"]
    assert counts(rows) == {"alert": 1, "unknown": 1, "warning": 1, "invalid": 0, "healthy": 1}


def test_a_machine_has_its_timeline_and_its_last_windows_evidence(live: FleetLive) -> None:
    for k in range(3):
        live.add_evidence("f2", "m2", kl_rows(5.0 * k, 1.0 + k))
    live.add_evidence("f2", "m2", [])
    m = live.machine("f2/m2")
    assert m is not None and m["model_version"] == "parity/v3"
    t = m["timeline"]
    assert t["start_s"] == [0.0, 5.0, 10.0] and t["end_s"] == [5.0, 10.0, 15.0]
    assert t["state"] == ["healthy", "load_alert", "load_alert"] and t["level"] == ["healthy", "alert", "alert"]
    assert t["probabilities"]["load_alert"] == pytest.approx([0.05, 0.9, 0.9])
    assert [e["window_start"] for e in m["evidence"]] == [0.0, 5.0, 10.0]
    assert m["evidence"][-1]["scores"] == {s: {k: 3.0 for k in STATES} for s in ("load", "motor")}
    for k in range(5):  # the timeline keeps the last `history` verdicts
        live.add_verdict("f2", "m2", verdict(15.0 + 5 * k, "load_alert"))
    assert len(live.machine("f2/m2")["timeline"]["state"]) == 4
    assert live.machine("f9/none") is None


def test_evidence_before_any_verdict_is_kept_but_shows_no_row() -> None:
    live = FleetLive()
    live.add_evidence("f1", "m0", kl_rows(0.0, 2.0))
    assert live.rows() == [] and live.seq == 0
    live.add_verdict("f1", "m0", verdict(0.0, "healthy"))
    assert len(live.machine("f1/m0")["evidence"]) == 1


def test_a_degradation_index_that_a_verdict_carries_is_shown() -> None:
    live = FleetLive()
    index = {"load": {"value": 0.4, "ci95": [0.3, 0.5], "rate_per_h": 0.1, "alert_in_s": 21600.0}}
    live.add_verdict("f1", "m0", verdict(0.0, "healthy", degradation=index))
    live.add_verdict("f1", "m0", verdict(5.0, "healthy"))  # a verdict without one keeps the last
    assert live.rows()[0]["degradation"] == index
    live.add_verdict("f1", "m1", verdict(0.0, "healthy"))
    assert live.row("f1/m1")["degradation"] is None


def test_history_and_evidence_must_be_positive() -> None:
    with pytest.raises(ParameterError, match="history, evidence and expected_windows must be >= 1"):
        FleetLive(history=0)
    with pytest.raises(ParameterError, match="Got 360, 12 and 0"):
        FleetLive(expected_windows=0)


def _expected_rows(start: float, level: float) -> list[dict]:
    """One ``expected_window`` message's rows (as ``to_pylist`` gives them): 50 points of 0.1 s per sensor."""
    return [{"window_start": start, "window_end": start + 5.0, "sensor": s, "unit": u, "step": 0.1,
             "measured": [level + 0.1 * i for i in range(50)], "expected": [level] * 50, "source": f"{s} source",
             "model_version": "v"} for s, u in (("flow", "L/min"), ("torque", "N·m"))]


def test_the_machine_keeps_its_last_windows_of_measured_and_expected_sensors() -> None:
    live = FleetLive(expected_windows=2)
    live.add_verdict("f1", "m0", verdict(0.0, "healthy"))
    assert live.machine("f1/m0")["expected"] is None
    seq = live.seq
    for start in (0.0, 5.0, 10.0, 20.0):  # three windows in a row, then one after a missing window
        live.add_expected("f1", "m0", _expected_rows(start, start))
    assert live.seq == seq + 4 and live.changed(seq) == {"f1/m0"}
    x = live.machine("f1/m0")["expected"]
    assert set(x) == {"flow", "torque"} and x["torque"]["unit"] == "N·m" and x["flow"]["source"] == "flow source"
    flow = x["flow"]
    assert len(flow["t"]) == len(flow["measured"]) == len(flow["expected"]) == 2 * 50 + 1  # the last 2, a break
    assert flow["t"][0] == pytest.approx(10.05) and flow["t"][-1] == pytest.approx(24.95)
    assert flow["measured"][50] is None and flow["expected"][50] is None and flow["t"][50] == pytest.approx(17.5)
    assert flow["measured"][49] == pytest.approx(14.9) and flow["expected"][51] == 20.0
    live.add_expected("f1", "m0", _expected_rows(0.0, 1.0))  # a restarted stream: its time starts again
    assert live.machine("f1/m0")["expected"]["flow"]["t"][0] == pytest.approx(0.05)
    assert len(live.machine("f1/m0")["expected"]["flow"]["t"]) == 50


def test_a_page_gets_a_snapshot_then_only_what_changed(live: FleetLive) -> None:
    view = PageView()
    first = view.update(live)
    assert first is not None and first["snapshot"] and first["order"] == [r["id"] for r in live.rows()]
    assert len(first["rows"]) == 4 and first["fleets"] == ["f1", "f2"]
    assert first["states"] == ["healthy", "load_alert", "load_warning", "unknown"]
    assert view.update(live) is None  # nothing new
    live.add_verdict("f1", "m0", verdict(5.0, "healthy"))
    second = view.update(live)
    assert second is not None and not second["snapshot"]
    assert [r["id"] for r in second["rows"]] == ["f1/m0"] and "order" not in second  # same order: not resent
    live.add_verdict("f1", "m0", verdict(10.0, "load_alert"))
    third = view.update(live)
    assert third["order"][:2] == ["f2/m2", "f1/m0"] and third["counts"]["alert"] == 2
    live.add_evidence("f1", "m1", kl_rows(0.0, 1.0))  # new evidence: the row is resent (its page may show it)
    assert [r["id"] for r in view.update(live)["rows"]] == ["f1/m1"]


def test_a_filtered_page_drops_a_machine_that_leaves_its_filter(live: FleetLive) -> None:
    view = PageView(state="attention", fleet="f1")
    first = view.update(live)
    assert first["order"] == ["f1/m3", "f1/m1"] and first["counts"]["healthy"] == 1  # counts cover the fleet
    live.add_verdict("f1", "m1", verdict(5.0, "healthy"))
    second = view.update(live)
    assert second["rows"] == [] and second["order"] == ["f1/m3"]
    live.add_verdict("f2", "m2", verdict(15.0, "healthy"))  # another fleet: nothing this page shows changed
    assert view.update(live) is None
    assert PageView(machine="3").update(live)["order"] == ["f1/m3"]


def _get(url: str) -> tuple[int, bytes, str]:
    try:
        with urllib.request.urlopen(url, timeout=10) as response:
            return response.status, response.read(), response.headers["Content-Type"]
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read(), exc.headers["Content-Type"]


def test_the_server_serves_pages_json_and_event_streams(live: FleetLive) -> None:
    from services.web.server import STATIC, WebServer

    condition = threading.Condition()
    with WebServer(live, condition) as server:
        base = server.url
        status, body, kind = _get(base)
        assert status == 200 and kind.startswith("text/html") and b"/static/fleet.js" in body
        assert b"http" not in body.replace(b"http-equiv", b"")  # nothing fetched from elsewhere
        for name in sorted(p.name for p in STATIC.iterdir()):
            status, body, _ = _get(base + "static/" + name)
            assert status == 200 and b"https://" not in body and b"//cdn" not in body, name
        assert _get(base + "static/..%2F__init__.py")[0] == 404
        assert _get(base + "static/../server.py")[0] == 404
        assert _get(base + "nothing")[0] == 404
        status, body, _ = _get(base + "api/fleet?state=attention&fleet=f1")
        assert status == 200 and [r["id"] for r in json.loads(body)["rows"]] == ["f1/m3", "f1/m1"]
        status, body, _ = _get(base + "api/machine?id=f2/m2")
        assert status == 200 and json.loads(body)["row"]["state"] == "load_alert"
        assert _get(base + "api/machine?id=f9/x")[0] == 404
        assert _get(base + "machine?id=f2/m2")[0] == 200
        with urllib.request.urlopen(base + "events?state=alert", timeout=10) as stream:
            assert stream.headers["Content-Type"] == "text/event-stream"
            first = json.loads(stream.readline().decode().removeprefix("data: "))
            assert first["snapshot"] and first["order"] == ["f2/m2"]
            assert stream.readline() == b"\n"
            with condition:
                live.add_verdict("f1", "m0", verdict(5.0, "load_alert"))
                condition.notify_all()
            update = json.loads(stream.readline().decode().removeprefix("data: "))
            # both alerts since t = 5 s: then by id
            assert [r["id"] for r in update["rows"]] == ["f1/m0"] and update["order"] == ["f1/m0", "f2/m2"]
        assert server.watched() == set()
        with urllib.request.urlopen(base + "events/machine?id=f2/m2", timeout=10) as stream:
            assert json.loads(stream.readline().decode().removeprefix("data: "))["row"]["id"] == "f2/m2"
            assert server.watched() == {"f2/m2"}  # the service follows its sensors while the page is open
            assert server.streams >= 1  # (a stream whose page closed counts until its next write fails)


def test_a_machine_keeps_its_last_seconds_of_sensor_samples_thinned_for_its_page() -> None:
    import numpy as np

    live = FleetLive(sensor_seconds=2.0, sensor_points=50)
    live.add_verdict("f1", "m0", verdict(0.0, "healthy"))
    assert live.machine("f1/m0")["sensors"] is None and live.sensor_chunks("f1/m0") == 0
    for k in range(40):  # 4 s of 0.1 s chunks at 200 Hz
        t = (np.arange(20) + 20 * k) / 200.0
        flow = np.where(t > 3.9, np.nan, t)
        live.add_sensors("f1", "m0", t, {"flow": flow, "speed": 2 * t, "state": np.array(["healthy"] * 20, object)})
    sensors = live.machine("f1/m0")["sensors"]
    assert live.sensor_chunks("f1/m0") == 40 and sensors["units"] == {"flow": "L/min", "speed": "rad/s"}
    t = np.array(sensors["t"])
    assert t[-1] == 799 / 200 and t[0] >= 4.0 - 2.1 and len(t) <= 50  # the last ~2 s, thinned, newest kept
    assert sensors["channels"]["speed"] == pytest.approx(2 * t)
    assert sensors["channels"]["flow"][-1] is None  # NaN is sent as null
    live.add_sensors("f1", "m0", np.arange(20) / 200.0, {"flow": np.zeros(20), "speed": np.zeros(20)})
    assert live.machine("f1/m0")["sensors"]["t"][0] == 0.0  # a restarted stream starts again
    with pytest.raises(ParameterError, match="sensor_seconds must be > 0"):
        FleetLive(sensor_seconds=0.0)


def test_a_port_in_use_is_one_clear_error(live: FleetLive) -> None:
    from services.web.server import WebServer

    with WebServer(live, threading.Condition()) as server:
        port = int(server.url.rsplit(":", 1)[1].strip("/"))
        with pytest.raises(ParameterError, match=f"Got 127.0.0.1:{port}: .*Pick another --port"):
            WebServer(live, threading.Condition(), port=port)


def test_a_timeline_keeps_the_last_verdicts_in_order_and_states_that_come_later() -> None:
    from hydrowatch.web.live import Timeline

    timeline = Timeline(3)
    assert timeline.to_dict()["state"] == [] and len(timeline) == 0
    timeline.append(0.0, 5.0, "healthy", 0.9, {"healthy": 0.9, "load_alert": 0.1})
    timeline.append(5.0, 10.0, "invalid", 0.0, {})
    timeline.append(10.0, 15.0, "unknown", 0.0, {"healthy": 0.5, "load_alert": 0.5})
    timeline.append(15.0, 20.0, "motor_alert", 0.8, {"healthy": 0.1, "load_alert": 0.1, "motor_alert": 0.8})
    d = timeline.to_dict()
    assert len(timeline) == 3 and timeline.count == 4
    assert d["start_s"] == [5.0, 10.0, 15.0] and d["end_s"] == [10.0, 15.0, 20.0]
    assert d["state"] == ["invalid", "unknown", "motor_alert"] and d["level"] == ["invalid", "unknown", "alert"]
    assert d["p"] == [0.0, 0.0, 0.8]
    assert d["probabilities"] == {"healthy": [None, 0.5, 0.1], "load_alert": [None, 0.5, 0.1],
                                  "motor_alert": [None, None, 0.8]}


def test_a_forecast_adds_trend_and_time_to_alert_to_each_part_most_urgent_first() -> None:
    live = FleetLive()
    index = {"load": {"value": 0.2, "ci95": [0.1, 0.3]}, "motor_leak": {"value": 0.8, "ci95": [0.7, 0.9]},
             "valve_coil": {"value": 0.6, "ci95": [0.5, 0.7]}}
    live.add_verdict("f1", "m0", verdict(0.0, "healthy", degradation=index))
    seq = live.seq
    live.add_forecast("f1", "m0", {
        "load": {"alert_in_s": 900.0, "ci95": [600.0, 1500.0], "rate_per_h": 1.1, "level": 0.21},
        "motor_leak": {"alert_in_s": None, "ci95": [None, None], "rate_per_h": 0.01, "reason": "too flat: …"},
        "valve_coil": {"alert_in_s": 7200.0, "ci95": [5000.0, None], "rate_per_h": 0.2},
        "pump_leak": {"alert_in_s": None, "ci95": [None, None], "rate_per_h": None, "level": None,
                      "reason": "too short: …"}})
    assert live.changed(seq) == {"f1/m0"}
    parts = live.row("f1/m0")["degradation"]
    # soonest alert first, then the parts without one by index, highest first
    assert list(parts) == ["load", "valve_coil", "motor_leak", "pump_leak"]
    assert parts["load"] == {"value": 0.2, "ci95": [0.1, 0.3], "rate_per_h": 1.1, "alert_in_s": 900.0,
                             "alert_ci95": [600.0, 1500.0]}
    assert parts["motor_leak"]["reason"] == "too flat: …" and "alert_in_s" not in parts["motor_leak"]
    assert parts["pump_leak"] == {"value": None, "ci95": None, "reason": "too short: …"}
    live.add_verdict("f1", "m0", verdict(5.0, "healthy", degradation={**index, "load": {"value": 0.25,
                                                                                          "ci95": [0.2, 0.3]}}))
    assert live.row("f1/m0")["degradation"]["load"]["value"] == 0.25  # the latest index, the forecast kept
    assert live.row("f1/m0")["degradation"]["load"]["alert_in_s"] == 900.0


def test_the_web_service_takes_forecast_messages_into_the_rows() -> None:
    import numpy as np

    from hydrowatch.bus import Key, Message
    from hydrowatch.condition.forecast import forecast_alert
    from hydrowatch.training.chunks import WindowVerdict
    from hydrowatch.training.forecasts import MachineForecast
    from hydrowatch.training.messages import forecast_batch, verdict_batch
    from hydrowatch.verdict import Verdict
    from services.web import _take

    t = np.arange(0.0, 1800.0, 5.0)
    parts = {"load": forecast_alert(t, 0.6 * t / t[-1] + 0.01 * np.sin(t)), "valve_coil": forecast_alert(t, 0 * t)}
    live = FleetLive()
    index = {"load": {"value": 0.6, "ci95": [0.55, 0.65]}, "valve_coil": {"value": 0.0, "ci95": [-0.05, 0.05]}}
    health = verdict_batch(WindowVerdict("f1/m0", 1795.0, 1800.0, Verdict("healthy", 0.9), None, index), "v")
    forecast = forecast_batch(MachineForecast("f1/m0", 1795.0, parts, t.size), "v")
    _take(live, [Message(Key("f1", "m0", topic), batch, b"", 0, 0)
                 for topic, batch in (("health", health), ("forecast", forecast))])
    row = live.row("f1/m0")["degradation"]
    assert list(row) == ["load", "valve_coil"] and row["valve_coil"]["reason"].startswith("too flat")
    assert row["load"]["alert_in_s"] == pytest.approx(1200.0, rel=0.05) and row["load"]["value"] == 0.6


VALVE = ("100", "90", "80", "73")


def cycle_rows_of(first: int, valve: list[str], *, healthy: str | None = "100") -> list[dict[str, Any]]:
    """``cycle_verdict`` rows (as :func:`~hydrowatch.report.cycle_table.cycle_rows` gives them) of cycles ``first``,
    ``first + 1``, … of 60 s: the cooler at 100 %, the valve in the given states (p 0.9, ``unknown`` with novelty
    1.7)."""
    rows = []
    for i, state in enumerate(valve):
        cycle = first + i
        for component, s, states in (("cooler", "100", ("3", "20", "100")), ("valve", state, VALVE)):
            p = 0.96 if component == "cooler" else 0.9
            probabilities = {k: (p if k == s else (1 - p) / (len(states) - 1)) for k in states}
            if s == "unknown":
                probabilities = {k: 0.4 if k == "90" else 0.2 for k in states}
            rows.append({"cycle": cycle, "window_start": 60.0 * cycle, "window_end": 60.0 * cycle + 60.0,
                         "component": component, "state": s, "probability": max(probabilities.values()),
                         "probabilities": probabilities, "novelty": 1.7 if s == "unknown" else 0.3,
                         "reason": "no trained state of the component explains the cycle" if s == "unknown" else None,
                         "truth": None, "healthy": healthy, "model_version": "sha256:rig"})
    return rows


def test_a_cycles_machine_is_ranked_by_its_components_and_shows_each_ones_verdict(live: FleetLive) -> None:
    live.add_cycle_verdicts("lab", "rig1", cycle_rows_of(0, ["100", "100"]), received=100.0)
    row = live.row("lab/rig1")
    assert (row["state"], row["level"], row["p"], row["windows"], row["why"]) == ("healthy", "healthy", 0.9, 2, "")
    assert [c["component"] for c in row["components"]] == ["cooler", "valve"]
    assert live.row("f1/m0")["components"] is None  # a plant machine has none

    live.add_cycle_verdicts("lab", "rig1", cycle_rows_of(2, ["73", "73", "73"]), received=130.0)
    row = live.row("lab/rig1")
    assert (row["state"], row["level"], row["since_s"], row["last_s"]) == ("valve=73", "warning", 120.0, 300.0)
    assert row["p"] == pytest.approx(0.9) and row["since_wall"] == 130.0
    assert row["why"] == "valve 73 (p = 0.90; healthy 100) since cycle 2"
    cooler, valve = row["components"]
    assert (valve["state"], valve["level"], valve["since_cycle"], valve["cycle"], valve["since_s"]) == (
        "73", "warning", 2, 4, 120.0)
    assert valve["p_healthy"] == pytest.approx(0.1 / 3) and (cooler["level"], cooler["since_cycle"]) == ("healthy", 0)
    # ranked with the plant's machines: the alert, the unknown, then the warnings by since when (f1/m1 since 0 s)
    assert [r["id"] for r in live.rows()] == ["f2/m2", "f1/m3", "f1/m1", "lab/rig1", "f1/m0"]

    live.add_cycle_verdicts("lab", "rig1", cycle_rows_of(5, ["unknown"]), received=140.0)
    row = live.row("lab/rig1")
    assert (row["state"], row["level"], row["p"]) == ("unknown", "unknown", 0.0)
    assert row["why"] == "valve unknown (novelty 1.70) since cycle 5"
    assert [r["id"] for r in select(live.rows(), state="unknown")] == ["f1/m3", "lab/rig1"]  # unknown since 5 s first
    machine = live.machine("lab/rig1")
    timeline = machine["timeline"]  # history=4: the last 4 cycles, each component's probability of its healthy state
    assert timeline["state"] == ["valve=73", "valve=73", "valve=73", "unknown"]
    assert timeline["end_s"] == [180.0, 240.0, 300.0, 360.0]
    assert timeline["probabilities"]["cooler"] == [0.96] * 4
    assert timeline["probabilities"]["valve"] == pytest.approx([0.1 / 3] * 3 + [0.2], abs=1e-6)


def test_a_v1_cycle_verdict_without_a_healthy_state_ranks_every_trained_state_as_a_warning() -> None:
    live = FleetLive()
    live.add_cycle_verdicts("lab", "rig1", cycle_rows_of(0, ["100"], healthy=None))
    row = live.row("lab/rig1")
    assert row["level"] == "warning" and row["state"] == "cooler=100 valve=100"
    assert live.machine("lab/rig1")["timeline"]["probabilities"] == {}


def test_the_web_service_and_the_page_stream_take_a_cycles_machine() -> None:
    import pyarrow as pa

    from hydrowatch.bus import Key, Message
    from hydrowatch.schemas import CYCLE_VERDICT, wire_schema
    from services.web import _take
    from services.web.server import WebServer

    rows = [{**r, "probabilities": [{"state": k, "probability": p} for k, p in r["probabilities"].items()]}
            for r in cycle_rows_of(0, ["100", "80"])]
    batch = pa.RecordBatch.from_pylist(rows, schema=wire_schema(CYCLE_VERDICT))
    live = FleetLive()
    _take(live, [Message(Key("lab", "rig1", "cycle_health"), batch, b"", 2_000_000_000, 1_500_000_000)])
    row = live.row("lab/rig1")
    assert (row["state"], row["windows"], row["since_wall"], row["published_ms"]) == ("valve=80", 2, 2.0, 1500.0)
    condition = threading.Condition()
    with WebServer(live, condition) as server:
        status, body, _ = _get(server.url + "api/fleet")
        (sent,) = json.loads(body)["rows"]
        assert status == 200 and [(c["component"], c["state"], c["level"]) for c in sent["components"]] == [
            ("cooler", "100", "healthy"), ("valve", "80", "warning")]
        with urllib.request.urlopen(server.url + "events/machine?id=lab/rig1", timeout=10) as stream:
            page = json.loads(stream.readline().decode().removeprefix("data: "))
        assert page["row"]["components"][1]["text"] == "valve 80 (p = 0.90; healthy 100) since cycle 1"
        assert page["timeline"]["probabilities"]["valve"] == pytest.approx([0.9, 0.1 / 3], abs=1e-6)
