"""Success rates and cost of the gap analyser (issue 6).

For every effect: recordings made by the simulator with the effect concealed at a random realistic
magnitude, on a plant whose calibrated parameters differ from nominal by ±20 %, with sensor noise,
a 0–4 V filtered-noise command (bipolar −4…4 V for gear_backlash). The analysis starts from the
nominal parameters. A run is *right* when the report names the effect first and the held-out
NRMSE of the first located sensor falls by >= 30 % from the calibrated fit ("excess cut": its
error above the noise ceiling falls by >= 30 %, for effects the calibration had already mostly
absorbed). The null case (no effect) is right when ``mismatch`` is false. Pairs are right when both effects are named.

Targets: >= 90 % right per effect, no false discovery in the null case, a 120 s recording in under
5 minutes on 2 cores (reference = 300 s; the ratio is printed).

    python benchmarks/bench_gap.py --seeds 5 --seconds 30
    python benchmarks/bench_gap.py --effects none,transport_delay --seeds 10
    python benchmarks/bench_gap.py --timing 120          # one 120 s recording, all candidates
    python benchmarks/bench_gap.py --seeds 10 --jobs 2 --out runs.jsonl   # resumable; seeds interleaved
    python benchmarks/bench_gap.py --table runs.jsonl    # the success table of what has run

Timings on a shared machine are pessimistic: say how loaded it was.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import time
from pathlib import Path

import numpy as np

from hydrowatch.gap import CALIBRATED, GapAnalyser
from hydrowatch.plant.effects import EFFECT_IDS
from hydrowatch.plant.excitation import filtered_noise
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate

MAGNITUDES: dict[str, dict[str, tuple[float, float]]] = {
    "stribeck_friction": {"Ts": (0.6, 1.5), "Tc": (0.1, 0.3)},
    "quadratic_drag": {"Kd": (0.02, 0.05)},
    "valve_deadband": {"d": (0.05, 0.15)},
    "valve_saturation": {"x_max": (0.45, 0.65)},
    "valve_hysteresis": {"r": (0.1, 0.3)},
    "transport_delay": {"tau": (0.005, 0.02)},
    "entrained_air": {"alpha": (0.02, 0.1)},
    "pump_ripple": {"a1": (0.05, 0.2), "a2": (0.02, 0.1)},
    "thermal_drift": {"T_start": (30.0, 40.0), "T_end": (60.0, 80.0), "tau": (60.0, 300.0)},
    "gear_backlash": {"b": (0.01, 0.04)},
    "shaft_compliance": {"G": (300.0, 1500.0)},
    "sensor_lowpass": {"sensor": (0.0, 2.0), "tau": (0.01, 0.05)},
}
"""Ranges of the concealed magnitudes (uniform); sensor_lowpass's sensor is drawn from {0, 1, 2}."""

REFERENCE_SECONDS = 300.0
"""Target wall time for a 120 s recording, s."""


def draw_effect(effect_id: str, rng: np.random.Generator) -> dict[str, float]:
    """A random realistic magnitude of one effect."""
    values = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in MAGNITUDES[effect_id].items()}
    if effect_id == "sensor_lowpass":
        values["sensor"] = float(rng.integers(0, 3))
    return values


def plant(rng: np.random.Generator, spread: float = 0.2) -> PlantParameters:
    """Nominal plant with every calibrated parameter scaled by U(1 − spread, 1 + spread)."""
    p = PlantParameters()
    return p.replace(**{k: getattr(p, k) * rng.uniform(1 - spread, 1 + spread) for k in CALIBRATED})


def one_run(effect_ids: tuple[str, ...], seed: int, seconds: float, candidates: tuple[str, ...] | None
            ) -> tuple[bool, float, dict]:
    """Simulate, analyse, judge. Returns (right, wall seconds, report)."""
    rng = np.random.default_rng(seed)
    effects = {e: draw_effect(e, rng) for e in effect_ids}
    volts = (-4.0, 4.0) if "gear_backlash" in effect_ids else (0.0, 4.0)
    rec = simulate(filtered_noise(seconds, volts, seed=seed), plant(rng), effects, seed=seed)
    start = time.perf_counter()
    report = GapAnalyser(candidates=candidates).fit(rec).report_
    wall = time.perf_counter() - start
    named = [e["id"] for e in report["effects"]]
    if not effect_ids:
        return report["mismatch"] is False, wall, report
    if len(effect_ids) > 1:
        return set(effect_ids) <= set(named), wall, report
    sensors = [row["sensor"] for row in report["located"] if "relation" not in row]
    if not named or named[0] != effect_ids[0] or not sensors:
        return False, wall, report
    cut = 1 - report["fit"]["after"][sensors[0]] / report["fit"]["calibrated"][sensors[0]]
    return cut >= 0.3, wall, report


