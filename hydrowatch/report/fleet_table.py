"""The operator's view of a fleet: one row per machine, fed only by ``health_verdict`` messages (river style)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import pyarrow as pa

from hydrowatch.verdict import INVALID, UNKNOWN

HEALTHY = "healthy"


@dataclass
class MachineRow:
    """What the table shows for one machine.

    Attributes
    ----------
    state : str
        Latest verdict's state.
    probability : float
        Its probability (0 for invalid and unknown).
    since_s : float
        Window start of the first verdict of the current run of this state, s (recording time).
    last_s : float
        End of the latest window, s.
    reason : str or None
    windows : int
        Verdicts received.
    since_wall : float or None
        Wall-clock receive time of that first verdict, s since the Unix epoch (None when the caller gave none).
    """

    state: str
    probability: float
    since_s: float
    last_s: float
    reason: str | None
    windows: int
    since_wall: float | None = None

    def why(self) -> str:
        """Why the machine is in its state, for people: the verdict's reason, else its probability."""
        if self.reason:
            return self.reason
        return "" if self.state == HEALTHY else f"most probable trained state (p = {self.probability:.2f})"

    def to_dict(self, machine: str) -> dict[str, Any]:
        """``machine``, ``state``, ``since_s``, ``probability``, ``why``: one entry of the demo's ``attention``."""
        return {"machine": machine, "state": self.state, "since_s": self.since_s, "probability": self.probability,
                "why": self.why()}


LEVELS = ("alert", "unknown", "warning", "invalid", "healthy")
"""Names of the :func:`urgency` ranks, most urgent first (``LEVELS[urgency(state)]``)."""


def urgency(state: str) -> int:
    """Rank of a verdict state, most urgent first: 0 ``*_alert``, 1 ``unknown`` (a fault never trained on),
    2 ``*_warning`` (and any other trained fault state), 3 ``invalid`` (no verdict possible), 4 ``healthy``;
    :data:`LEVELS` names them."""
    if state.endswith("_alert"):
        return 0
    return {UNKNOWN: 1, INVALID: 3, HEALTHY: 4}.get(state, 2)


class FleetTable:
    """Latest verdict per machine; ``update`` takes one verdict row, ``rows``/``render`` read."""

    def __init__(self) -> None:
        self._rows: dict[str, MachineRow] = {}

    def update(self, machine: str, verdict: dict[str, Any], received: float | None = None) -> MachineRow:
        """Add one verdict (a ``health_verdict`` row as a dict) of ``machine``, received at wall-clock time
        ``received`` (s since the epoch, optional); returns the machine's new row."""
        old = self._rows.get(machine)
        state = str(verdict["state"])
        if old is not None and old.state == state:
            since, since_wall = old.since_s, old.since_wall
        else:
            since, since_wall = float(verdict["window_start"]), received
        row = self._rows[machine] = MachineRow(state, float(verdict.get("probability") or 0.0), since,
                                               float(verdict["window_end"]), verdict.get("reason"),
                                               (old.windows if old else 0) + 1, since_wall)
        return row

    def latest(self) -> Mapping[str, MachineRow]:
        """Machine → row, unsorted and read-only (a live view: no copy, no sort)."""
        return MappingProxyType(self._rows)

    def rows(self) -> dict[str, MachineRow]:
        """Machine → row, sorted by machine."""
        return dict(sorted(self._rows.items()))

    def by_urgency(self) -> dict[str, MachineRow]:
        """Machine → row, most urgent first (:func:`urgency`), then longest in that state, then by machine."""
        return dict(sorted(self._rows.items(), key=lambda kv: (urgency(kv[1].state), kv[1].since_s, kv[0])))

    def attention(self) -> list[dict[str, Any]]:
        """The machines that are not healthy, most urgent first, as :meth:`MachineRow.to_dict`."""
        return [row.to_dict(m) for m, row in self.by_urgency().items() if row.state != HEALTHY]

    def render(self) -> str:
        """The table as text, one line per machine."""
        lines = [f"{'machine':<22} {'state':<20} {'p':>6} {'since [s]':>10} {'last [s]':>10} {'windows':>8}  reason"]
        for machine, r in self.rows().items():
            lines.append(f"{machine:<22} {r.state:<20} {r.probability:>6.3f} {r.since_s:>10.1f} {r.last_s:>10.1f} "
                         f"{r.windows:>8}  {r.reason or ''}")
        return "\n".join(lines)


