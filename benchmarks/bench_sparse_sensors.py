"""Accuracy per window on every subset of the sensors, per method, through the command line (issue 13 item 4).

For the study's 7 states and all 13, for every non-empty subset of {flow, speed, torque} and every method
(``parity``, ``entropy`` = the study's method with Box-Jenkins reference models unless ``--reference narx``,
``stats`` = the per-window statistics baseline), the whole path a user takes:

1. ``hydrowatch simulate --format parquet``: one recording per state with every channel, for training
   (filtered noise 0–4 V, seed ``--seed``) and for two tests on **other recordings**:
   ``other seed`` (filtered noise 0–4 V, seed + 1) and ``later day, duty cycle`` (the unit's leakages,
   load and damping drifted ±3–5 % by :func:`hydrowatch.plant.population.later_day`, as
   ``bench_unseen_units.py``'s later day; holds, ramps and steps over 0.5–3.5 V,
   :func:`~hydrowatch.plant.excitation.duty_cycle`, seed + 2);
2. each file stripped to ``t``, ``voltage``, the subset and ``state``, written as CSV (a rig's export);
3. ``hydrowatch import`` of every CSV into MCAP;
4. ``hydrowatch train --method M`` on the subset's training MCAPs (MLflow in a scratch folder, not registered);
5. ``hydrowatch score --json --smoothing 1`` on each test folder: accuracy = share of the judged windows (invalid
   ones left out) whose verdict is the file's state, pooled over the states' files (``unknown`` counts as wrong;
   where ≥ 10 % of a cell's windows read ``unknown``, a line under the table says so).

A method that cannot use a subset says so at ``train`` (one line, exit 2): the cell shows ``refused: <reason>``.
The commands run in this process (``hydrowatch.cli.main``, the same argument parsing, files and outputs as the
shell, without starting Python 150 times).

Run: ``python benchmarks/bench_sparse_sensors.py [--quick] [--states 7|13|both] [--methods parity,entropy,stats]
[--json OUT] [--keep DIR]``. ``--quick``: 180 s per state to train (the entropy method's data plan needs 178.5 s),
60 s per state and test; the default is 300 s and 150 s.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
from threadpoolctl import threadpool_limits

from hydrowatch.cli import main as hydrowatch
from hydrowatch.plant.excitation import duty_cycle
from hydrowatch.plant.faults import EXTENDED_STATES, STUDY_STATES
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.population import later_day
from hydrowatch.recording import INPUT, SENSORS
from hydrowatch.training.scoring import pooled_accuracy

METHODS = ("parity", "entropy", "stats")
SUBSETS: tuple[tuple[str, ...], ...] = tuple(c for k in (1, 2, 3) for c in itertools.combinations(SENSORS, k))
"""Every non-empty subset of the sensors, the single sensors first."""
TESTS = ("other seed", "later day, duty cycle")


def cli(*argv: object) -> tuple[int, str, str]:
    """``hydrowatch ARGV`` in this process: exit code, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = hydrowatch([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def checked(*argv: object) -> str:
    """stdout of a command that must succeed."""
    code, out, err = cli(*argv)
    if code != 0:
        raise RuntimeError(f"hydrowatch {' '.join(map(str, argv))} failed ({code}): {err.strip()}")
    return out


def simulate(folder: Path, states: tuple[str, ...], seconds: float, seed: int, later: bool) -> Path:
    """``hydrowatch simulate`` of every state into ``folder`` (Parquet, every channel): filtered noise 0–4 V, or the
    later day's unit on a duty cycle."""
    argv: list[object] = ["simulate", "--out", folder, "--states", ",".join(states), "--seconds", seconds,
                          "--seed", seed, "--format", "parquet"]
    if later:
        nominal, command = folder.parent / f"{folder.name}-nominal.json", folder.parent / f"{folder.name}-u.csv"
        day = later_day(PlantParameters(), np.random.default_rng(seed))
        nominal.write_text(json.dumps(day.to_dict()))
        u = duty_cycle(seconds, (0.5, 3.5), seed=seed)
        command.write_text("t,voltage\n" + "\n".join(f"{i / 200.0:.3f},{v!r}" for i, v in enumerate(u.tolist())))
        argv += ["--nominal", nominal, "--command", command]
    checked(*argv)
    return folder


def sparse_copy(full: Path, folder: Path, sensors: tuple[str, ...]) -> Path:
    """Every recording of ``full`` as a CSV of ``t``, the command, ``sensors`` and ``state`` only, imported into
    MCAP in ``folder`` (``hydrowatch import``)."""
    folder.mkdir(parents=True)
    for path in sorted(full.glob("*.parquet")):
        table = pq.read_table(path, columns=["t", INPUT, *sensors, "state"])
        csv = folder / f"{path.stem}.csv"
        pa_csv.write_csv(table.replace_schema_metadata(None), csv)
        checked("import", csv, "--out", folder / f"{path.stem}.mcap")
        csv.unlink()
    return folder


def train(data: Path, out: Path, method: str, reference: str, tracking: str) -> str | None:
    """``hydrowatch train``; None when it trained, else ``refused: <reason>`` (the command's one-line error)."""
    code, _, err = cli("train", "--data", data, "--out", out, "--method", method, "--reference", reference,
                       "--tracking-uri", tracking, "--no-register", "--json")
    if code == 0:
        return None
    return "refused: " + err.strip().splitlines()[-1].split("error: ", 1)[-1]


def accuracy(model: Path, data: Path) -> tuple[float | None, float]:
    """``hydrowatch score --json --smoothing 1``: accuracy over every judged window of the folder's files, and the
    share of them read ``unknown`` (the open-set rule), %."""
    results = [json.loads(line) for line in checked("score", "--model", model, "--data", data, "--json",
                                                    "--smoothing", "1").splitlines() if line.startswith("{")]
    got, _, verdicts = pooled_accuracy(results)
    unknown = 100.0 * float(np.mean(np.asarray(verdicts) == "unknown")) if verdicts else 0.0
    return (None if got is None else 100.0 * got), unknown


def run(states: tuple[str, ...], methods: list[str], args: argparse.Namespace, root: Path) -> dict[str, object]:
    """The table of one state set; returns its cells."""
    train_s, test_s = (180.0, 60.0) if args.quick else (args.train_seconds, args.test_seconds)
    k = len(states)
    t0 = time.time()
    full = {"train": simulate(root / f"{k}-train", states, train_s, args.seed, later=False),
            "other seed": simulate(root / f"{k}-other-seed", states, test_s, args.seed + 1, later=False),
            "later day, duty cycle": simulate(root / f"{k}-later-day", states, 2 * test_s, args.seed + 2,
                                              later=True)}
    tracking = f"sqlite:///{root / 'mlflow.db'}"
    print(f"\n## {k} states: train {train_s:.0f} s per state (seed {args.seed}), test {test_s:.0f} s (other seed) "
          f"and {2 * test_s:.0f} s (later day, duty cycle) per state; % of judged windows right, per window",
          flush=True)
    print("| sensors | " + " | ".join(f"{m}, {t}" for m in methods for t in TESTS) + " |")
    print("|---|" + "---|" * (len(methods) * len(TESTS)), flush=True)
    cells: dict[str, object] = {}
    unknown: list[str] = []
    for sensors in SUBSETS:
        name = "+".join(sensors)
        data = {part: sparse_copy(path, root / f"{k}-{name}" / part.replace(" ", "-").replace(",", ""), sensors)
                for part, path in full.items()}
        row = []
        for method in methods:
            model = root / f"{k}-{name}" / f"model-{method}"
            refused = train(data["train"], model, method, args.reference, tracking)
            for test in TESTS:
                if refused is not None:
                    cell: object = refused
                    row.append(refused)
                else:
                    cell, rejected = accuracy(model, data[test])
                    row.append("–" if cell is None else f"{cell:.1f}")
                    if rejected >= 10.0:
                        unknown.append(f"{method} on {name}, {test}: {rejected:.0f}")
                cells[f"{name}|{method}|{test}"] = cell
        print(f"| {name} | " + " | ".join(row) + " |", flush=True)
    if unknown:
        print(f"Read `unknown` (the open-set rule; % of judged windows, where ≥ 10): {'; '.join(unknown)}.")
    print(f"({k} states: {time.time() - t0:.0f} s)", flush=True)
    return cells


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="180 s per state to train, 60 s per test")
    ap.add_argument("--train-seconds", type=float, default=300.0)
    ap.add_argument("--test-seconds", type=float, default=150.0)
    ap.add_argument("--states", choices=("7", "13", "both"), default="both")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated, of " + ",".join(METHODS))
    ap.add_argument("--reference", choices=("bj", "narx"), default="bj", help="the entropy method's reference models")
    ap.add_argument("--seed", type=int, default=2031, help="training data seed (the tests use seed + 1, + 2)")
    ap.add_argument("--json", default=None, help="write the cells here")
    ap.add_argument("--keep", type=Path, default=None, help="work in this folder and keep the files")
    args = ap.parse_args()
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        ap.error(f"--methods must be among {list(METHODS)}. Got unknown {unknown}.")
    sets = {"7": (STUDY_STATES,), "13": (EXTENDED_STATES,), "both": (STUDY_STATES, EXTENDED_STATES)}[args.states]
    with (contextlib.nullcontext(str(args.keep)) if args.keep else tempfile.TemporaryDirectory()) as folder, \
            threadpool_limits(1):  # a shared 2-core machine: one BLAS thread, as the other benchmarks
        root = Path(folder)
        root.mkdir(parents=True, exist_ok=True)
        figures = {f"{len(s)} states": run(tuple(s), methods, args, root) for s in sets}
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