def _job(task: tuple[str, int, float, tuple[str, ...] | None]) -> dict:
    case, seed, seconds, candidates = task
    ids = () if case == "none" else tuple(case.split("+"))
    right, wall, report = one_run(ids, seed, seconds, candidates)
    sensors = [row["sensor"] for row in report["located"] if "relation" not in row]
    cut = excess_cut = None
    if sensors:
        before, after, noise = (report["fit"]["calibrated"][sensors[0]], report["fit"]["after"][sensors[0]],
                                report["noise"][sensors[0]])
        cut = 1 - after / before
        excess_cut = 1 - max(after**2 - noise**2, 0.0) / max(before**2 - noise**2, 1e-12)
    return {"case": case, "seed": seed, "seconds": seconds, "right": bool(right), "wall": round(wall, 1),
            "named": [e["id"] for e in report["effects"]], "cut": cut, "excess_cut": excess_cut,
            "broken": [r["relation"] for r in report["relations"] if r["broken"]]}


def table(rows: list[dict]) -> str:
    """The success table (markdown) of finished runs, one line per case and length."""
    groups: dict[tuple[str, float], list[dict]] = {}
    for row in rows:
        groups.setdefault((row["case"], row["seconds"]), []).append(row)
    lines = ["| case | s | right | rate | mean wall s | named first | right on excess | false extra "
             "| relations broken (most often) |", "|---|---|---|---|---|---|---|---|---|"]
    for (case, seconds), runs in groups.items():
        ids = [] if case == "none" else case.split("+")
        right = sum(r["right"] for r in runs)
        first = sum(bool(r["named"]) and (not ids or r["named"][0] in ids) for r in runs) if ids else "–"
        # cut >= 30 % implies an excess cut >= 51 %, so a right run is right on the excess too
        excess = (f"{sum(r['right'] or (r['named'][:1] == ids and (r.get('excess_cut') or 0.0) >= 0.3) for r in runs)}"
                  f"/{len(runs)}" if len(ids) == 1 else "–")
        extra = sum(bool(set(r["named"]) - set(ids)) for r in runs)
        counts: dict[str, int] = {}
        for r in runs:
            key = "+".join(r["broken"]) or "none"
            counts[key] = counts.get(key, 0) + 1
        common = max(counts, key=lambda k: counts[k])
        lines.append(f"| {case} | {seconds:g} | {right}/{len(runs)} | {right / len(runs):.0%} | "
                     f"{np.mean([r['wall'] for r in runs]):.0f} | {first} | {excess} | {extra} | "
                     f"{common} ({counts[common]}) |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effects", default="none," + ",".join(EFFECT_IDS),
                        help="comma list; 'none' is the null case; 'a+b' is a pair")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--candidates", help="comma list of candidate effects (default: all)")
    parser.add_argument("--timing", type=float, help="only time one recording of this many seconds")
    parser.add_argument("--jobs", type=int, default=1, help="recordings analysed at once (processes)")
    parser.add_argument("--out", type=Path, help="append one JSON line per run here; runs already in it are skipped")
    parser.add_argument("--table", type=Path, help="only print the success table of a --out file")
    args = parser.parse_args()
    if args.table:
        print(table([json.loads(line) for line in args.table.read_text().splitlines() if line.strip()]))
        return
    candidates = tuple(args.candidates.split(",")) if args.candidates else None
    if args.timing:
        _, wall, report = one_run(("transport_delay",), 0, args.timing, candidates)
        print(f"{args.timing:g} s recording, transport_delay concealed: {wall:.1f} s wall "
              f"(reference {REFERENCE_SECONDS:g} s, ratio {wall / REFERENCE_SECONDS:.2f}); named "
              f"{[e['id'] for e in report['effects']]}")
        return
    done = set()
    if args.out and args.out.exists():
        done = {(r["case"], r["seed"], r["seconds"]) for r in map(json.loads, args.out.read_text().splitlines())}
    tasks = [(case, seed, args.seconds, candidates) for seed in range(args.first_seed, args.first_seed + args.seeds)
             for case in args.effects.split(",") if (case, seed, args.seconds) not in done]
    rows = []
    with multiprocessing.Pool(args.jobs) as pool:
        for row in pool.imap_unordered(_job, tasks):
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.out:
                with args.out.open("a") as f:
                    f.write(json.dumps(row) + "\n")
    print(table(rows))


if __name__ == "__main__":
    main()
