"""bench_degradation's units and their window fits, stored so that the index and forecast can be re-measured in minutes.

Simulating one unit (seven machines over 2 h) and fitting its windows takes ~110 s on one core; turning the fits into
indices and forecasts (``window_degradation``, ``forecast_alert``) takes a few seconds. ``bench_degradation.py --fits
DIR`` keeps each unit's fits in ``DIR/seed{S}_unit{K}_{H}h_{COMMISSION}.npz`` and reads them back on the next run, so
a change to the rules after the fits (the modules in :data:`REPLAYED`) is measured on the same windows in minutes.

A stored file is used only when it still describes what the code would compute: it holds the :func:`fingerprint` of
the code that fitted it, a probe unit's fits (a file made by code that fits the probe otherwise is refused, naming it:
delete it or give another folder), and the unit's draw (its parameters and paths) must be the one the seed draws now.
The probe is behaviour, not source: a change to the library that leaves every fit as it was (a new attribute, a
docstring, the rules after the fits) keeps the stored fits; one that moves any number of the probe's commissioning or
window fits does not. A change that moves fits only in a regime the probe does not reach would go unseen: after
changing how windows are fitted, delete the folder. The files are plain ``numpy`` archives read without pickle.
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from hydrowatch.condition import ConditionFeatures
from hydrowatch.condition import estimates as E
from hydrowatch.condition.unit_checks import RELIEF_SHUT_SHARE, pump_at_limit_share
from hydrowatch.plant import PlantSimulator
from hydrowatch.plant.excitation import duty_cycle, filtered_noise
from hydrowatch.plant.faults import FAULTS, speed_drop_table
from hydrowatch.plant.fleet import DegradationPath, Fleet, MachineSpec
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.population import later_day, random_unit
from hydrowatch.plant.wear import worn_parameters

CHANNELS = ("voltage", "flow", "speed", "torque")
W = 1000
"""Window length, samples (5 s at 200 Hz)."""
VOLTS = (0.5, 3.5)
CHUNK_S = 300.0
TO_INDEX = 1.3
START_S = 120.0
COMMISSIONING = {"noise": (0.0, 4.0), "noise5": (0.0, 5.0)}
"""Filtered-noise commissioning recordings by name, V: 0–4 V (the identification run of ``hydrowatch simulate``), or
up to full stroke (u_max = 5 V), where more units' pumps reach their limit (docs/degradation.md, "Limits")."""
FIELDS = ("severity", "mse", "curvature")
PROBE = (1, 0.1)
"""Seed and hours of the probe unit whose fits are the code's :func:`fingerprint`: a random unit commissioned as every
unit is, then its seven machines over 6 minutes (every part wearing from 0 to 1.3 within 4 of them), ~12 s."""


def _windows(out: dict[str, np.ndarray], i: int) -> np.ndarray:
    n = out["t"].shape[1] // W * W
    return np.stack([out[c][i, :n].reshape(-1, W) for c in CHANNELS], axis=-1)


def draw_unit(k: int, rng: np.random.Generator, hours: float) -> dict:
    """Everything random about unit k: its parameters, commissioning seed, later day, paths and seeds."""
    unit = random_unit(rng)
    commission_seed = int(rng.integers(2**31))
    day = later_day(unit, rng)
    shape = "linear" if k % 2 == 0 else "exp"
    longest = min(120.0, (hours * 3600.0 - START_S) / 60.0)  # every path ends inside the run
    paths = {f: DegradationPath(f, START_S, float(rng.uniform(min(30.0, longest), longest)) * 60.0,
                                final_drop=TO_INDEX * 0.3, shape=shape) for f in FAULTS}
    return {"unit": unit, "commission_seed": commission_seed, "day": day, "shape": shape, "paths": paths,
            "fleet_seed": int(rng.integers(2**31)), "command_seed": int(rng.integers(2**31))}


def commission(unit: PlantParameters, seed: int, command: str) -> tuple[ConditionFeatures, float]:
    """The unit commissioned on 300 s of ``command``, and the share of that recording's samples with the pump at its
    limit at the identified parameters (``pump_at_limit_share``: 0 = capacity not determined, ≥ 0.5 = relief gain
    barely seen; docs/degradation.md, "Limits")."""
    u = (duty_cycle(300.0, VOLTS, seed=seed) if command == "duty"
         else filtered_noise(300.0, COMMISSIONING[command], seed=seed))
    sim = PlantSimulator([unit], None, seed=seed)
    sim.settle(float(u[0]))
    out = sim.step(u[None, :])
    out = {k: v if v.ndim == 2 else v[None, :] for k, v in out.items()}
    healthy = _windows(out, 0)
    features = ConditionFeatures().fit({"healthy": healthy})
    return features, pump_at_limit_share(healthy, features.nominal_)