def verdict_rows(batch: pa.RecordBatch) -> list[dict[str, Any]]:
    """``health_verdict`` rows (v1 or v2) as dicts: ``probabilities`` as state → p, ``degradation`` (None when absent)
    as fault → ``{"value", "ci95": [lo, hi]}`` as ``score --json`` writes it."""
    rows = batch.to_pylist()
    for row in rows:
        row["probabilities"] = {p["state"]: p["probability"] for p in row.get("probabilities") or []}
        parts = row.get("degradation")
        row["degradation"] = None if parts is None else {
            d["fault"]: {"value": d["index"], "ci95": [d["low"], d["high"]]} for d in parts}
    return rows


def forecast_parts(batch: pa.RecordBatch) -> tuple[float | None, dict[str, dict[str, Any]]]:
    """A ``forecast`` message as ``score --json``'s summary ``forecast`` writes it: the start of the window it counts
    from, s (None for an empty message), and fault → ``{"alert_in_s", "ci95": [lo, hi], "rate_per_h", "level",
    "model", "points", "reset_at_s"}`` (+ ``reason`` when there is no forecast, ``untold_from`` when the part shares
    its index with a look-alike)."""
    rows = batch.to_pylist()
    parts = {}
    for r in rows:
        part = {"alert_in_s": r["alert_in_s"], "ci95": [r.get("low_s"), r.get("high_s")],
                "rate_per_h": r.get("rate_per_h"), "level": r.get("level"), "model": r["model"], "points": r["points"],
                "reset_at_s": r.get("reset_at")}
        for key in ("reason", "untold_from"):  # untold_from: forecast v2
            if r.get(key) is not None:
                part[key] = r[key]
        parts[r["fault"]] = part
    return (float(rows[0]["window_start"]) if rows else None), parts


FORECAST_KEYS = ("rate_per_h", "alert_in_s", "reason", "untold_from")
"""What a part's entry in :func:`wear_parts` takes from its forecast (its ``ci95`` becomes ``alert_ci95``)."""


def wear_parts(degradation: Mapping[str, Mapping[str, Any]] | None,
               forecast: Mapping[str, Mapping[str, Any]] | None) -> dict[str, dict[str, Any]] | None:
    """Each part's wear as an operator reads it, most urgent first: the latest window's index (``value``, ``ci95``,
    from ``health_verdict`` v2) with the machine's forecast (``rate_per_h`` [index/h], ``alert_in_s`` [s],
    ``alert_ci95``, ``reason`` when there is no forecast, from ``…/forecast``); None when there is neither.

    Order: parts with a forecast of the alert, soonest first (0: already beyond it); then the others by index,
    highest first (a part at 0.9 that is too flat to forecast needs a look before one at 0.1).
    """
    if not degradation and not forecast:
        return None
    parts: dict[str, dict[str, Any]] = {}
    for fault, d in (degradation or {}).items():
        parts[fault] = dict(d)
    for fault, f in (forecast or {}).items():
        part = parts.setdefault(fault, {"value": f.get("level"), "ci95": None})
        part.update({k: f.get(k) for k in FORECAST_KEYS if f.get(k) is not None})
        if f.get("alert_in_s") is not None:
            part["alert_ci95"] = f.get("ci95")

    def order(item: tuple[str, dict[str, Any]]) -> tuple[float, float, str]:
        fault, p = item
        alert = p.get("alert_in_s")
        value = p.get("value")
        return (float(alert) if alert is not None else float("inf"),
                -float(value) if value is not None else 0.0, fault)

    return dict(sorted(parts.items(), key=order))


