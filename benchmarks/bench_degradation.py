"""Degradation index and forecast on parts wearing out, on units that did not tune them (issue 15).

Each unit draws every nominal parameter (``hydrowatch.plant.population.random_unit``: ±20 %, leakages and damping
±50 %, sensor noise 1–3× the default). It is commissioned on 300 s of its own healthy operation
(``ConditionFeatures().fit({"healthy": …})``: the unit's nominal parameters are identified, as ``hydrowatch
commission`` does): filtered noise 0–4 V by default (an identification run), or its working duty cycle
(``--commission duty``, which leaves the pump and relief to the prior: docs/unseen-units.md). It then runs on a
**later day** (``later_day``: leakages, load and damping drifted ±3–5 %) for
``--hours`` on a working duty cycle (holds, ramps, steps over 0.5–3.5 V) as seven machines: six each with one part
wearing from index 0 to 1.3 (beyond the alert) over 30–120 minutes (drawn per path, starting after 2 minutes),
linear on even units and accelerating (``exp``) on odd ones, and one healthy machine.

Per fault kind it prints:

- ``index MAE``: mean |index − true index| over the path's windows with an index (median and worst unit), and
  ``indexed``: the smallest share of a path's windows that have one (invalid windows and windows whose fit does
  not determine the part have none);
- ``others max``: the largest (signed: false wear, not "better than new") index any *other* component reads on
  that path (worst unit), and the share of windows
  where one reads above 0.15;
- ``forecast err``: at the first window whose true index passes 0.5, the forecast time to alert against the truth,
  |error| / truth (median and worst unit), and ``covered``: the share of paths whose 95 % interval holds the truth
  (``None`` forecasts count as wrong and not covered), ``no fcst`` the paths without one, and ``false fcst`` the paths
  on which, at that moment, another part forecasts an alert (any time ahead);
- ``95% holds``: the share of a path's indexed windows whose 95 % interval holds the true index (median and worst
  unit; the interval's honesty, docs/degradation.md "The 95 % interval"), and ``±`` its median half-width (the
  median over paths of each path's median);
- the healthy machine: the shortest ``alert_in_s`` any component forecasts after ``--hours`` (None: none);
- per unit, the commissioning recording's share of samples with the pump at its limit (0: the pump's capacity not
  determined; from 0.5 the relief's gain barely seen: the two causes of most misses, docs/degradation.md "Limits").

Run: ``python benchmarks/bench_degradation.py [--units 8] [--seed 2026] [--hours 2] [--json OUT]``. The population
of ``--seed 7`` tuned the constants of hydrowatch/condition/degradation.py and forecast.py during development;
report on another seed.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from threadpoolctl import threadpool_limits

from hydrowatch.condition import ConditionFeatures
from hydrowatch.condition import estimates as E
from hydrowatch.condition.degradation import window_degradation
from hydrowatch.condition.forecast import forecast_alert, ruled_out_forecast
from hydrowatch.condition.unit_checks import pump_at_limit_share
from hydrowatch.plant import PlantSimulator
from hydrowatch.plant.excitation import duty_cycle, filtered_noise
from hydrowatch.plant.faults import FAULTS
from hydrowatch.plant.fleet import DegradationPath, Fleet, MachineSpec
from hydrowatch.plant.paths import path_index
from hydrowatch.plant.population import later_day, random_unit

CHANNELS = ("voltage", "flow", "speed", "torque")
W = 1000
VOLTS = (0.5, 3.5)
CHUNK_S = 300.0
TO_INDEX = 1.3
START_S = 120.0


def _windows(out: dict[str, np.ndarray], i: int) -> np.ndarray:
    n = out["t"].shape[1] // W * W
    return np.stack([out[c][i, :n].reshape(-1, W) for c in CHANNELS], axis=-1)


COMMISSIONING = {"noise": (0.0, 4.0), "noise5": (0.0, 5.0)}
"""Filtered-noise commissioning recordings by name, V: 0–4 V (the identification run of ``hydrowatch simulate``), or
up to full stroke (u_max = 5 V), where more units' pumps reach their limit (docs/degradation.md, "Limits")."""


def _commission(unit, seed: int, command: str) -> tuple[ConditionFeatures, float]:
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


