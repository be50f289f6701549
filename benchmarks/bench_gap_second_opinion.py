"""How often the sparse-regression second opinion agrees with the effect the gap analyser names (issue 6).

The recordings are those of bench_gap.py (same effect magnitudes, plant spread, noise and command
per seed). By default each run calibrates and asks the second opinion (second_opinion.py) about the
concealed effect on the calibrated residual: that is exactly the opinion the report gives on the
first named effect, and it does not depend on the diagnosis (bench_gap.py names the concealed effect
first in 10/10 runs of every case). ``--full`` runs the whole analysis instead and reads the verdicts
of the named effects from the report (the concealed effect's verdict when it was named, else none).

    python benchmarks/bench_gap_second_opinion.py --seeds 3 --seconds 24 --out so.jsonl   # resumable
    python benchmarks/bench_gap_second_opinion.py --table so.jsonl

Prints the CPU time per run (process time; the table's "CPU s" is the whole analysis with ``--full``,
else the second opinion alone) next to the wall time and the load average: the machine is shared,
so wall times are pessimistic. The "none" row counts runs that named anything.
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

from bench_gap import MAGNITUDES, draw_effect, excitation, plant  # noqa: E402

from hydrowatch.gap import GapAnalyser  # noqa: E402
from hydrowatch.gap.align import align  # noqa: E402
from hydrowatch.gap.calibrate import calibrate  # noqa: E402
from hydrowatch.gap.diagnose import residual_is_white  # noqa: E402
from hydrowatch.gap.second_opinion import second_opinion  # noqa: E402
from hydrowatch.plant.excitation import filtered_noise  # noqa: E402
from hydrowatch.plant.parameters import PlantParameters  # noqa: E402
from hydrowatch.plant.simulator import simulate  # noqa: E402

VERDICT_KEYS = ("agrees", "specific", "supporting", "share", "rank", "implicated")


def one_run(case: str, seed: int, seconds: float, full: bool) -> dict:
    """One recording of bench_gap.py's design, judged by the second opinion."""
    rng = np.random.default_rng(seed)
    ids = () if case == "none" else tuple(case.split("+"))
    effects = {e: draw_effect(e, rng) for e in ids}
    volts = excitation(ids)
    rec = simulate(filtered_noise(seconds, volts, seed=seed), plant(rng), effects, seed=seed)
    row: dict = {"case": case, "seed": seed, "seconds": seconds, "full": full, "volts": list(volts)}
    wall, cpu = time.perf_counter(), time.process_time()
    if full:
        report = GapAnalyser().fit(rec).report_
        row["named"] = [e["id"] for e in report["effects"]]
        row["verdicts"] = {e["id"]: {k: e["second_opinion"][k] for k in VERDICT_KEYS}
                           for e in report["effects"] if "second_opinion" in e}
        row["opinion"] = report["second_opinion"]
    else:
        aligned = align(rec)
        fit = calibrate(aligned, PlantParameters())
        row["white"] = residual_is_white(aligned, fit.prediction)
        cpu_so = time.process_time()
        opinion = second_opinion(aligned, fit.prediction, pump_speed=PlantParameters().omega_p)
        row["cpu_second_opinion"] = round(time.process_time() - cpu_so, 3)
        row["opinion"] = opinion.as_dict()
        row["verdicts"] = {e: {k: opinion.verdict(e)[k] for k in VERDICT_KEYS} for e in ids}
    row["wall"] = round(time.perf_counter() - wall, 1)
    row["cpu"] = round(time.process_time() - cpu, 1)
    row["load"] = round(os.getloadavg()[0], 2)
    return row


