"""``hydrowatch score``: offline verdicts of recordings, window by window (contract: ``score --json``).

One JSON object per input file on stdout with ``--json``; otherwise one line per file (counts and
accuracy). The work is :func:`hydrowatch.training.scoring.score_recording`.
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
    parser.add_argument("--json", action="store_true", help="one JSON object per file (the contract's format)")
    parser.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for models:/ (default as train)")
    parser.add_argument("--smoothing", type=int, default=None, metavar="N",
                        help="parity bundles: pool each verdict's evidence over the machine's last N valid windows "
                             "(default 12: what spread severities and the open set need on working commands; "
                             "1: each window alone). Entropy bundles: 1 only")


def run(args: argparse.Namespace) -> int:
    """Score every file; returns 0."""
    from hydrowatch.io import read_recording
    from hydrowatch.training import load_bundle, recording_files, score_recording
    from hydrowatch.training.scoring import smoothing_for

    bundle = load_bundle(args.model, args.tracking_uri)
    smoothing = smoothing_for(bundle, args.smoothing)
    for path in recording_files(args.data):
        result = score_recording(bundle, read_recording(path), smoothing)
        if args.json:
            print(json.dumps(result), flush=True)
        else:
            s = result["summary"]
            accuracy = "" if s["accuracy"] is None else f" accuracy={s['accuracy']:.4f}"
            counts = " ".join(f"{k}={v}" for k, v in sorted(s["counts"].items()))
            print(f"{path}: windows={s['windows']} {counts}{accuracy}", flush=True)
    return 0