def _estimates(features: ConditionFeatures, windows: np.ndarray) -> tuple[np.ndarray, dict]:
    """Valid mask and the free parity fits of one chunk's windows (kept small: the signals are dropped)."""
    valid = np.array([r is None for r in features.window_reasons(windows)], dtype=bool)
    p = features.nominal_
    sig = E.window_signals(windows[valid], features.sensors, p, features.viscosity_coefficient, p)
    est = E.parity_estimates(sig, p)
    return valid, {"severity": dict(est.severity), "mse": dict(est.mse), "curvature": dict(est.curvature)}


def _concat(parts: list[dict]) -> E.ParityEstimates:
    return E.ParityEstimates(*({k: np.concatenate([p[field][k] for p in parts]) for k in parts[0][field]}
                               for field in ("severity", "mse", "curvature")))


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


def run_unit(draw: dict, hours: float, command: str = "noise") -> dict:
    """One unit: commission, then seven machines over ``hours``; per fault the path's figures, and the healthy one."""
    features, at_limit = _commission(draw["unit"], draw["commission_seed"], command)
    shape, paths = draw["shape"], draw["paths"]
    specs = [MachineSpec(f, path=p) for f, p in paths.items()] + [MachineSpec("healthy")]
    fleet = Fleet(specs, nominal=draw["day"], seed=draw["fleet_seed"])
    total = hours * 3600.0
    u = duty_cycle(total, VOLTS, seed=draw["command_seed"])
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
    t = np.concatenate(starts)
    blocks = (W - 1) // E.parity.BLOCK
    result: dict = {"shape": shape, "paths": {}, "pump_at_limit_share": round(at_limit, 4)}
    for i, spec in enumerate(specs):
        ok = np.concatenate(valid[i])
        d = window_degradation(_concat(fits[i]), ok, features.nominal_, blocks, features.relations_,
                               capacity_known=features.capacity_known_)
        if spec.machine == "healthy":
            forecasts = {f: _forecast(t, d, f, t.size - 1) for f in FAULTS}
            soonest = [f.alert_in_s for f in forecasts.values()]
            result["healthy_soonest_s"] = min((s for s in soonest if s is not None), default=None)
            result["healthy_max_index"] = float(max(np.nanmax(np.abs(d.value[f])) for f in FAULTS))
            result["healthy"] = {f: {"max": float(np.nanmax(np.abs(d.value[f]))),
                                     "p99": float(np.nanpercentile(np.abs(d.value[f]), 99)),
                                     "forecast": forecasts[f].to_dict()} for f in FAULTS}
            continue
        fault, path = spec.machine, paths[spec.machine]
        truth = np.asarray(path_index(path, t + W / 400.0))
        v = d.value[fault]
        others = np.nanmax(np.stack([d.value[f] for f in FAULTS if f != fault]), axis=0)  # false *wear*: signed
        row = {"duration_min": path.duration_s / 60.0, "mae": float(np.nanmean(np.abs(v - truth))),
               "indexed": float(np.mean(np.isfinite(v))),
               "others_max": float(np.nanmax(others)), "others_share": float(np.nanmean(others > 0.15)),
               "interval_covers": _interval_covers(d, fault, truth),
               "interval_half_width": _half_width(d, fault)}
        now = int(np.argmax(truth >= 0.5))
        t_alert = START_S + path.duration_s * _fraction_at(1.0 / TO_INDEX, shape)
        remaining = t_alert - (t[now] + W / 400.0)
        f = _forecast(t, d, fault, now)
        wrong = {g: _forecast(t, d, g, now).alert_in_s for g in FAULTS if g != fault}
        found = {g: x for g, x in wrong.items() if x is not None}  # a false alert forecast
        row["others_forecast_s"] = min(found.values(), default=None)
        row["others_forecast_part"] = min(found, key=found.__getitem__) if found else None
        row.update(remaining_s=remaining, forecast_s=f.alert_in_s, ci95=list(f.ci95), model=f.model, reason=f.reason)
        row["forecast_err"] = None if f.alert_in_s is None else abs(f.alert_in_s - remaining) / remaining
        lo, hi = f.ci95
        row["covered"] = f.alert_in_s is not None and (lo or 0.0) <= remaining <= (hi if hi is not None else np.inf)
        result["paths"][fault] = row
    return result


def _forecast(t: np.ndarray, d, fault: str, now: int):
    """The forecast ``score --json`` gives of the part from windows 0..now, as the machine knew them then (a
    provisional value a later pool confirms joins only then; a part the latest window rules out has none:
    ``training.scoring.degradation_forecast``)."""
    if d.ruled_out(fault, now):
        return ruled_out_forecast()
    return forecast_alert(t[: now + 1], d.history(fault, upto=now))