def table(rows: list[dict]) -> str:
    """Markdown: per case, how often the second opinion agrees with the concealed effect."""
    groups: dict[tuple[str, float, bool], list[dict]] = {}
    for row in rows:
        groups.setdefault((row["case"], row["seconds"], row["full"]), []).append(row)
    lines = ["| case | s | runs | named first | agrees | specific term | ranked first | supporting terms (most often) "
             "| other effects implicated | CPU s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for (case, seconds, full), runs in sorted(groups.items()):
        volts = {tuple(r.get("volts", (-4.0, 4.0) if case == "gear_backlash" else (0.0, 4.0))) for r in runs}
        label = case + "".join(f", {lo:g}…{hi:g} V" for lo, hi in sorted(volts))
        label += "" if full else " (calibrated only)"
        cpu = np.mean([r["cpu"] if full else r["cpu_second_opinion"] for r in runs])
        if case == "none":
            named = sum(bool(r.get("named")) for r in runs)
            white = sum(bool(r.get("white", not r.get("named"))) for r in runs)
            implicated = sorted({e for r in runs for e in (r["opinion"] or {}).get("implicated", [])})
            lines.append(f"| {label} | {seconds:g} | {len(runs)} | {named}/{len(runs)} | – (calibrated residual white: "
                         f"{white}/{len(runs)}) | – | – | – | "
                         f"{', '.join(implicated) or 'none'} "
                         f"| {cpu:.2f} |")
            continue
        ids = case.split("+")
        v = [r["verdicts"].get(ids[0]) for r in runs]
        agree = sum(bool(x and x["agrees"]) for x in v)
        specific = sum(bool(x and x["specific"]) for x in v)
        first = sum(bool(x and x["rank"] == 1) for x in v)
        terms: dict[str, int] = {}
        others: dict[str, int] = {}
        for x in v:
            for item in (x or {}).get("supporting", []):
                term = item.split(": ", 1)[1]
                terms[term] = terms.get(term, 0) + 1
            for e in (x or {}).get("implicated", []):
                if e not in ids:
                    others[e] = others.get(e, 0) + 1
        top = ", ".join(f"{t} ({n})".replace("|", "\\|") for t, n in sorted(terms.items(), key=lambda kv: -kv[1])[:3])
        top = top or "–"
        rest = ", ".join(f"{e} ({n})" for e, n in sorted(others.items(), key=lambda kv: -kv[1])[:3]) or "none"
        first_named = f"{sum(bool(r['named']) and r['named'][0] == ids[0] for r in runs)}/{len(runs)}" if full else "–"
        n = len(runs)
        lines.append(f"| {label} | {seconds:g} | {n} | {first_named} | {agree}/{n} | {specific}/{n} | {first}/{n} "
                     f"| {top} | {rest} | {cpu:.2f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--effects", default=",".join(["none", *MAGNITUDES]),
                        help="comma-separated cases: 'none', effect ids, or pairs 'a+b'")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=24.0)
    parser.add_argument("--full", action="store_true", help="run the whole analysis (slow)")
    parser.add_argument("--out", type=Path, help="append one JSON line per run; runs already there are skipped")
    parser.add_argument("--table", type=Path, help="print the table of a --out file and exit")
    args = parser.parse_args()
    if args.table is not None:
        print(table([json.loads(line) for line in args.table.read_text().splitlines() if line.strip()]))
        return
    done = set()
    if args.out is not None and args.out.exists():
        done = {(r["case"], r["seed"], r["seconds"], r["full"])
                for r in map(json.loads, args.out.read_text().splitlines()) if r}
    rows = []
    for case in args.effects.split(","):
        for seed in range(args.seeds):
            if (case, seed, args.seconds, args.full) in done:
                continue
            row = one_run(case, seed, args.seconds, args.full)
            rows.append(row)
            print(json.dumps({k: row[k] for k in ("case", "seed", "wall", "cpu", "load")}
                             | {"verdicts": {e: v["agrees"] for e, v in row["verdicts"].items()}}), flush=True)
            if args.out is not None:
                with args.out.open("a") as f:
                    f.write(json.dumps(row) + "\n")
    print(table(rows))


if __name__ == "__main__":
    main()
