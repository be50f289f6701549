"""``hydrowatch train``: fit reference models, base distributions and the classifier; track in MLflow.

Prints a JSON summary (version, states, NRMSE per sensor, test accuracy, per-class recall, MLflow
run id and registered model URI). The work is :func:`hydrowatch.training.pipeline.train_and_track`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hydrowatch.training.options import add_tracking_arguments, add_training_arguments, settings_from_args

NAME = "train"
HELP = "train reference models + health model from labelled recordings; log to MLflow and register the bundle"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--data DIR --out MODEL_DIR`` plus training and MLflow flags."""
    parser.add_argument("--data", required=True, type=Path, help="labelled recordings (folder or file)")
    parser.add_argument("--out", required=True, type=Path, help="model bundle folder to write")
    parser.add_argument("--report", type=Path, default=None, help="also keep the plots and tables in this folder")
    add_training_arguments(parser)
    add_tracking_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Train, save, log; print the JSON summary; returns 0."""
    from hydrowatch.training.pipeline import train_and_track

    _, summary = train_and_track(
        args.data, args.out, settings_from_args(args), tracking=args.tracking_uri, experiment=args.experiment,
        model_name=None if args.no_register else args.model_name, alias=args.alias, report_dir=args.report,
    )
    print(json.dumps(summary))
    return 0
