"""The fleet as the live page shows it: latest verdict, recent history and evidence of every machine.

:class:`FleetLive` is fed one bus message at a time (river style: ``add_verdict`` / ``add_evidence``
return nothing; reading changes nothing). The verdict rows themselves, the "since when" rule and the
urgency order are :class:`hydrowatch.report.fleet_table.FleetTable`'s (the terminal ``watch`` and the
demo report use the same); this module adds what a page needs on top: a change counter so that a page
gets only what changed since its last update, each machine's timeline of verdicts and probabilities,
the evidence (relative entropies or parity relation scores) of its last windows, and each part's wear: its
index from the latest verdict with the trend and time to alert of the machine's latest forecast, most urgent
first (:func:`~hydrowatch.report.fleet_table.wear_parts`), and a rig's cycles machine's components (its latest verdict
per component; :mod:`hydrowatch.report.cycle_table`: the machine's verdict is its verdict on its latest cycle).

A machine's id on the page is ``<fleet>/<machine>``.
"""

from __future__ import annotations

import sys
from collections import Counter, deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrowatch.channels import PLANT
from hydrowatch.errors import ParameterError
from hydrowatch.report.cycle_table import CycleTable
from hydrowatch.report.fleet_table import HEALTHY, LEVELS, FleetTable, MachineRow, urgency, wear_parts
from hydrowatch.web.traces import ExpectedTrace

UNITS = PLANT.units
"""Unit of each channel the plant (and the study's rig) publishes."""
ATTENTION = "attention"
"""The state filter that keeps every machine that is not healthy."""


