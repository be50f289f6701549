"""The fleet as the live page shows it: latest verdict, recent history and evidence of every machine.

:class:`FleetLive` is fed one bus message at a time (river style: ``add_verdict`` / ``add_evidence``
return nothing; reading changes nothing). The verdict rows themselves, the "since when" rule and the
urgency order are :class:`hydrowatch.report.fleet_table.FleetTable`'s (the terminal ``watch`` and the
demo report use the same); this module adds what a page needs on top: a change counter so that a page
gets only what changed since its last update, each machine's timeline of verdicts and probabilities,
and the evidence (relative entropies or parity relation scores) of its last windows.

A machine's id on the page is ``<fleet>/<machine>``.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hydrowatch.errors import ParameterError
from hydrowatch.report.fleet_table import HEALTHY, LEVELS, FleetTable, MachineRow, urgency

ATTENTION = "attention"
"""The state filter that keeps every machine that is not healthy."""


@dataclass
class _Machine:
    fleet: str
    machine: str
    timeline: deque[tuple[float, float, str, float, dict[str, float]]]
    evidence: deque[dict[str, Any]]
    published_ms: float | None = None
    model_version: str | None = None
    degradation: dict[str, Any] | None = None


class FleetLive:
    """Every machine's latest verdict, its recent timeline and its last windows' evidence, with change tracking.

    Parameters
    ----------
    history : int
        Verdicts kept per machine for its timeline (default 360: 30 min of 5 s windows).
    evidence : int
        Windows of evidence (``kl_window`` messages) kept per machine (default 12: the scorer's pool).

    Attributes
    ----------
    seq : int
        Counts the messages taken in; :meth:`changes` answers "what changed after ``seq``".
    """

    def __init__(self, *, history: int = 360, evidence: int = 12) -> None:
        if history < 1 or evidence < 1:
            raise ParameterError(f"history and evidence must be >= 1. Got {history} and {evidence}.")
        self.history = history
        self.evidence = evidence
        self.seq = 0
        self._table = FleetTable()
        self._machines: dict[str, _Machine] = {}
        self._changed: dict[str, int] = {}

    def _machine(self, fleet: str, machine: str) -> tuple[str, _Machine]:
        ident = f"{fleet}/{machine}"
        found = self._machines.get(ident)
        if found is None:
            found = self._machines[ident] = _Machine(fleet, machine, deque(maxlen=self.history),
                                                     deque(maxlen=self.evidence))
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
        m.timeline.append((float(verdict["window_start"]), row.last_s, row.state, row.probability,
                           dict(verdict.get("probabilities") or {})))
        m.published_ms = published_ms
        m.model_version = verdict.get("model_version")
        if verdict.get("degradation") is not None:
            m.degradation = dict(verdict["degradation"])
        self.seq += 1
        self._changed[ident] = self.seq

    def add_evidence(self, fleet: str, machine: str, rows: Sequence[Mapping[str, Any]]) -> None:
        """Take one ``kl_window`` message (its rows, one per sensor or relation × state, as dicts)."""
        if not rows:
            return
        ident, m = self._machine(fleet, machine)
        scores: dict[str, dict[str, float]] = {}
        for r in rows:
            scores.setdefault(str(r["sensor"]), {})[str(r["state"])] = float(r["relative_entropy"])
        first = rows[0]
        m.evidence.append({"window_start": float(first["window_start"]), "window_end": float(first["window_end"]),
                           "model_version": first.get("model_version"), "scores": scores})
        if ident in self._table.latest():
            self.seq += 1
            self._changed[ident] = self.seq

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
        return {"id": ident, "fleet": m.fleet, "machine": m.machine, "state": r.state, "level": LEVELS[rank],
                "rank": rank, "p": r.probability, "since_s": r.since_s, "since_wall": r.since_wall,
                "last_s": r.last_s, "windows": r.windows, "why": r.why(), "published_ms": m.published_ms,
                "degradation": m.degradation}

    def rows(self) -> list[dict[str, Any]]:
        """Every machine's row, most urgent first (:meth:`FleetTable.by_urgency`)."""
        return [self._row(ident, r) for ident, r in self._table.by_urgency().items()]

    def changed(self, since: int) -> set[str]:
        """Ids of the machines whose verdict or evidence came after ``seq`` was ``since``."""
        return {ident for ident, seq in self._changed.items() if seq > since}

    def machine(self, ident: str) -> dict[str, Any] | None:
        """What the machine page shows: its row, its timeline (window bounds s, state, probability, every
        state's probability per window) and the evidence of its last windows; None for an unknown machine."""
        row = self.row(ident)
        if row is None:
            return None
        m = self._machines[ident]
        states = sorted({s for *_, probabilities in m.timeline for s in probabilities})
        timeline = {
            "start_s": [w[0] for w in m.timeline], "end_s": [w[1] for w in m.timeline],
            "state": [w[2] for w in m.timeline], "p": [w[3] for w in m.timeline],
            "level": [LEVELS[urgency(w[2])] for w in m.timeline],
            "probabilities": {s: [w[4].get(s) for w in m.timeline] for s in states},
        }
        return {"row": row, "model_version": m.model_version, "timeline": timeline, "evidence": list(m.evidence)}


def select(rows: Iterable[dict[str, Any]], state: str | None = None, fleet: str | None = None) -> list[dict[str, Any]]:
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
    """
    out = []
    for row in rows:
        if fleet and row["fleet"] != fleet:
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
    state, fleet : str or None
        The page's filters, as :func:`select` takes them.

    Each :meth:`update` returns one message for the page (None when nothing it shows changed):
    ``{"seq", "snapshot": bool, "rows": [row, …], "order": [id, …] (only when the order or the set of
    rows shown changed, and always in a snapshot), "counts": {level: n}, "states": [...], "fleets": [...]}``.
    ``rows`` are, in a snapshot, every row shown and otherwise the rows shown that changed; ``order``
    lists the ids shown, most urgent first; ``counts``, ``states`` and ``fleets`` cover the page's fleet
    filter (every state), so that the state filter can offer every state there is.
    """

    def __init__(self, state: str | None = None, fleet: str | None = None) -> None:
        self.state = state or None
        self.fleet = fleet or None
        self.seq = -1
        self._order: list[str] | None = None

    def update(self, live: FleetLive) -> dict[str, Any] | None:
        """The next message for the page, from ``live`` as it is now; None when nothing shown changed."""
        if live.seq == self.seq and self._order is not None:
            return None
        every = live.rows()
        in_fleet = select(every, fleet=self.fleet)
        shown = select(in_fleet, state=self.state)
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
