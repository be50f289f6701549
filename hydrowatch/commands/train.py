"""``hydrowatch train``: fit a health model (parity or the study's entropy method); track in MLflow.

Prints one JSON summary per trained bundle (version, method, states, NRMSE per sensor for the
entropy method, test accuracy, per-class recall, MLflow run id, registered model URI and the address
of the runs table in MLflow's UI, and with ``--check-seconds`` the accuracy on other commands).
``--method both`` trains ``OUT/entropy`` and ``OUT/parity`` as two runs to compare. The JSON goes out
with ``--json`` or when stdout is not a terminal; on a terminal a short summary per bundle
(:mod:`hydrowatch.report.console`). The work is :func:`hydrowatch.training.pipeline.train_each`.
``--rig NAME|FILE`` trains the cycles method on a rig's data folder instead
(:func:`hydrowatch.training.rig_pipeline.train_rig_and_track`, docs/rigs.md).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hydrowatch.training.options import (
    add_tracking_arguments,
    add_training_arguments,
    settings_list_from_args,
    tracking_names,
)

NAME = "train"
HELP = "train the health model (parity, entropy or both) from labelled recordings; log to MLflow and register it"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--data DIR --out MODEL_DIR`` plus training and MLflow flags."""
    parser.add_argument("--data", required=True, type=Path,
                        help="labelled recordings (folder or file); with --rig the rig's data folder")
    parser.add_argument("--rig", default=None, metavar="NAME|FILE",
                        help="train the cycles method (one verdict per component per cycle) on the cycles of this rig "
                             "description (a shipped name such as uci-hydraulic, or a .toml file); --data: a folder of "
                             "per-cycle files (wide layout), a CSV/Parquet table (long) or an MCAP file of "
                             "`import --rig`")
    parser.add_argument("--out", required=True, type=Path,
                        help="model bundle folder to write (--method both: OUT/entropy and OUT/parity)")
    parser.add_argument("--report", type=Path, default=None, help="also keep the plots and tables in this folder")
    parser.add_argument("--json", action="store_true",
                        help="one JSON summary per bundle (the default when stdout is not a terminal)")
    add_training_arguments(parser)
    add_tracking_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Train, save, log; print the summaries (JSON or for people); returns 0."""
    from hydrowatch.report.console import json_output, train_next, train_text
    from hydrowatch.training.pipeline import train_each

    as_json, tracking_uri, runs_url = json_output(args.json), "", None
    if args.rig is not None:
        return _train_rig(args, as_json)
    experiment, model_name = tracking_names(args)
    for summary in train_each(
        args.data, args.out, settings_list_from_args(args), report_dir=args.report, tracking=args.tracking_uri,
        experiment=experiment, model_name=model_name, alias=args.alias, check_seconds=args.check_seconds,
    ):
        print(json.dumps(summary) if as_json else train_text(summary), flush=True)
        tracking_uri, runs_url = summary["tracking_uri"], summary.get("runs_url")
    if not as_json:
        print(train_next(str(args.out), tracking_uri, runs_url))
    return 0


def _train_rig(args: argparse.Namespace, as_json: bool) -> int:
    """``--rig``: the cycles method on the rig's cycles (``--method`` left at its default or ``cycles``), registered
    as ``hydrowatch-<rig>`` and logged to that experiment unless ``--model-name``/``--experiment`` say otherwise
    (:func:`~hydrowatch.training.options.mlflow_name`)."""
    from hydrowatch.errors import ParameterError
    from hydrowatch.report.console import train_next
    from hydrowatch.training.options import DEFAULT_CLI_METHOD, settings_from_args
    from hydrowatch.training.rig_pipeline import train_rig_and_track

    if args.method not in (DEFAULT_CLI_METHOD, "cycles"):
        raise ParameterError(f"--rig trains the cycles method. Got --method {args.method}; leave --method out.")
    args.method = "cycles"
    _, summary = train_rig_and_track(
        args.rig, args.data, args.out, settings_from_args(args), tracking=args.tracking_uri,
        experiment=args.experiment, model_name=args.model_name, register=not args.no_register, alias=args.alias,
        report_dir=args.report)
    if as_json:
        print(json.dumps(summary), flush=True)
    else:
        figures = ", ".join(f"{c} {f['accuracy']:.1%} ({f['features']})" for c, f in summary["components"].items())
        print(f"trained {summary['version']} (cycles, rig {summary['rig']}); honest-split accuracy {figures}")
        print(train_next(str(args.out), summary["tracking_uri"], summary["runs_url"]))
    return 0
