"""``hydrowatch score``: offline verdicts of recordings, window by window (contract: ``score --json``).

One JSON object per input file on stdout with ``--json`` or when stdout is not a terminal; on a
terminal a few lines per file (counts, accuracy, last verdict, forecast; :mod:`hydrowatch.report.console`).
The work is :func:`hydrowatch.training.scoring.score_recording`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

NAME = "score"
HELP = "score recordings window by window with a model bundle (MODEL_DIR or models:/NAME@ALIAS)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--model``, ``--data``, ``--json``, ``--tracking-uri``, ``--smoothing``."""
    parser.add_argument("--model", required=True, help="model bundle folder or models:/NAME@ALIAS")
    parser.add_argument("--data", required=True, type=Path, help="recording file or folder of recordings")
    parser.add_argument("--json", action="store_true",
                        help="one JSON object per file (the contract's format; default when stdout is not a terminal)")
    parser.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for models:/ (default as train)")
    parser.add_argument("--smoothing", type=int, default=None, metavar="N",
                        help="parity bundles: pool each verdict's evidence over the machine's last N valid windows "
                             "(default 12: what spread severities and the open set need on working commands; "
                             "1: each window alone). Entropy bundles: 1 only")


def run(args: argparse.Namespace) -> int:
    """Score every file; returns 0."""
    from hydrowatch.io import read_recording
    from hydrowatch.report.console import SCORE_NEXT, json_output, score_text
    from hydrowatch.training import load_bundle, recording_files, score_recording
    from hydrowatch.training.scoring import smoothing_for

    bundle = load_bundle(args.model, args.tracking_uri)
    smoothing = smoothing_for(bundle, args.smoothing)
    as_json = json_output(args.json)
    for path in recording_files(args.data):
        result = score_recording(bundle, read_recording(path), smoothing)
        print(json.dumps(result) if as_json else score_text(result), flush=True)
    if not as_json:
        print(f"model {bundle.version[:19]}… ({args.model}); {SCORE_NEXT}")
    return 0
