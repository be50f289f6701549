"""The gap analyser on a population of units whose every parameter differs from the design (issue 12).

Each run: a random unit (every parameter of ``hydrowatch.gap.CALIBRATED`` × U(0.7, 1.3), default
sensor noise), 120 s of filtered noise over −4…4 V, and one case concealed in it: nothing, one
catalog effect at a random realistic magnitude (bench_gap.MAGNITUDES; thermal drift with τ from
20 s to 300 s), a pair, or out-of-catalog physics (``OUT_OF_CATALOG``). The analysis starts from
the design values, with every default. A run is **right** when the report names exactly the
concealed effects (nothing: no effect; out-of-catalog: ``unidentified``, for one sensor or more, and
no catalog effect).

Every row also says whether the case *matters* on this record (the calibrated model's held-out
NRMSE ≥ 2× the noise ceiling on some sensor) and whether the report lists the concealed effect
under ``experiments`` (the recording cannot reveal it; the report names the run that would):
such runs are counted separately, not hidden in the rate.

    python benchmarks/bench_gap_population.py --population 2027 --units 2 --out runs.jsonl
    python benchmarks/bench_gap_population.py --cases none --units 10 --population 2027 --out runs.jsonl
    python benchmarks/bench_gap_population.py --table runs.jsonl

A figure counts only on a population that tuned nothing: say which ``--population`` gave it. One
process (the machine has 2 cores); say the load average (printed per run).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_gap import MAGNITUDES  # noqa: E402

from hydrowatch.gap import CALIBRATED, GapAnalyser  # noqa: E402
from hydrowatch.plant.excitation import filtered_noise  # noqa: E402
from hydrowatch.plant.parameters import PlantParameters  # noqa: E402
from hydrowatch.plant.simulator import simulate  # noqa: E402
from hydrowatch.recording import Recording  # noqa: E402

SPREAD = 0.3
"""Every calibrated parameter of a unit is its design value × U(1 − SPREAD, 1 + SPREAD)."""

SECONDS = 120.0
VOLTS = (-4.0, 4.0)

DRIFT_TAU = (20.0, 300.0)
"""Warm-up time constants of the concealed thermal drift, s (short ones as well as long)."""

PAIRS = ("pump_ripple+valve_saturation", "transport_delay+quadratic_drag", "gear_backlash+entrained_air")
OUT_OF_CATALOG = ("angle_ripple", "kinked_flow_meter")
"""Physics the catalog lacks, applied to the recorded sensors: a load-torque ripple tied to the
load angle (2 per revolution, 3–8 % of the torque's spread, in the torque sensor), and a flow
meter whose gain bends with the flow (a tanh kink of 4–8 % of the flow's spread)."""

EFFECTS = ("stribeck_friction", "quadratic_drag", "valve_deadband", "valve_saturation", "valve_hysteresis",
           "transport_delay", "entrained_air", "pump_ripple", "thermal_drift", "gear_backlash", "shaft_compliance",
           "sensor_lowpass")
CASES = ("none", *OUT_OF_CATALOG, *EFFECTS, *PAIRS)


def random_unit(rng: np.random.Generator) -> PlantParameters:
    """One unit: every calibrated parameter × U(1 − SPREAD, 1 + SPREAD), default sensor noise."""
    p = PlantParameters()
    return p.replace(**{k: getattr(p, k) * float(rng.uniform(1 - SPREAD, 1 + SPREAD)) for k in CALIBRATED})


def draw(effect_id: str, rng: np.random.Generator) -> dict[str, float]:
    """A random realistic magnitude of one catalog effect."""
    ranges = dict(MAGNITUDES[effect_id])
    if effect_id == "thermal_drift":
        ranges["tau"] = DRIFT_TAU
    values = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in ranges.items()}
    if effect_id == "sensor_lowpass":
        values["sensor"] = float(rng.integers(0, 3))
    return values


def recording(case: str, population: int, unit: int) -> tuple[Recording, list[str]]:
    """The recording of one run and the ids a right report names."""
    seed = population * 1000 + unit
    rng = np.random.default_rng([population, unit])
    plant = random_unit(rng)
    command = filtered_noise(SECONDS, VOLTS, seed=seed)
    if case in OUT_OF_CATALOG:
        rec = simulate(command, plant, None, seed=seed)
        return _out_of_catalog(rec, case, rng, plant), ["unidentified"]
    ids = [] if case == "none" else case.split("+")
    rec = simulate(command, plant, {e: draw(e, rng) for e in ids}, seed=seed)
    return rec, ids


def _out_of_catalog(rec: Recording, case: str, rng: np.random.Generator, plant: PlantParameters) -> Recording:
    channels = dict(rec.channels)
    if case == "angle_ripple":
        angle = np.cumsum(rec["speed"]) / 200.0
        channels["torque"] = rec["torque"] + float(rng.uniform(0.03, 0.08)) * np.std(rec["torque"]) * np.sin(2 * angle)
    else:
        flow = rec["flow"]
        spread = float(np.std(flow))
        kink = np.tanh((flow - np.median(flow)) / (0.3 * spread))
        channels["flow"] = flow + float(rng.uniform(0.04, 0.08)) * spread * kink
    return Recording(rec.t, channels, rec.meta)


def one_run(case: str, population: int, unit: int) -> dict:
    """Analyse one run; the row of the table."""
    rec, expected = recording(case, population, unit)
    start, cpu = time.perf_counter(), time.process_time()
    report = GapAnalyser().fit(rec).report_
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    named = [e["id"] for e in report["effects"]]
    fit, noise = report["fit"], report["noise"]
    ratio = {s: fit["calibrated"][s] / noise[s] for s in noise}
    right = set(named) == {"unidentified"} if expected == ["unidentified"] else sorted(named) == sorted(expected)
    return {"case": case, "population": population, "unit": unit, "right": right,
            "named": named, "matters": max(ratio.values()) >= 2.0,
            "calibrated_over_noise": {s: round(v, 3) for s, v in ratio.items()},
            "unrevealable": [e for e in expected if e in report["experiments"]],
            "tested": report["discovery_test"]["calibrated"]["beyond"],
            "not_determined": sorted(report["identifiability"]["not_determined"]),
            "wall": round(wall, 1), "cpu": round(cpu, 1), "load": round(os.getloadavg()[0], 2)}


def table(rows: list[dict]) -> str:
    """The success table (markdown): one line per case, over every population in ``rows``."""
    lines = ["| case | runs | right | rate | right where it matters | unrevealable (experiment named) "
             "| calibrated/noise NRMSE median (worst) | CPU s median (worst) | named when wrong |",
             "|---|---|---|---|---|---|---|---|---|"]
    for case in dict.fromkeys(r["case"] for r in rows):
        runs = [r for r in rows if r["case"] == case]
        right = sum(r["right"] for r in runs)
        matter = [r for r in runs if r["matters"] and not r["unrevealable"]]
        ratios = [max(r["calibrated_over_noise"].values()) for r in runs]
        cpu = [r["cpu"] for r in runs]
        wrong = sorted({"+".join(r["named"]) or "nothing" for r in runs if not r["right"]})
        unrevealable = sum(bool(r["unrevealable"]) for r in runs)
        lines.append(f"| {case} | {len(runs)} | {right} | {right / len(runs):.0%} | "
                     f"{sum(r['right'] for r in matter)}/{len(matter)} | {unrevealable} | "
                     f"{np.median(ratios):.2f} ({max(ratios):.2f}) | {np.median(cpu):.0f} ({max(cpu):.0f}) | "
                     f"{', '.join(wrong) or '–'} |")
    loads = [r["load"] for r in rows]
    pops = sorted({r["population"] for r in rows})
    lines.append(f"\npopulations {pops}; load average (1 min) after each run {min(loads):.1f}–{max(loads):.1f} "
                 f"on {os.cpu_count()} cores")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES), help="comma list; 'none', catalog ids, a+b pairs, "
                        f"{', '.join(OUT_OF_CATALOG)}")
    parser.add_argument("--population", type=int, default=2027,
                        help="population seed (report on one that tuned nothing)")
    parser.add_argument("--units", type=int, default=2, help="units per case")
    parser.add_argument("--first-unit", type=int, default=0)
    parser.add_argument("--out", type=Path, help="append one JSON line per run; runs already there are skipped")
    parser.add_argument("--table", type=Path, help="only print the table of a --out file")
    args = parser.parse_args()
    if args.table:
        print(table([json.loads(line) for line in args.table.read_text().splitlines() if line.strip()]))
        return
    done = set()
    if args.out and args.out.exists():
        done = {(r["case"], r["population"], r["unit"]) for r in map(json.loads, args.out.read_text().splitlines())}
    rows = []
    for unit in range(args.first_unit, args.first_unit + args.units):
        for case in args.cases.split(","):
            if (case, args.population, unit) in done:
                continue
            row = one_run(case, args.population, unit)
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.out:
                with args.out.open("a") as f:
                    f.write(json.dumps(row) + "\n")
    if rows:
        print(table(rows))


if __name__ == "__main__":
    main()