class FleetWear:
    """Each machine's wear from the bus, for a table or a report (river style): the latest verdict's ``degradation``
    (:meth:`add_verdict`) and the latest ``forecast`` message (:meth:`add_forecast`), read together by
    :meth:`by_machine` (:func:`wear_parts`: most urgent part first)."""

    def __init__(self) -> None:
        self._index: dict[str, dict[str, Any]] = {}
        self._forecast: dict[str, dict[str, Any]] = {}

    def add_verdict(self, machine: str, verdict: Mapping[str, Any]) -> None:
        """Take a ``health_verdict`` row (:func:`verdict_rows`); one without a ``degradation`` changes nothing."""
        if verdict.get("degradation") is not None:
            self._index[machine] = dict(verdict["degradation"])

    def add_forecast(self, machine: str, parts: Mapping[str, Mapping[str, Any]]) -> None:
        """Take a ``forecast`` message's parts (:func:`forecast_parts`)."""
        self._forecast[machine] = {f: dict(p) for f, p in parts.items()}

    def by_machine(self) -> dict[str, dict[str, dict[str, Any]]]:
        """Machine → its parts (:func:`wear_parts`), machines sorted by their soonest alert, then by id."""
        found = {m: wear_parts(self._index.get(m), self._forecast.get(m)) for m in {*self._index, *self._forecast}}
        parts = {m: p for m, p in found.items() if p}

        def soonest(item: tuple[str, dict[str, dict[str, Any]]]) -> tuple[float, str]:
            alerts = [p["alert_in_s"] for p in item[1].values() if p.get("alert_in_s") is not None]
            return (min(alerts) if alerts else float("inf"), item[0])

        return dict(sorted(parts.items(), key=soonest))


def duration_text(seconds: float) -> str:
    """Operating time for people: ``now``, seconds, minutes below two hours, else hours (as the web page writes
    it)."""
    if seconds <= 0:
        return "now"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def wear_text(fault: str, part: Mapping[str, Any]) -> str:
    """One part's wear in a line: ``motor_leak 0.48 [0.41–0.55] ↑1.62/h alert in 6 min (95 %: 4–9 min)``, or the
    reason there is no forecast (an entry of :func:`wear_parts`)."""
    value, ci = part.get("value"), part.get("ci95")
    text = f"{fault} {'–' if value is None else f'{value:.2f}'}"
    if ci and None not in ci:
        text += f" [{ci[0]:.2f}–{ci[1]:.2f}]"
    if part.get("rate_per_h") is not None:
        rate = part["rate_per_h"]
        text += f" {'↑' if rate >= 0 else '↓'}{abs(rate):.2f}/h"
    alert = part.get("alert_in_s")
    if alert is not None and alert <= 0:
        text += " at alert"
    elif alert is not None:
        lo, hi = part.get("alert_ci95") or (None, None)
        text += (f" alert in {duration_text(alert)} (95 %: {'0' if lo is None else duration_text(lo)}–"
                 f"{'open' if hi is None else duration_text(hi)})")
        if part.get("untold_from"):
            text += f" (or {part['untold_from']}: not yet told apart)"
    elif part.get("reason"):
        text += f" (no forecast: {str(part['reason']).split(':')[0]})"
    return text


def wear_cells(fault: str, part: Mapping[str, Any]) -> list[str]:
    """A part's wear as table cells: part, index with its interval, trend per hour, time to alert with its interval
    (or why there is none); the words of :func:`wear_text`."""
    whole = wear_text(fault, {k: part.get(k) for k in ("value", "ci95")})
    rate = part.get("rate_per_h")
    alert = wear_text("", {k: part.get(k) for k in ("alert_in_s", "alert_ci95", "reason", "untold_from")}).strip(" –")
    return [fault, whole[len(fault) + 1:], "" if rate is None else f"{rate:+.2f}", alert]


WORN = 0.15
"""Index from which a part without a forecast is listed among a machine's wear (a look-alike's noise stays below,
docs/degradation.md); parts with a forecast of the alert always are."""


def render_wear(by_machine: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> str:
    """Lines of each machine's worn parts (:meth:`FleetWear.by_machine`'s order, parts most urgent first): parts with
    a forecast of the alert or an index ≥ :data:`WORN`; ``""`` when no machine has any."""
    lines = []
    for machine, parts in by_machine.items():
        shown = [wear_text(f, p) for f, p in parts.items()
                 if p.get("alert_in_s") is not None or (p.get("value") or 0.0) >= WORN]
        if shown:
            lines.append(f"{machine:<22} {'; '.join(shown)}")
    return "\n".join(["wear (most urgent first)", *lines]) if lines else ""
