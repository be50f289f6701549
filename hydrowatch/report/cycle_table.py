"""The operator's view of a rig's cycles machines: each component's latest verdict and since when (river style).

A cycles bundle judges whole cycles and publishes one ``cycle_verdict`` row per cycle and component on
``hydro/<fleet>/<machine>/cycle_health`` (docs/rigs.md). :class:`CycleTable` keeps each machine's components and
turns each cycle into one **machine verdict**, a ``health_verdict``-like row that
:class:`~hydrowatch.report.fleet_table.FleetTable` ranks beside the plant's machines, so that ``watch``, the web
page and the reports sort both kinds by one rule:

- state ``healthy`` when every component is in its healthy state (the rig description's, which ``cycle_verdict``
  v2 carries as ``healthy``); ``unknown`` when a component is ``unknown`` (no trained state explains the cycle);
  else the components that are not healthy as ``component=state`` joined by spaces (``valve=73 accumulator=90``),
  ranked as a warning (:func:`~hydrowatch.report.fleet_table.urgency`: the description does not say which
  degraded state is an alert);
- probability: the smallest of those components' probabilities (of every component's when healthy; 0 for
  ``unknown``, as a health verdict);
- reason: each of those components in words (:meth:`ComponentRow.text`);
- probabilities: each component's probability of its healthy state (what the machine page's timeline draws).

A ``cycle_verdict`` v1 row has no ``healthy``: its trained states cannot be told apart and all rank as a warning.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyarrow as pa

from hydrowatch.report.fleet_table import HEALTHY
from hydrowatch.verdict import UNKNOWN

WARNING = "warning"
"""Level of a trained state other than the component's healthy one."""


def component_level(state: str, healthy: str | None) -> str:
    """``healthy`` (the component's healthy state), ``unknown``, or ``warning`` (another trained state; every trained
    state when ``healthy`` is None)."""
    if state == UNKNOWN:
        return UNKNOWN
    return HEALTHY if healthy is not None and state == healthy else WARNING


def cycle_row(row: Mapping[str, Any]) -> dict[str, Any]:
    """One ``cycle_verdict`` row as Arrow's ``to_pylist`` gives it (v1 or v2), with ``probabilities`` as state → p and
    ``healthy`` None when absent."""
    found = row.get("probabilities") or []
    probabilities = dict(found) if isinstance(found, Mapping) else {p["state"]: p["probability"] for p in found}
    return {**row, "probabilities": probabilities, "healthy": row.get("healthy")}


def cycle_rows(batch: pa.RecordBatch) -> list[dict[str, Any]]:
    """A ``cycle_verdict`` message's rows (:func:`cycle_row`)."""
    return [cycle_row(row) for row in batch.to_pylist()]


@dataclass
class ComponentRow:
    """What the views show of one component of one machine.

    Attributes
    ----------
    state : str
        Latest verdict's state (a trained state, e.g. ``"73"``, or ``unknown``).
    probability : float
        Probability of the most probable trained state, 0 to 1.
    healthy : str or None
        The component's healthy state (None from a v1 message).
    level : str
        :func:`component_level`.
    cycle : int
        Latest cycle judged.
    since_cycle : int
        First cycle of the current run of this state.
    since_s : float
        Start of that cycle, s (recording time).
    novelty : float or None
        Distance to the nearest trained state over its threshold (above 1: ``unknown``).
    p_healthy : float or None
        Probability of the healthy state.
    truth : str or None
        The cycle's label, when it carried one.
    reason : str or None
        Why ``unknown``.
    cycles : int
        Verdicts received.
    """

    state: str
    probability: float
    healthy: str | None
    level: str
    cycle: int
    since_cycle: int
    since_s: float
    novelty: float | None
    p_healthy: float | None
    truth: str | None
    reason: str | None
    cycles: int

    def text(self, component: str) -> str:
        """The component in words: ``cooler 100``, ``valve 73 (p = 0.98; healthy 100) since cycle 12``, ``pump unknown
        (novelty 1.80) since cycle 40``."""
        if self.level == HEALTHY:
            return f"{component} {self.state}"
        if self.level == UNKNOWN:
            novelty = "" if self.novelty is None else f" (novelty {self.novelty:.2f})"
            return f"{component} unknown{novelty} since cycle {self.since_cycle}"
        healthy = "" if self.healthy is None else f"; healthy {self.healthy}"
        return f"{component} {self.state} (p = {self.probability:.2f}{healthy}) since cycle {self.since_cycle}"

    def to_dict(self, component: str) -> dict[str, Any]:
        """``component``, ``state``, ``level``, ``p``, ``healthy``, ``cycle``, ``since_cycle``, ``since_s``,
        ``novelty``, ``p_healthy``, ``truth``, ``text`` (what the web page is sent)."""
        return {"component": component, "state": self.state, "level": self.level, "p": self.probability,
                "healthy": self.healthy, "cycle": self.cycle, "since_cycle": self.since_cycle, "since_s": self.since_s,
                "novelty": self.novelty, "p_healthy": self.p_healthy, "truth": self.truth, "text": self.text(component)}


