"""Degradation paths as text and as recordings: ``--degrade FAULT:FROM:TO:SECONDS[:linear|exp]`` (issue 15).

FROM and TO are **degradation-index** values (:mod:`hydrowatch.condition.degradation`): the speed drop at 2 V as a
fraction of the alert drop, 0 = new, 0.5 = warning, 1.0 = alert. They are the scale the monitor reports, so a
path written as ``load:0:1.2:3600`` is read back by ``score --json`` as an index going from 0 to 1.2 over an hour,
whatever the unit's parameters (the severity that causes a given drop is found on the simulated unit itself).
A part whose drop at 2 V starts to move only once it has worn some way (a relief spring whose pump is at its limit at
2 V) wears unseen before the path starts, without a step (:func:`hydrowatch.plant.wear.unseen_severity`).
The path starts at the recording's first sample and holds TO after SECONDS.
"""

from __future__ import annotations

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.plant.effects import Effects
from hydrowatch.plant.faults import FAULTS, LEVELS
from hydrowatch.plant.fleet import Fleet, MachineSpec
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.wear import SHAPES, DegradationPath
from hydrowatch.recording import SAMPLE_RATE_HZ, Recording

FORM = "FAULT:FROM:TO:SECONDS[:linear|exp]"
"""The text form of a path."""


def _number(text: str, field: str, spec: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not np.isfinite(value):
        raise ParameterError(f"--degrade {field} must be a number. Got {text!r} in {spec!r} ({FORM}).")
    return value


def parse_degradation(spec: str) -> DegradationPath:
    """A :class:`~hydrowatch.plant.wear.DegradationPath` from ``FAULT:FROM:TO:SECONDS[:linear|exp]``.

    FROM, TO: index values ≥ 0 (drop = index × 0.30, below 1); SECONDS > 0; shape ``linear`` (default) or ``exp``.

    Raises
    ------
    ParameterError
        Naming the field that is wrong and the text it was in.
    """
    parts = spec.strip().split(":")
    if len(parts) not in (4, 5):
        raise ParameterError(f"--degrade must have the form {FORM}. Got {spec!r} ({len(parts)} fields); "
                             "e.g. load:0:1.2:3600:linear.")
    fault, start, end, seconds = parts[:4]
    shape = parts[4] if len(parts) == 5 else "linear"
    if fault not in FAULTS:
        raise ParameterError(f"--degrade FAULT must be one of {list(FAULTS)}. Got {fault!r} in {spec!r}.")
    top = 1.0 / LEVELS["alert"]
    index = {}
    for field, text in (("FROM", start), ("TO", end)):
        value = _number(text, field, spec)
        if not 0.0 <= value < top:
            raise ParameterError(f"--degrade {field} must be an index in [0, {top:.3g}) (0 = new, 1 = alert). "
                                 f"Got {text!r} in {spec!r}.")
        index[field] = value
    duration = _number(seconds, "SECONDS", spec)
    if duration <= 0.0:
        raise ParameterError(f"--degrade SECONDS must be > 0. Got {seconds!r} in {spec!r}.")
    if shape not in SHAPES:
        raise ParameterError(f"--degrade shape must be one of {list(SHAPES)}. Got {shape!r} in {spec!r}.")
    if index["TO"] == 0.0:
        raise ParameterError(f"--degrade TO must be > 0 (a path must reach some wear). Got {end!r} in {spec!r}.")
    return DegradationPath(fault, 0.0, duration, final_drop=index["TO"] * LEVELS["alert"],
                           start_drop=index["FROM"] * LEVELS["alert"], shape=shape)


def path_index(path: DegradationPath, t: np.ndarray | float) -> np.ndarray | float:
    """True degradation index of the path's fault at times t, s: its speed drop at 2 V / 0.30."""
    return path.drop_at(t) / LEVELS["alert"]


def simulate_path(path: DegradationPath, command: np.ndarray, *, nominal: PlantParameters | None = None,
                  effects: Effects | None = None, noise: bool = True, seed: int = 0, fleet: str = "simulated",
                  update_seconds: float = 1.0) -> Recording:
    """One machine driven by ``command`` while its fault follows ``path`` (parameters move every ``update_seconds``).

    Parameters
    ----------
    command : ndarray, shape (n,)
        Valve command, V, from t = 0.
    nominal : PlantParameters, optional
        The machine as new (default nominal); the path's drops are relative to its own speed.

    Returns
    -------
    Recording
        Labelled per sample (``meta["labels"]``: the nearest named level of the current drop); ``meta`` also has
        ``degradation`` (fault, from, to, seconds, shape as given, index values) and ``machine``
        ``degrade_<fault>``.
    """
    machine = Fleet([MachineSpec(f"degrade_{path.fault}", path=path, effects=effects)], fleet=fleet, nominal=nominal,
                    noise=noise, seed=seed, update_seconds=update_seconds)
    u = np.asarray(command, dtype=np.float64)
    machine.settle(float(u[0]))
    step = max(1, int(round(update_seconds * SAMPLE_RATE_HZ)))
    parts, labels = [], []
    for start in range(0, u.size, step):
        chunk = u[start:start + step]
        parts.append(machine.step(chunk))
        labels.append(np.full(chunk.size, machine.states[0], dtype=object))
    out = {k: np.concatenate([p[k] for p in parts], axis=1) for k in parts[0]}
    rec = machine.recordings(out)[0]
    rec.meta.update(state=None, labels=np.concatenate(labels), degradation={
        "fault": path.fault, "from": path.start_drop / LEVELS["alert"], "to": path.final_drop / LEVELS["alert"],
        "seconds": path.duration_s, "shape": path.shape})
    return rec