def _interval_covers(d, fault: str, truth: np.ndarray) -> float | None:
    """Share of the path's windows with an index whose 95 % interval holds the true index (None: no index)."""
    has = np.isfinite(d.value[fault])
    if not has.any():
        return None
    lo, hi = d.low[fault][has], d.high[fault][has]
    return float(np.mean((lo <= truth[has]) & (truth[has] <= hi)))


def _half_width(d, fault: str) -> float | None:
    """Median half-width of the path's 95 % intervals, in index (None: no index)."""
    has = np.isfinite(d.value[fault])
    return float(np.median((d.high[fault][has] - d.low[fault][has]) / 2.0)) if has.any() else None


def _median_worst(shares: list) -> str:
    """"median / worst" of per-path shares (None: the path had no index)."""
    x = np.array([v for v in shares if v is not None], dtype=float)
    return f"{'-':>20}" if x.size == 0 else f"{np.median(x):10.1%} / {x.min():6.1%}"


def _fraction_at(x: float, shape: str) -> float:
    """Elapsed fraction of a path at which its drop fraction reaches x (inverse of the path's shape)."""
    if shape == "linear":
        return x
    from hydrowatch.plant.fleet import EXP_GROWTH

    return float(np.log1p(x * np.expm1(EXP_GROWTH)) / EXP_GROWTH)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=8)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--hours", type=float, default=2.0)
    parser.add_argument("--json", default=None)
    parser.add_argument("--commission", choices=(*COMMISSIONING, "duty"), default="noise",
                        help="commissioning recording: 300 s filtered noise 0-4 V (an identification run, default), "
                             "0-5 V (noise5: to full stroke), or 300 s of the working duty cycle")
    parser.add_argument("--only", type=int, default=None, help="run only unit K of the population (diagnosis)")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    units = []
    with threadpool_limits(1):
        for k in range(args.units):
            draw = draw_unit(k, rng, args.hours)
            if args.only is not None and k != args.only:
                continue
            t0 = time.time()
            units.append(run_unit(draw, args.hours, args.commission))
            print(f"unit {k}: {time.time() - t0:.0f} s", flush=True)
    print(f"\n{len(units)} units (seed {args.seed}), {args.hours:g} h each, working duty cycle {VOLTS} V, later day, "
          f"commissioned on {args.commission}")
    print(f"{'fault':14} {'index MAE med/worst':>20} {'indexed':>8} {'others max':>10} {'>0.15':>7} "
          f"{'fcst err med/worst':>19} {'covered':>8} {'no fcst':>8} {'95% holds med/worst':>20} {'±':>6} "
          f"{'false fcst':>10}")
    for fault in FAULTS:
        rows = [u["paths"][fault] for u in units]
        mae = np.array([r["mae"] for r in rows])
        err = np.array([np.inf if r["forecast_err"] is None else r["forecast_err"] for r in rows])
        print(f"{fault:14} {np.median(mae):9.3f} / {mae.max():.3f} {min(r['indexed'] for r in rows):8.0%} "
              f"{max(r['others_max'] for r in rows):10.3f} "
              f"{max(r['others_share'] for r in rows):7.1%} {np.median(err):9.1%} / {err.max():6.1%} "
              f"{np.mean([r['covered'] for r in rows]):8.0%} {sum(r['forecast_s'] is None for r in rows):8d} "
              f"{_median_worst([r.get('interval_covers') for r in rows])} "
              f"{np.median([r['interval_half_width'] for r in rows if r.get('interval_half_width') is not None]):6.3f} "
              f"{sum(r.get('others_forecast_s') is not None for r in rows):10d}")
    soonest = [u["healthy_soonest_s"] for u in units]
    finite = [s for s in soonest if s is not None]
    print(f"healthy {args.hours:g} h: soonest forecast alert "
          f"{'none' if not finite else f'{min(finite) / 3600:.1f} h'} ({len(finite)} of {len(units)} units forecast "
          f"one); largest |index| {max(u['healthy_max_index'] for u in units):.3f}")
    print("commissioning's share of samples with the pump at its limit, per unit: "
          + " ".join(f"{u['pump_at_limit_share']:.3f}" for u in units))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"seed": args.seed, "units": units, "hours": args.hours}, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
