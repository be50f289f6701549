"""``hydrowatch demo``: the whole pipeline on one machine with embedded defaults (``make demo``).

``--rig NAME|FILE [--data FOLDER]``: the pipeline on a rig's recorded cycles instead
(:mod:`hydrowatch.training.rig_demo`: import, train the cycles method with MLflow, replay every cycle through the
registered model, ``<out>/report.html``).

Simulates identification data, trains a parity bundle and the study's method with Box-Jenkins and
NARX reference models (MLflow), measures accuracy on other seeds and commands, runs a live fleet
with faults appearing through recorder and scorer processes on a loopback bus with the live table,
and writes ``<out>/report.html``. Prints its summary as JSON with ``--json`` or when stdout is not a
terminal, and on a terminal a few lines: the fleet first, the models, where the files are. The
defaults finish in a few minutes on 2 cores; ``--full-plan`` and ``--narx 15,15,35`` give the
study's sizes.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from hydrowatch.training.options import add_training_arguments, settings_from_args

NAME = "demo"
HELP = "run the whole pipeline on embedded defaults and write an HTML report"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--out``, sizes, and the training flags (``--method``/``--reference`` are ignored: all three are trained)."""
    parser.add_argument("--out", type=Path, default=Path("demo"), help="output folder (default demo)")
    parser.add_argument("--tracking-uri", default=None, help="MLflow tracking URI (default sqlite:///<cwd>/mlruns/…)")
    parser.add_argument("--live-seconds", type=float, default=330.0,
                        help="simulated seconds of the live fleet (faults appear from 20 s to 60 s; the scorer pools "
                             "12 windows, so a changed machine is named within the minute after; m06's motor leak "
                             "wears slowly and is forecast once 300 s of its history are in)")
    parser.add_argument("--speed", type=float, default=10.0, help="live fleet: simulated seconds per second")
    parser.add_argument("--accuracy-seconds", type=float, default=60.0, help="seconds per state of the accuracy runs")
    parser.add_argument("--json", action="store_true",
                        help="print the summary as JSON (the default when stdout is not a terminal)")
    parser.add_argument("--rig", default=None, metavar="NAME|FILE",
                        help="run the pipeline on a rig's recorded cycles instead (e.g. uci-hydraulic): import, train "
                             "the cycles method (MLflow), replay every cycle through the registered model, report")
    parser.add_argument("--data", type=Path, default=None,
                        help="with --rig: the rig's data folder (default: the shared data folder of a shipped rig)")
    add_training_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Run the demo and print its summary (JSON or for people); returns 0."""
    from hydrowatch.report.console import demo_text, json_output
    from hydrowatch.training.demo import DemoSettings, run_demo

    if args.rig is not None:
        return _rig_demo(args, json_output(args.json))
    base = settings_from_args(args)
    settings = DemoSettings(
        out=args.out, training={"parity": replace(base, method="parity"),
                                "bj": replace(base, method="entropy", reference="bj"),
                                "narx": replace(base, method="entropy", reference="narx")},
        tracking=args.tracking_uri, seed=args.seed, accuracy_seconds=args.accuracy_seconds,
        live_seconds=args.live_seconds, speed=args.speed)
    summary = run_demo(settings, show=sys.stderr.isatty())
    print(json.dumps(summary, default=str) if json_output(args.json) else demo_text(summary))
    return 0


def _rig_demo(args: argparse.Namespace, as_json: bool) -> int:
    """``--rig``: :func:`hydrowatch.training.rig_demo.run_rig_demo`; prints its summary (JSON or a few lines)."""
    from hydrowatch.training.rig_demo import run_rig_demo

    summary = run_rig_demo(args.rig, args.out, data=args.data, tracking=args.tracking_uri)
    if as_json:
        print(json.dumps(summary))
        return 0
    print(f"rig {summary['rig']}: {summary['cycles']} cycles from {summary['data']}")
    for c, f in summary["honest"].items():
        replayed = summary["replay"][c]["accuracy"]
        print(f"  {c}: honest split {f['accuracy']:.1%} ({f['features']}), replay of all cycles on the bus "
              f"{'unlabelled' if replayed is None else f'{replayed:.1%}'}")
    print(f"registered {summary['model_uri']} (run {summary['run_id']}); next: open {summary['report']}")
    return 0
