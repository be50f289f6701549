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
  not determine the part have none); ``early``: the share of windows with an index while the true index is 0.1–0.5
  (median and worst path: what the wider margin for early wear costs, docs/degradation.md);
- ``others max``: the largest (signed: false wear, not "better than new") index any *other* component reads on
  that path (worst unit), the share of windows where one reads above 0.15 (worst path) and ``paths``: how many paths
  had any such window (each listed after the table, with the part and the unit's commissioning);
- ``forecast err``: at the first window whose true index passes 0.5, the forecast time to alert against the truth,
  |error| / truth (median and worst unit), and ``covered``: the share of paths whose 95 % interval holds the truth
  (``None`` forecasts count as wrong and not covered), ``no fcst`` the paths without one, ``false fcst`` the paths
  on which, at that moment, another part forecasts an alert (any time ahead), and ``either`` those on which another
  part's alert forecast says it may be this part's (the relief spring and the coil sharing one index on a unit whose
  relief was barely seen, docs/degradation.md; the path's own forecast then says so too);
- ``95% holds``: the share of a path's indexed windows whose 95 % interval holds the true index (median and worst
  unit; the interval's honesty, docs/degradation.md "The 95 % interval"), and ``±`` its median half-width (the
  median over paths of each path's median);
- the healthy machine: the shortest ``alert_in_s`` any component forecasts after ``--hours`` (None: none);
- per unit, the commissioning recording's share of samples with the pump at its limit (0: the pump's capacity not
  determined; from 0.5 the relief's gain barely seen: the two causes of most misses, docs/degradation.md "Limits").

Run: ``python benchmarks/bench_degradation.py [--units 8] [--seed 2026 [2027 …]] [--hours 2] [--json OUT]
[--fits DIR]``: ~110 s per unit on one core; with ``--fits DIR`` each unit's window fits are kept and read back on the
next run (benchmarks/degradation_fits.py), which then takes ~5 s per unit: a change to the index or forecast rules is
re-measured on the same windows. ``--relief-shut``: only units whose commissioning had the pump at its limit in 30 %
of its samples or more (``unit_checks.RELIEF_SHUT_SHARE``: the relief's gain barely seen, about 1 unit in 13; half or
more before stop 60, about 1 in 40–80), the
first ``--units`` of each seed (unit numbers are their place in the seed's draws). Seeds 7 and 2054–2093 tuned the
constants of hydrowatch/condition/degradation.py, attribution.py and forecast.py during development, and later
stops' fresh seeds once a change was chosen on them (up to 2120 and 3030 by stop 64; docs/degradation.md says which
did what); report on another seed.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from degradation_fits import COMMISSIONING, START_S, TO_INDEX, W, cached_fits, draw_unit, relief_shut_units
from threadpoolctl import threadpool_limits

from hydrowatch.condition import estimates as E
from hydrowatch.condition.degradation import window_degradation
from hydrowatch.condition.forecast import part_forecast
from hydrowatch.condition.unit_checks import relief_barely_seen
from hydrowatch.plant.faults import FAULTS
from hydrowatch.plant.paths import path_index

FALSE_WEAR = 0.15
"""Index another part may not exceed on a path (issue 15: "other components: index stays below 0.15")."""


def score_unit(fits: dict, draw: dict) -> dict:
    """One unit's figures from its window fits (``degradation_fits.unit_fits``): per fault its path's, and the healthy
    machine's."""
    t, paths, shape = fits["t"], draw["paths"], draw["shape"]
    blocks = (W - 1) // E.parity.BLOCK
    result: dict = {"shape": shape, "paths": {}, "pump_at_limit_share": round(fits["at_limit"], 4)}
    for machine, (ok, est) in fits["machines"].items():
        d = window_degradation(est, ok, fits["nominal"], blocks, fits["relations"],
                               capacity_known=fits["capacity_known"],
                               relief_barely_seen=relief_barely_seen(fits["at_limit"]))
        if machine == "healthy":
            forecasts = {f: _forecast(t, d, f, t.size - 1) for f in FAULTS}
            soonest = [f.alert_in_s for f in forecasts.values()]
            result["healthy_soonest_s"] = min((s for s in soonest if s is not None), default=None)
            result["healthy_max_index"] = float(max(np.nanmax(np.abs(d.value[f])) for f in FAULTS))
            result["healthy"] = {f: {"max": float(np.nanmax(np.abs(d.value[f]))),
                                     "p99": float(np.nanpercentile(np.abs(d.value[f]), 99)),
                                     "forecast": forecasts[f].to_dict()} for f in FAULTS}
            continue
        fault, path = machine, paths[machine]
        truth = np.asarray(path_index(path, t + W / 400.0))
        v = d.value[fault]
        others = {g: d.value[g] for g in FAULTS if g != fault}
        above = np.nanmax(np.stack(list(others.values())), axis=0)  # false *wear*: signed
        band = (truth >= 0.1) & (truth < 0.5)
        row = {"duration_min": path.duration_s / 60.0, "mae": float(np.nanmean(np.abs(v - truth))),
               "indexed": float(np.mean(np.isfinite(v))),
               "indexed_early": float(np.mean(np.isfinite(v[band]))) if band.any() else None,
               "others_max": float(np.nanmax(above)), "others_share": float(np.nanmean(above > FALSE_WEAR)),
               "others_worn": sorted(g for g, x in others.items() if np.any(x > FALSE_WEAR)),
               "interval_covers": _interval_covers(d, fault, truth),
               "interval_half_width": _half_width(d, fault)}
        now = int(np.argmax(truth >= 0.5))
        t_alert = START_S + path.duration_s * _fraction_at(1.0 / TO_INDEX, shape)
        remaining = t_alert - (t[now] + W / 400.0)
        f = _forecast(t, d, fault, now)
        others = {g: _forecast(t, d, g, now) for g in FAULTS if g != fault}
        # another part's alert forecast: false, unless it says it may be this part's (a shared index, untold_from)
        found = {g: o.alert_in_s for g, o in others.items() if o.alert_in_s is not None and o.untold_from != fault}
        row["others_forecast_s"] = min(found.values(), default=None)
        row["others_forecast_part"] = min(found, key=found.__getitem__) if found else None
        row["either_forecast_parts"] = sorted(g for g, o in others.items()
                                              if o.alert_in_s is not None and o.untold_from == fault)
        row.update(remaining_s=remaining, forecast_s=f.alert_in_s, ci95=list(f.ci95), model=f.model, reason=f.reason,
                   untold_from=f.untold_from)
        row["forecast_err"] = None if f.alert_in_s is None else abs(f.alert_in_s - remaining) / remaining
        lo, hi = f.ci95
        row["covered"] = bool(f.alert_in_s is not None
                              and (lo or 0.0) <= remaining <= (hi if hi is not None else np.inf))
        result["paths"][fault] = row
    return result


def _forecast(t: np.ndarray, d, fault: str, now: int):
    """The forecast ``score --json`` gives of the part from windows 0..now, as the machine knew them then (a
    provisional value a later pool confirms joins only then; a part the latest window rules out has none; a part
    sharing its index with a look-alike says so: ``forecast.part_forecast``)."""
    return part_forecast(t, d, fault, now)


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
    parser.add_argument("--seed", type=int, nargs="+", default=[2026], help="one population per seed")
    parser.add_argument("--hours", type=float, default=2.0)
    parser.add_argument("--json", default=None)
    parser.add_argument("--commission", choices=(*COMMISSIONING, "duty"), default="noise",
                        help="commissioning recording: 300 s filtered noise 0-4 V (an identification run, default), "
                             "0-5 V (noise5: to full stroke), or 300 s of the working duty cycle")
    parser.add_argument("--only", type=int, default=None, help="run only unit K of the population (diagnosis)")
    parser.add_argument("--relief-shut", action="store_true",
                        help="only units whose commissioning barely saw the relief (pump at its limit in 30 %% of it "
                             "or more: about 1 unit in 13), the first --units of each seed")
    parser.add_argument("--fits", default=None, metavar="DIR",
                        help="keep each unit's window fits in DIR and read them back when there (degradation_fits)")
    args = parser.parse_args()
    if args.relief_shut and args.commission != "noise":
        parser.error("--relief-shut selects units by their commissioning on filtered noise 0-4 V (--commission noise)")
    units: dict[str, dict] = {}
    with threadpool_limits(1):
        for seed in args.seed:
            rng = np.random.default_rng(seed)
            drawn = (relief_shut_units(seed, args.units, args.hours, folder=args.fits) if args.relief_shut
                     else [(k, draw_unit(k, rng, args.hours)) for k in range(args.units)])
            for k, draw in drawn:
                if args.only is not None and k != args.only:
                    continue
                t0 = time.time()
                fits, stored = cached_fits(args.fits, seed, k, draw, args.hours, args.commission)
                units[f"{seed}/{k}"] = score_unit(fits, draw)
                print(f"seed {seed} unit {k}: {time.time() - t0:.0f} s{' (stored fits)' if stored else ''}",
                      flush=True)
    summarise(units, args)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"seeds": args.seed, "units": units, "hours": args.hours, "commission": args.commission}, fh,
                      indent=1, default=str)


