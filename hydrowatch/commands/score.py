"""``hydrowatch score``: offline verdicts of recordings, window by window (contract: ``score --json``).

One JSON object per input file on stdout with ``--json`` or when stdout is not a terminal; on a
terminal a few lines per file (counts, accuracy, last verdict, forecast; :mod:`hydrowatch.report.console`).
The work is :func:`hydrowatch.training.scoring.score_recording`.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path
from typing import TYPE_CHECKING

from hydrowatch.training.options import DEFAULT_SCORING_EXPERIMENT

if TYPE_CHECKING:
    from hydrowatch.training.bundle import ModelBundle

NAME = "score"
HELP = "score recordings window by window with a model bundle (MODEL_DIR or models:/NAME@ALIAS)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--model``, ``--data``, ``--json``, ``--tracking-uri``, ``--log-run``, ``--experiment``, ``--smoothing``."""
    parser.add_argument("--model", required=True, help="model bundle folder or models:/NAME@ALIAS")
    parser.add_argument("--data", required=True, type=Path, help="recording file or folder of recordings")
    parser.add_argument("--json", action="store_true",
                        help="one JSON object per file (the contract's format; default when stdout is not a terminal)")
    parser.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for models:/ (default as train)")
    parser.add_argument("--log-run", action="store_true",
                        help="also log the scoring as an MLflow run (experiment --experiment, at --tracking-uri): each "
                             "file's window counts, accuracy, forecast per part, and the degradation index per part "
                             "over the windows (one curve each)")
    parser.add_argument("--experiment", default=DEFAULT_SCORING_EXPERIMENT,
                        help=f"with --log-run: MLflow experiment (default {DEFAULT_SCORING_EXPERIMENT})")
    parser.add_argument("--smoothing", type=int, default=None, metavar="N",
                        help="parity bundles: pool each verdict's evidence over the machine's last N valid windows "
                             "(default 12: what spread severities and the open set need on working commands; "
                             "1: each window alone). Entropy bundles: 1 only")


def run(args: argparse.Namespace) -> int:
    """Score every file; returns 0."""
    from hydrowatch.io import read_recording
    from hydrowatch.report.console import SCORE_NEXT, json_output, score_text
    from hydrowatch.training import load_bundle, recording_files, score_recording
    from hydrowatch.training.scoring import scoring_metrics, smoothing_for

    bundle = load_bundle(args.model, args.tracking_uri)
    as_json = json_output(args.json)
    if bundle.method == "cycles":
        return _score_cycles(bundle, args, as_json)
    smoothing = smoothing_for(bundle, args.smoothing)
    files = recording_files(args.data)
    metrics: dict[str, float] = {}
    steps: list[tuple[str, float, int]] = []
    for path in files:
        result = score_recording(bundle, read_recording(path), smoothing)
        print(json.dumps(result) if as_json else score_text(result), flush=True)
        if args.log_run:  # one file: plain keys; several: each file's keys under its name
            found = scoring_metrics(result, "" if len(files) == 1 else f"{metric_name(Path(path).stem)}/")
            metrics.update(found[0])
            steps += found[1]
    if args.log_run:
        from hydrowatch.training.tracking import log_scoring

        logged = log_scoring(params={"model": args.model, "model_version": bundle.version, "method": bundle.method,
                                     "data": str(args.data), "files": len(files), "smoothing": smoothing},
                             metrics=metrics, steps=steps, tracking=args.tracking_uri, experiment=args.experiment,
                             run_name=f"score {Path(args.data).name}")
        if not as_json:
            print(f"logged MLflow run {logged['run_id']} ({logged['experiment']}, {logged['tracking_uri']})")
    if not as_json:
        print(f"model {bundle.version[:19]}… ({args.model}); {SCORE_NEXT}")
    return 0


def metric_name(text: str) -> str:
    """``text`` with every character MLflow refuses in a metric key (not alphanumeric, ``_-. /``) as ``_``."""
    return re.sub(r"[^A-Za-z0-9_\-. /]", "_", text)


def _score_cycles(bundle: ModelBundle, args: argparse.Namespace, as_json: bool) -> int:
    """A cycles bundle: the rig folder ``--data`` scored cycle by cycle, one JSON object (docs/formats.md); with
    ``--log-run`` an MLflow run with :func:`~hydrowatch.training.rig_pipeline.cycle_scoring_metrics`."""
    from hydrowatch.training.rig_pipeline import cycle_scoring_metrics, read_rig_folder, score_cycles

    result = score_cycles(bundle, read_rig_folder(bundle.health_method, args.data))  # type: ignore[arg-type]
    if args.log_run:
        from hydrowatch.training.tracking import log_scoring

        logged = log_scoring(params={"model": args.model, "model_version": bundle.version, "method": bundle.method,
                                     "data": str(args.data), "rig": result["rig"]},
                             metrics=cycle_scoring_metrics(result), steps=[], tracking=args.tracking_uri,
                             experiment=args.experiment, run_name=f"score {Path(args.data).name}")
        if not as_json:
            print(f"logged MLflow run {logged['run_id']} ({logged['experiment']}, {logged['tracking_uri']})")
    if as_json:
        print(json.dumps(result), flush=True)
        return 0
    summary = result["summary"]
    for c, counts in summary["counts"].items():
        right = summary["accuracy"][c]
        print(f"{c}: {counts}" + ("" if right is None else f", accuracy {right:.1%}"))
    print(f"{summary['cycles']} cycles of rig {result['rig']}; model {bundle.version}")
    return 0