SCREEN_SHARE = RELIEF_SHUT_SHARE - 0.1
"""Pump-at-limit share, at the unit's true parameters, from which :func:`relief_shut_units` commissions a drawn unit
to see whether it is one: on the 80 units of seeds 2086–2095 the share at the identified parameters was within 0.01
of it (0.512 and 0.589 for 0.517 and 0.598). 0.4 while :data:`RELIEF_SHUT_SHARE` was 0.5."""


def _true_share(draw: dict) -> float:
    """The commissioning recording's share of samples with the pump at its limit at the unit's true parameters."""
    u = filtered_noise(300.0, COMMISSIONING["noise"], seed=draw["commission_seed"])
    sim = PlantSimulator([draw["unit"]], None, seed=draw["commission_seed"])
    sim.settle(float(u[0]))
    out = sim.step(u[None, :])
    return pump_at_limit_share(_windows({k: v if v.ndim == 2 else v[None, :] for k, v in out.items()}, 0),
                               draw["unit"])


def relief_shut_units(seed: int, units: int, hours: float, limit: int = 2000,
                      folder: str | Path | None = None) -> list[tuple[int, dict]]:
    """The first ``units`` units the seed draws whose commissioning (300 s of filtered noise 0–4 V) has the pump at
    its limit in :data:`RELIEF_SHUT_SHARE` of its samples or more (the relief's gain barely seen: about 1 unit in 13),
    as (k, draw); a unit is commissioned only when its true parameters give :data:`SCREEN_SHARE` or more. With a
    ``folder`` (``--fits``) the screen's unit numbers are kept there with the fingerprint of the code that screened
    (a replay then draws them without simulating the screen, ~2 minutes per seed)."""
    rng, found = np.random.default_rng(seed), []
    kept = None if folder is None else Path(folder) / f"seed{seed}_relief_shut_{hours:g}h.json"
    if kept is not None and kept.exists():
        known = json.loads(kept.read_text())
        if known["fingerprint"] == fingerprint() and len(known["units"]) >= units:
            wanted = set(known["units"][:units])
            draws = [(k, draw_unit(k, rng, hours)) for k in range(max(wanted) + 1)]
            return [(k, d) for k, d in draws if k in wanted]
    for k in range(limit):
        draw = draw_unit(k, rng, hours)
        if _true_share(draw) >= SCREEN_SHARE and commission(draw["unit"], draw["commission_seed"], "noise")[1] \
                >= RELIEF_SHUT_SHARE:
            found.append((k, draw))
            if len(found) == units:
                if kept is not None:
                    kept.parent.mkdir(parents=True, exist_ok=True)
                    kept.write_text(json.dumps({"fingerprint": fingerprint(), "units": [k for k, _ in found]}))
                return found
    raise ValueError(f"seed {seed}: only {len(found)} of {limit} units drawn had the relief barely seen")


def _estimates(features: ConditionFeatures, windows: np.ndarray) -> tuple[np.ndarray, dict]:
    """Valid mask and the free parity fits of one chunk's windows (kept small: the signals are dropped)."""
    valid = np.array([r is None for r in features.window_reasons(windows)], dtype=bool)
    p = features.nominal_
    sig = E.window_signals(windows[valid], features.sensors, p, features.viscosity_coefficient, p)
    est = E.parity_estimates(sig, p)
    return valid, {field: dict(getattr(est, field)) for field in FIELDS}


def _concat(parts: list[dict]) -> E.ParityEstimates:
    return E.ParityEstimates(*({k: np.concatenate([p[field][k] for p in parts]) for k in parts[0][field]}
                               for field in FIELDS))