def summarise(units: dict[str, dict], args: argparse.Namespace) -> None:
    """The table per fault kind, the paths with false wear, the healthy machines and the commissioning shares."""
    print(f"\n{len(units)} units (seeds {' '.join(map(str, args.seed))}), {args.hours:g} h each, working duty cycle "
          f"0.5-3.5 V, later day, commissioned on {args.commission}")
    print(f"{'fault':14} {'index MAE med/worst':>20} {'indexed':>8} {'early med/worst':>16} {'others max':>10} "
          f"{'>0.15':>7} {'paths':>5} {'fcst err med/worst':>19} {'covered':>8} {'no fcst':>8} "
          f"{'95% holds med/worst':>20} {'±':>6} {'false fcst':>10} {'either':>6}")
    worn = []
    for fault in FAULTS:
        rows = [u["paths"][fault] for u in units.values()]
        mae = np.array([r["mae"] for r in rows])
        err = np.array([np.inf if r["forecast_err"] is None else r["forecast_err"] for r in rows])
        print(f"{fault:14} {np.median(mae):9.3f} / {mae.max():.3f} {min(r['indexed'] for r in rows):8.0%} "
              f"{_median_worst([r['indexed_early'] for r in rows]):>16} "
              f"{max(r['others_max'] for r in rows):10.3f} {max(r['others_share'] for r in rows):7.1%} "
              f"{sum(r['others_share'] > 0 for r in rows):5d} {np.median(err):9.1%} / {err.max():6.1%} "
              f"{np.mean([r['covered'] for r in rows]):8.0%} {sum(r['forecast_s'] is None for r in rows):8d} "
              f"{_median_worst([r.get('interval_covers') for r in rows])} "
              f"{np.median([r['interval_half_width'] for r in rows if r.get('interval_half_width') is not None]):6.3f} "
              f"{sum(r.get('others_forecast_s') is not None for r in rows):10d} "
              f"{sum(bool(r.get('either_forecast_parts')) for r in rows):6d}")
        worn += [f"  {name} {fault}: {', '.join(r['others_worn'])} above {FALSE_WEAR} in {r['others_share']:.1%} of "
                 f"its windows (largest {r['others_max']:.2f}; commissioning at the pump's limit "
                 f"{units[name]['pump_at_limit_share']:.0%})"
                 for name, r in ((n, u["paths"][fault]) for n, u in units.items()) if r["others_share"] > 0]
    print(f"paths on which another part reads above {FALSE_WEAR}: {len(worn)} of {len(units) * len(FAULTS)}")
    print("\n".join(worn))
    soonest = [u["healthy_soonest_s"] for u in units.values()]
    finite = [s for s in soonest if s is not None]
    print(f"healthy {args.hours:g} h: soonest forecast alert "
          f"{'none' if not finite else f'{min(finite) / 3600:.1f} h'} ({len(finite)} of {len(units)} units forecast "
          f"one); largest |index| {max(u['healthy_max_index'] for u in units.values()):.3f}")
    print("commissioning's share of samples with the pump at its limit, per unit: "
          + " ".join(f"{name} {u['pump_at_limit_share']:.3f}" for name, u in units.items()))


if __name__ == "__main__":
    main()