class Timeline:
    """The last ``size`` verdicts of one machine, in arrays (river style: :meth:`append` one, :meth:`to_dict` reads).

    A deque of verdict dicts took ~1.2 kB per verdict (430 MB for 1000 machines × 360 verdicts of 7
    states); here a verdict is 3 float64, one int32 and one float32 per trained state (~80 bytes).

    Parameters
    ----------
    size : int
        Verdicts kept (the oldest goes when one more comes).
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self.count = 0
        self._bounds = np.zeros((size, 3))  # window start s, window end s, probability of the state
        self._state = np.zeros(size, dtype=np.int32)
        self._p = np.full((size, 0), np.nan, dtype=np.float32)
        self._names: list[str] = []  # verdict states, indexed by _state
        self._columns: dict[str, int] = {}  # trained state -> column of _p

    def append(self, start_s: float, end_s: float, state: str, probability: float,
               probabilities: Mapping[str, float]) -> None:
        """Add one verdict (window bounds s, state, its probability, every trained state's probability)."""
        for name in probabilities:
            if name not in self._columns:
                self._columns[name] = self._p.shape[1]
                self._p = np.hstack([self._p, np.full((self.size, 1), np.nan, dtype=np.float32)])
        if state not in self._names:
            self._names.append(state)
        i = self.count % self.size
        self._bounds[i] = (start_s, end_s, probability)
        self._state[i] = self._names.index(state)
        self._p[i] = np.nan
        for name, value in probabilities.items():
            self._p[i, self._columns[name]] = value
        self.count += 1

    def __len__(self) -> int:
        return min(self.count, self.size)

    def to_dict(self) -> dict[str, Any]:
        """Oldest first: ``start_s``, ``end_s``, ``state``, ``p``, ``level`` (lists) and ``probabilities``
        (trained state → list, None where a verdict had none)."""
        order = np.arange(self.count - len(self), self.count) % self.size
        states = [self._names[k] for k in self._state[order].tolist()]
        p = self._p[order]
        return {"start_s": self._bounds[order, 0].tolist(), "end_s": self._bounds[order, 1].tolist(),
                "state": states, "p": self._bounds[order, 2].tolist(),
                "level": [LEVELS[urgency(s)] for s in states],
                "probabilities": {name: [None if np.isnan(v) else round(v, 6) for v in p[:, j].tolist()]
                                  for name, j in sorted(self._columns.items())}}


@dataclass
class _Machine:
    fleet: str
    machine: str
    timeline: Timeline
    evidence: deque[dict[str, Any]]
    sensors: deque[tuple[np.ndarray, dict[str, np.ndarray]]]
    expected: ExpectedTrace
    published_ms: float | None = None
    model_version: str | None = None
    degradation: dict[str, Any] | None = None
    forecast: dict[str, Any] | None = None
    sensor_chunks: int = 0


class FleetLive:
    """Every machine's latest verdict, its recent timeline and its last windows' evidence, with change tracking.

    Parameters
    ----------
    history : int
        Verdicts kept per machine for its timeline (default 360: 30 min of 5 s windows).
    evidence : int
        Windows of evidence (``kl_window`` messages) kept per machine (default 12: the scorer's pool).
    sensor_seconds : float
        Seconds of sensor samples kept per machine that :meth:`add_sensors` is given (default 10 s: two
        of the scorer's 5 s windows).
    sensor_points : int
        Most samples per channel a machine page is sent (evenly thinned; default 500).
    expected_windows : int
        Windows of measured and expected sensors (``expected_window`` messages) kept per machine that
        :meth:`add_expected` is given (default 6: 30 s).

    Attributes
    ----------
    seq : int
        Counts the messages taken in; :meth:`changed` answers "what changed after ``seq``".
    """

    def __init__(self, *, history: int = 360, evidence: int = 12, sensor_seconds: float = 10.0,
                 sensor_points: int = 500, expected_windows: int = 6) -> None:
        if history < 1 or evidence < 1 or expected_windows < 1:
            raise ParameterError(f"history, evidence and expected_windows must be >= 1. Got {history}, {evidence} and "
                                 f"{expected_windows}.")
        if not sensor_seconds > 0 or sensor_points < 2:
            raise ParameterError(f"sensor_seconds must be > 0 and sensor_points >= 2. Got {sensor_seconds} and "
                                 f"{sensor_points}.")
        self.history = history
        self.evidence = evidence
        self.sensor_seconds = sensor_seconds
        self.sensor_points = sensor_points
        self.expected_windows = expected_windows
        self.seq = 0
        self._table = FleetTable()
        self._cycles = CycleTable()
        self._machines: dict[str, _Machine] = {}
        self._changed: dict[str, int] = {}
        self._rows: tuple[int, list[dict[str, Any]]] | None = None  # (seq, rows) of the last :meth:`rows`

    def _machine(self, fleet: str, machine: str) -> tuple[str, _Machine]:
        ident = f"{fleet}/{machine}"
        found = self._machines.get(ident)
        if found is None:
            found = self._machines[ident] = _Machine(fleet, machine, Timeline(self.history),
                                                     deque(maxlen=self.evidence), deque(),
                                                     ExpectedTrace(self.expected_windows))
        return ident, found

    def add_verdict(self, fleet: str, machine: str, verdict: Mapping[str, Any], *, received: float | None = None,
                    published_ms: float | None = None) -> None:
        """Take one ``health_verdict`` row (as :func:`~hydrowatch.report.fleet_table.verdict_rows` gives it).

        ``received`` is the wall-clock receive time (s since the epoch; "since when" on the page),
        ``published_ms`` the publish time the bus message carried (ms since the epoch; lets a page measure
        how late it shows the verdict). A ``degradation`` entry (fault → ``{"value", "ci95", …}``), should a
        verdict carry one, is kept as it is.
        """
        ident, m = self._machine(fleet, machine)
        row = self._table.update(ident, dict(verdict), received)
        m.timeline.append(float(verdict["window_start"]), row.last_s, row.state, row.probability,
                          verdict.get("probabilities") or {})
        m.published_ms = published_ms
        m.model_version = verdict.get("model_version")
        if verdict.get("degradation") is not None:
            m.degradation = dict(verdict["degradation"])
        self.seq += 1
        self._changed[ident] = self.seq

    def add_cycle_verdicts(self, fleet: str, machine: str, rows: Sequence[Mapping[str, Any]], *,
                           received: float | None = None, published_ms: float | None = None) -> None:
        """Take one ``cycle_verdict`` message of a rig's cycles machine (its rows as
        :func:`~hydrowatch.report.cycle_table.cycle_rows` gives them): its components are updated and the machine's
        verdict on each cycle (:func:`~hydrowatch.report.cycle_table.machine_verdict`) is taken as
        :meth:`add_verdict` takes a health verdict."""
        for verdict in self._cycles.update(f"{fleet}/{machine}", rows):
            self.add_verdict(fleet, machine, verdict, received=received, published_ms=published_ms)

    def add_evidence(self, fleet: str, machine: str, rows: Sequence[Mapping[str, Any]]) -> None:
        """Take one ``kl_window`` message (its rows, one per sensor or relation × state, as dicts)."""
        if not rows:
            return
        ident, m = self._machine(fleet, machine)
        scores: dict[str, dict[str, float]] = {}
        for r in rows:
            # (names interned: a fleet's evidence repeats the same few names millions of times)
            scores.setdefault(sys.intern(str(r["sensor"])), {})[sys.intern(str(r["state"]))] = float(
                r["relative_entropy"])
        first = rows[0]
        m.evidence.append({"window_start": float(first["window_start"]), "window_end": float(first["window_end"]),
                           "model_version": first.get("model_version"), "scores": scores})
        if ident in self._table.latest():
            self.seq += 1
            self._changed[ident] = self.seq

    def add_expected(self, fleet: str, machine: str, rows: Sequence[Mapping[str, Any]]) -> None:
        """Take one ``expected_window`` message (its rows, one per sensor the model predicts, as dicts): the machine
        page charts its sensors against what the model expected (:class:`~hydrowatch.web.traces.ExpectedTrace`)."""
        if not rows:
            return
        ident, m = self._machine(fleet, machine)
        m.expected.add(rows)
        if ident in self._table.latest():
            self.seq += 1
            self._changed[ident] = self.seq

    def add_forecast(self, fleet: str, machine: str, parts: Mapping[str, Mapping[str, Any]]) -> None:
        """Take one ``forecast`` message, as :func:`~hydrowatch.report.fleet_table.forecast_parts` reads it (fault →
        ``{"alert_in_s", "ci95", "rate_per_h", …}``): the machine's parts then show their trend and time to alert
        (:func:`~hydrowatch.report.fleet_table.wear_parts`)."""
        ident, m = self._machine(fleet, machine)
        m.forecast = {f: dict(p) for f, p in parts.items()}
        if ident in self._table.latest():
            self.seq += 1
            self._changed[ident] = self.seq

    def add_sensors(self, fleet: str, machine: str, t: np.ndarray, channels: Mapping[str, np.ndarray]) -> None:
        """Take one ``sensor_chunk`` (sample times ``t`` s, shape (n,), and channel arrays of the same shape; a
        non-numeric column such as ``state`` is left out). Keeps the machine's last ``sensor_seconds``; a chunk
        earlier than the last one kept (a restarted stream) starts them again."""
        if len(t) == 0:
            return
        _, m = self._machine(fleet, machine)
        if m.sensors and t[0] <= m.sensors[-1][0][-1]:
            m.sensors.clear()
        m.sensors.append((np.asarray(t, dtype=np.float64),
                          {k: np.asarray(v) for k, v in channels.items() if np.asarray(v).dtype.kind == "f"}))
        while m.sensors and m.sensors[0][0][-1] < t[-1] - self.sensor_seconds:
            m.sensors.popleft()
        m.sensor_chunks += 1

    def sensor_chunks(self, ident: str) -> int:
        """Sensor chunks taken for machine ``ident`` so far (a page compares it to know whether they changed)."""
        found = self._machines.get(ident)
        return 0 if found is None else found.sensor_chunks

    def _sensors(self, m: _Machine) -> dict[str, Any] | None:
        if not m.sensors:
            return None
        t = np.concatenate([c[0] for c in m.sensors])
        names = sorted(set.intersection(*(set(c[1]) for c in m.sensors)))
        step = max(1, -(-t.size // self.sensor_points))
        start = t.size - 1 - ((t.size - 1) // step) * step  # keep the newest sample
        columns = {k: np.concatenate([c[1][k] for c in m.sensors])[start::step] for k in names}
        return {"t": t[start::step].tolist(), "units": {k: UNITS.get(k, "") for k in names},
                "channels": {k: [None if not np.isfinite(v) else v for v in c.tolist()] for k, c in columns.items()}}

    def __len__(self) -> int:
        """Machines with at least one verdict."""
        return len(self._table.latest())

    def row(self, ident: str) -> dict[str, Any] | None:
        """What the fleet page shows of one machine (None before its first verdict)."""
        found = self._table.latest().get(ident)
        return None if found is None else self._row(ident, found)

    def _row(self, ident: str, r: MachineRow) -> dict[str, Any]:
        m = self._machines[ident]
        rank = urgency(r.state)
        components = self._cycles.components(ident)
        return {"id": ident, "fleet": m.fleet, "machine": m.machine, "state": r.state, "level": LEVELS[rank],
                "rank": rank, "p": r.probability, "since_s": r.since_s, "since_wall": r.since_wall,
                "last_s": r.last_s, "windows": r.windows, "why": r.why(), "published_ms": m.published_ms,
                "degradation": wear_parts(m.degradation, m.forecast),
                "components": None if components is None else [c.to_dict(name) for name, c in components.items()]}

    def rows(self) -> list[dict[str, Any]]:
        """Every machine's row, most urgent first (:meth:`FleetTable.by_urgency`); the same list until the next
        message (every open page asks for it after each burst: made once per burst)."""
        if self._rows is None or self._rows[0] != self.seq:
            self._rows = (self.seq, [self._row(ident, r) for ident, r in self._table.by_urgency().items()])
        return self._rows[1]

    def changed(self, since: int) -> set[str]:
        """Ids of the machines whose verdict or evidence came after ``seq`` was ``since``."""
        return {ident for ident, seq in self._changed.items() if seq > since}

    def machine(self, ident: str) -> dict[str, Any] | None:
        """What the machine page shows: its row, its timeline (window bounds s, state, probability, every
        state's probability per window), the evidence of its last windows and, when :meth:`add_sensors` was given
        any, its last ``sensor_seconds`` of samples (``{"t": [...], "units": {name: unit}, "channels": {name:
        [...]}}``, at most ``sensor_points`` per channel, NaN as None; else None), and when :meth:`add_expected` was
        given any, its last windows' measured and expected sensors (:meth:`ExpectedTrace.to_dict
        <hydrowatch.web.traces.ExpectedTrace.to_dict>`; else None); None for an unknown machine."""
        row = self.row(ident)
        if row is None:
            return None
        m = self._machines[ident]
        return {"row": row, "model_version": m.model_version, "timeline": m.timeline.to_dict(),
                "evidence": list(m.evidence), "sensors": self._sensors(m), "expected": m.expected.to_dict()}


def select(rows: Iterable[dict[str, Any]], state: str | None = None, fleet: str | None = None,
           machine: str | None = None) -> list[dict[str, Any]]:
    """The rows a page's filters keep, in their order.

    Parameters
    ----------
    rows : iterable of dict
        Rows as :meth:`FleetLive.rows` gives them.
    state : str or None
        None or ``""``: every state; ``"attention"``: every machine that is not healthy; a level name
        (``alert``, ``unknown``, ``warning``, ``invalid``, ``healthy``); or one state (``load_alert``).
    fleet : str or None
        None or ``""``: every fleet; else that fleet only.
    machine : str or None
        None or ``""``: every machine; else the machines whose id contains it (case-insensitive).
    """
    out = []
    needle = (machine or "").lower()
    for row in rows:
        if fleet and row["fleet"] != fleet:
            continue
        if needle and needle not in row["machine"].lower():
            continue
        if state and not (row["state"] == state or row["level"] == state or (state == ATTENTION and
                                                                               row["state"] != HEALTHY)):
            continue
        out.append(row)
    return out


def counts(rows: Iterable[dict[str, Any]]) -> dict[str, int]:
    """Machines per urgency level (every level present, most urgent first)."""
    found = Counter(row["level"] for row in rows)
    return {level: found.get(level, 0) for level in LEVELS}


class PageView:
    """What one open fleet page is sent: a snapshot first, then only what changed (river style).

    Parameters
    ----------
    state, fleet, machine : str or None
        The page's filters, as :func:`select` takes them.

    Each :meth:`update` returns one message for the page (None when nothing it shows changed):
    ``{"seq", "snapshot": bool, "rows": [row, …], "order": [id, …] (only when the order or the set of
    rows shown changed, and always in a snapshot), "counts": {level: n}, "states": [...], "fleets": [...]}``.
    ``rows`` are, in a snapshot, every row shown and otherwise the rows shown that changed; ``order``
    lists the ids shown, most urgent first; ``counts``, ``states`` and ``fleets`` cover the page's fleet
    filter (every state), so that the state filter can offer every state there is.
    """

    def __init__(self, state: str | None = None, fleet: str | None = None, machine: str | None = None) -> None:
        self.state = state or None
        self.fleet = fleet or None
        self.machine = machine or None
        self.seq = -1
        self._order: list[str] | None = None

    def update(self, live: FleetLive) -> dict[str, Any] | None:
        """The next message for the page, from ``live`` as it is now; None when nothing shown changed."""
        if live.seq == self.seq and self._order is not None:
            return None
        every = live.rows()
        in_fleet = select(every, fleet=self.fleet)
        shown = select(in_fleet, state=self.state, machine=self.machine)
        order = [r["id"] for r in shown]
        snapshot = self._order is None
        if snapshot:
            rows = shown
        else:
            changed = live.changed(self.seq)
            rows = [r for r in shown if r["id"] in changed]
        self.seq = live.seq
        if not snapshot and not rows and order == self._order:
            return None
        message: dict[str, Any] = {"seq": self.seq, "snapshot": snapshot, "rows": rows, "counts": counts(in_fleet),
                                   "states": sorted({r["state"] for r in in_fleet}),
                                   "fleets": sorted({r["fleet"] for r in every})}
        if snapshot or order != self._order:
            message["order"] = order
        self._order = order
        return message