def unit_fits(draw: dict, hours: float, command: str = "noise") -> dict[str, Any]:
    """Commission the unit, run its seven machines (six paths and a healthy one) over ``hours`` on the working duty
    cycle and fit every window: ``t`` (window starts, s), the commissioned ``nominal``, ``relations`` and
    ``capacity_known``, ``at_limit`` (the commissioning's pump-at-limit share) and per machine (valid mask, fits)."""
    features, at_limit = commission(draw["unit"], draw["commission_seed"], command)
    specs = [MachineSpec(f, path=p) for f, p in draw["paths"].items()] + [MachineSpec("healthy")]
    fleet = Fleet(specs, nominal=draw["day"], seed=draw["fleet_seed"])
    u = duty_cycle(hours * 3600.0, VOLTS, seed=draw["command_seed"])
    fleet.settle(float(u[0]))
    chunk = int(CHUNK_S * 200)
    valid: list[list[np.ndarray]] = [[] for _ in specs]
    fits: list[list[dict]] = [[] for _ in specs]
    starts: list[np.ndarray] = []
    for a in range(0, u.size, chunk):
        out = fleet.step(u[a:a + chunk])
        starts.append(out["t"][0, : out["t"].shape[1] // W * W : W])
        for i in range(len(specs)):
            ok, est = _estimates(features, _windows(out, i))
            valid[i].append(ok)
            fits[i].append(est)
    return {"t": np.concatenate(starts), "nominal": features.nominal_, "relations": tuple(features.relations_),
            "capacity_known": bool(features.capacity_known_), "at_limit": float(at_limit),
            "machines": {s.machine: (np.concatenate(valid[i]), _concat(fits[i])) for i, s in enumerate(specs)}}


@functools.cache
def fingerprint() -> str:
    """SHA-256 of the :data:`PROBE` unit's commissioning and window fits as this code makes them (float32, so that
    the last bits of a float do not count), on one thread, and of the parameters each fault's path gives a unit
    whose relief is shut at 2 V (:func:`hydrowatch.plant.wear.unseen_severity`: wear the probe's paths may not
    exercise)."""
    seed, hours = PROBE
    with threadpool_limits(1):
        fits = unit_fits(draw_unit(0, np.random.default_rng(seed), hours), hours)
    h = hashlib.sha256(json.dumps([fits["nominal"].to_dict(), list(fits["relations"]), fits["capacity_known"],
                                   round(fits["at_limit"], 6)]).encode())
    for machine, (valid, est) in fits["machines"].items():
        h.update(machine.encode() + valid.tobytes())
        for field in FIELDS:
            for key, x in sorted(getattr(est, field).items()):
                h.update(key.encode() + np.asarray(x, dtype=np.float32).tobytes())
    shut = PlantParameters().replace(omega_p=0.55 * PlantParameters().omega_p)  # the pump at its limit at 2 V
    for fault in FAULTS:
        path = DegradationPath(fault, 60.0, 600.0, final_drop=0.39)
        table = speed_drop_table(fault, path.top_drop, shut)
        worn = [worn_parameters(path, shut, table, t)[0].to_dict() for t in (0.0, 59.0, 60.0, 61.0, 300.0)]
        h.update(json.dumps(worn, sort_keys=True).encode())
    return h.hexdigest()


def _draw_summary(draw: dict) -> dict[str, Any]:
    return {"unit": draw["unit"].to_dict(), "day": draw["day"].to_dict(), "shape": draw["shape"],
            "durations_s": {f: p.duration_s for f, p in draw["paths"].items()}}


def fits_path(folder: str | Path, seed: int, k: int, hours: float, command: str) -> Path:
    return Path(folder) / f"seed{seed}_unit{k}_{hours:g}h_{command}.npz"


def save_fits(path: Path, fits: dict[str, Any], draw: dict) -> None:
    """Write one unit's fits (``unit_fits``) with the fingerprint and the draw they came from."""
    arrays: dict[str, np.ndarray] = {"t": fits["t"]}
    for machine, (valid, est) in fits["machines"].items():
        arrays[f"{machine}/valid"] = valid
        for field in FIELDS:
            for key, x in getattr(est, field).items():
                arrays[f"{machine}/{field}/{key}"] = np.asarray(x)
    meta = {"fingerprint": fingerprint(), "draw": _draw_summary(draw), "nominal": fits["nominal"].to_dict(),
            "relations": list(fits["relations"]), "capacity_known": fits["capacity_known"],
            "at_limit": fits["at_limit"], "machines": list(fits["machines"])}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, meta=np.array(json.dumps(meta)), **arrays)
    tmp.replace(path)


def load_fits(path: Path, draw: dict) -> dict[str, Any]:
    """One unit's stored fits; ValueError naming the file when it came from other fitting code or another draw."""
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        if meta["fingerprint"] != fingerprint():
            raise ValueError(f"{path}: window fits made by library code that fits otherwise (fingerprint "
                             f"{meta['fingerprint'][:12]}, this code's {fingerprint()[:12]}); delete the file or give "
                             "--fits another folder")
        if meta["draw"] != json.loads(json.dumps(_draw_summary(draw))):
            raise ValueError(f"{path}: fits of another unit than this seed draws (its parameters or paths differ); "
                             "delete the file or give --fits another folder")
        machines = {}
        for machine in meta["machines"]:
            fields = [{key[len(f"{machine}/{field}/"):]: z[key] for key in z.files
                       if key.startswith(f"{machine}/{field}/")} for field in FIELDS]
            machines[machine] = (z[f"{machine}/valid"], E.ParityEstimates(*fields))
        return {"t": z["t"], "nominal": PlantParameters.from_dict(meta["nominal"]),
                "relations": tuple(meta["relations"]), "capacity_known": meta["capacity_known"],
                "at_limit": meta["at_limit"], "machines": machines}


def cached_fits(folder: str | Path | None, seed: int, k: int, draw: dict, hours: float,
                command: str) -> tuple[dict[str, Any], bool]:
    """The unit's fits from ``folder`` when stored there, else simulated (and stored when a folder is given); True
    when they were read back."""
    path = None if folder is None else fits_path(folder, seed, k, hours, command)
    if path is not None and path.exists():
        return load_fits(path, draw), True
    fits = unit_fits(draw, hours, command)
    if path is not None:
        save_fits(path, fits, draw)
    return fits, False
