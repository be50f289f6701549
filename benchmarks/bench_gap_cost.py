"""Where one gap analysis spends its simulations (issue 12, item 5): one run of the population bench, counted.

Every model the analysis simulates (not one taken from its kept simulations, gap/simulations.py) is counted
in simulations of the whole record (a model simulated over the 14 s screening head counts 14/120) and its
process CPU time, both by the analysis step
that asked for it (the innermost of calibrate, screen, recalibrate, polish, settle, _absorb, prune,
identify on the call stack). Prints the bench's row (named, right, wall and CPU seconds, load) with
``sims`` (per step and ``total``), ``sim_cpu`` (CPU s per step) and ``sims_by_length``.

    HYDROWATCH_THREADS=2 python benchmarks/bench_gap_cost.py [CASE] [--seed 2035] [--unit 0] [-v] [--report OUT.json]

Without arguments it runs the slowest known case, the dev pair (gear_backlash+entrained_air, seed 2035).

CPU time is the process's (every simulation thread); on a shared machine say the load (the row has it).
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import time
import traceback
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_gap_population as bench  # noqa: E402

from hydrowatch.gap import align  # noqa: E402
from hydrowatch.log import configure  # noqa: E402
from hydrowatch.recording import SAMPLE_RATE_HZ  # noqa: E402

STEPS = ("calibrate", "screen", "recalibrate", "polish", "settle", "_absorb", "prune", "identify")
"""Analysis steps the simulations are counted by (the innermost on the call stack)."""


REFERENCE_CASE = "gear_backlash+entrained_air"
REFERENCE_SEED = 2035
"""The default run: the slowest known case, the dev population's backlash + air pair (docs/gap.md, item 5)."""


class Counter:
    """A stand-in for the simulation behind ``simulate_sensors`` that counts what each step simulates (records,
    CPU s): the models actually simulated, not those taken from the analysis's kept simulations
    (gap/simulations.py)."""

    def __init__(self) -> None:
        self.records: collections.Counter[str] = collections.Counter()
        self.by_length: collections.Counter[str] = collections.Counter()
        self.cpu: collections.Counter[str] = collections.Counter()
        self.original = align._simulate_models

    def __call__(self, aligned: align.AlignedRecording, parameters: Any, effects: Any, stop: int | None = None) -> Any:
        names = [frame.name for frame in traceback.extract_stack()]
        step = next((s for s in reversed(names) if s in STEPS), "other")
        samples = aligned.t.size if stop is None else stop
        records = samples * len(parameters) / (bench.SECONDS * SAMPLE_RATE_HZ)
        self.records[step] += records
        self.records["total"] += records
        self.by_length[f"{step}/{samples / SAMPLE_RATE_HZ:.0f} s"] += records
        start = time.process_time()
        out = self.original(aligned, parameters, effects, stop)
        self.cpu[step] += time.process_time() - start
        return out

    def install(self) -> None:
        """Put the counter in place of the simulation that ``simulate_sensors`` calls."""
        align._simulate_models = self  # type: ignore[assignment]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", nargs="?", default=REFERENCE_CASE, help=f"one of {', '.join(bench.CASES)}")
    parser.add_argument("--seed", "--population", dest="population", type=int, default=REFERENCE_SEED)
    parser.add_argument("--unit", type=int, default=0)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="log the analysis' steps to stderr")
    parser.add_argument("--report", type=Path, help="write the analysis' whole report (JSON) here, to compare two "
                        "versions of the code field by field (a change meant to save time must leave it equal)")
    args = parser.parse_args()
    configure(args.verbose)
    counter = Counter()
    counter.install()
    row = bench.one_run(args.case, args.population, args.unit, args.report)
    row["sims"] = {k: round(v) for k, v in counter.records.most_common()}
    row["sim_cpu"] = {k: round(v, 1) for k, v in counter.cpu.most_common()}
    row["sims_by_length"] = {k: round(v) for k, v in counter.by_length.most_common()}
    print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