def machine_verdict(components: Mapping[str, ComponentRow], start_s: float, end_s: float,
                    model_version: str | None) -> dict[str, Any]:
    """The machine's verdict on one cycle from its components' (module docstring), as a ``health_verdict`` row
    (:func:`~hydrowatch.report.fleet_table.verdict_rows`' form) for :meth:`FleetTable.update
    <hydrowatch.report.fleet_table.FleetTable.update>`."""
    off = {c: r for c, r in components.items() if r.level != HEALTHY}
    if not off:
        state, reason = HEALTHY, None
        probability = min((r.probability for r in components.values()), default=0.0)
    else:
        unknown = any(r.level == UNKNOWN for r in off.values())
        state = UNKNOWN if unknown else " ".join(f"{c}={r.state}" for c, r in off.items())
        probability = 0.0 if unknown else min(r.probability for r in off.values())
        reason = "; ".join(r.text(c) for c, r in off.items())
    return {"window_start": start_s, "window_end": end_s, "state": state, "probability": probability,
            "probabilities": {c: r.p_healthy for c, r in components.items() if r.p_healthy is not None},
            "reason": reason, "model_version": model_version, "degradation": None}


class CycleTable:
    """Each cycles machine's components (:class:`ComponentRow`); :meth:`update` takes one ``cycle_verdict`` message,
    :meth:`components` and :meth:`by_machine` read."""

    def __init__(self) -> None:
        self._machines: dict[str, dict[str, ComponentRow]] = {}

    def update(self, machine: str, rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
        """Take one ``cycle_verdict`` message of ``machine`` (:func:`cycle_rows`: cycle after cycle, each component);
        returns the machine's verdict after each cycle in it (:func:`machine_verdict`), in the message's order."""
        components = self._machines.setdefault(machine, {})
        verdicts: list[dict[str, Any]] = []
        for i, row in enumerate(rows):
            name, state, healthy = str(row["component"]), str(row["state"]), row.get("healthy")
            old = components.get(name)
            same = old is not None and old.state == state
            novelty = row.get("novelty")
            components[name] = ComponentRow(
                state, float(row.get("probability") or 0.0), healthy, component_level(state, healthy),
                int(row["cycle"]), old.since_cycle if same and old else int(row["cycle"]),
                old.since_s if same and old else float(row["window_start"]),
                None if novelty is None or novelty != novelty else float(novelty),
                None if healthy is None else (row.get("probabilities") or {}).get(healthy), row.get("truth"),
                row.get("reason"), (old.cycles if old else 0) + 1)
            if i + 1 == len(rows) or rows[i + 1]["cycle"] != row["cycle"]:  # the cycle's last component
                verdicts.append(machine_verdict(components, float(row["window_start"]), float(row["window_end"]),
                                                row.get("model_version")))
        return verdicts

    def components(self, machine: str) -> dict[str, ComponentRow] | None:
        """The machine's components in the order they first came (None for a machine without cycle verdicts)."""
        return self._machines.get(machine)

    def by_machine(self) -> dict[str, dict[str, ComponentRow]]:
        """Machine → its components, machines sorted by id."""
        return dict(sorted(self._machines.items()))


def render_components(by_machine: Mapping[str, Mapping[str, ComponentRow]]) -> str:
    """Lines of each cycles machine's components (``watch``): ``""`` when there is none."""
    lines = [f"{machine:<22} {' · '.join(r.text(c) for c, r in parts.items())}"
             for machine, parts in by_machine.items()]
    return "\n".join(["components (cycles machines)", *lines]) if lines else ""


def component_cells(component: str, row: ComponentRow) -> list[Any]:
    """A component as table cells (the reports): component, state, level, probability, healthy state, since cycle,
    novelty, truth."""
    return [component, row.state, row.level, row.probability, row.healthy or "", row.since_cycle,
            "" if row.novelty is None else row.novelty, row.truth or ""]


COMPONENT_COLUMNS = ["component", "state", "level", "probability", "healthy state", "since cycle", "novelty", "truth"]
"""Headers of :func:`component_cells`."""

__all__ = ["COMPONENT_COLUMNS", "ComponentRow", "CycleTable", "component_cells", "component_level", "cycle_row",
           "cycle_rows",
           "machine_verdict", "render_components"]
