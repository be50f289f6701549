"""``hydrowatch gap``: sim-to-real mismatch analysis of one recording (contract.md).

Writes the report to ``--report``; prints it as JSON too with ``--json`` or when stdout is not a
terminal, and on a terminal a short summary (:mod:`hydrowatch.report.console`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hydrowatch.errors import ParameterError
from hydrowatch.plant.effects import EFFECT_IDS

NAME = "gap"
HELP = "sim-to-real mismatch analysis: calibrate, locate, name missing physics, save the augmented model"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--real", type=Path, required=True, help="recording (MCAP, Parquet or CSV)")
    parser.add_argument("--nominal", type=Path,
                        help="nominal plant parameters, JSON: a parameters object or a model saved by --save-model "
                             "(default: built-in nominal)")
    parser.add_argument("--report", type=Path, required=True, help="where to write the JSON report")
    parser.add_argument("--html", type=Path, help="also write an HTML report with plots")
    parser.add_argument("--save-model", type=Path, help="write the augmented model (parameters + effects), JSON")
    parser.add_argument("--json", action="store_true",
                        help="also print the report as JSON (the default when stdout is not a terminal)")
    parser.add_argument("--effects", help=f"comma-separated candidate effects to try (default: all of {EFFECT_IDS})")


def run(args: argparse.Namespace) -> int:
    from hydrowatch.gap import GapAnalyser, read_model
    from hydrowatch.io import read_recording
    from hydrowatch.report.console import gap_text, json_output

    nominal, effects = (None, None) if args.nominal is None else read_model(args.nominal)
    candidates = None
    if args.effects:
        candidates = tuple(e.strip() for e in args.effects.split(",") if e.strip())
        if not candidates:
            raise ParameterError(f"--effects must name at least one effect. Got '{args.effects}'.")
    recording = read_recording(args.real)
    recording.meta.setdefault("source", str(args.real))
    analyser = GapAnalyser(nominal=nominal, effects=effects, candidates=candidates).fit(recording)
    args.report.write_text(json.dumps(analyser.report_, indent=2) + "\n", encoding="utf-8")
    written = [str(args.report)]
    if args.save_model is not None:
        written.append(str(args.save_model))
        args.save_model.write_text(json.dumps(analyser.model_, indent=2) + "\n", encoding="utf-8")
    if args.html is not None:
        from hydrowatch.gap.html import write_html

        write_html(analyser, args.html)
        written.append(str(args.html))
    if json_output(args.json):
        print(json.dumps(analyser.report_))
    else:
        print(gap_text(analyser.report_, str(args.real), written))
    return 0
