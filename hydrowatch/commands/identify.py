"""``hydrowatch identify``: one reference model (Box-Jenkins or NARX) from a recording, with its validation."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.io import read_recording
from hydrowatch.recording import UNITS

NAME = "identify"
HELP = "identify one reference model (Box-Jenkins or NARX) from a recording and print it with its validation"


def _int_list(text: str, count: int, what: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != count or min(values) < 0:
        raise ParameterError(f"{what} must be {count} non-negative integers separated by commas. Got {text!r}.")
    return values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, required=True, help="recording (.mcap, .parquet or .csv)")
    parser.add_argument("--output", required=True, help="output column, e.g. speed, flow or torque")
    parser.add_argument("--input", default="voltage", help="input column (default: voltage)")
    parser.add_argument("--model", choices=("bj", "narx"), default="bj", help="model kind (default: bj)")
    parser.add_argument("--orders", help="Box-Jenkins NB,NF,NC,ND (default: from the GPAC tables)")
    parser.add_argument(
        "--delay", type=int, help="Box-Jenkins dead time K in samples (default: from the impulse response)"
    )
    parser.add_argument(
        "--auto", action="store_true", help="search the Box-Jenkins orders by the study's validation rules"
    )
    parser.add_argument("--taps", default="15,15", help="NARX input and output delay-line taps NU,NY (default: 15,15)")
    parser.add_argument("--hidden", type=int, default=35, help="NARX hidden neurons (default: 35)")
    parser.add_argument("--save", type=Path, help="also save the fitted model to this file")
    parser.add_argument("--json", action="store_true", help="print the contract's JSON object")


def _signals(args: argparse.Namespace) -> tuple[Any, Any]:
    # only the two columns are needed (a name that is no channel at all is refused just below)
    recording = read_recording(args.data, required=[c for c in (args.input, args.output) if c in UNITS])
    for role, column in (("input", args.input), ("output", args.output)):
        if column not in recording.channels:
            raise DataError(
                f"{role} column must be one of {', '.join(sorted(recording.channels))}. Got {column!r}.", str(args.data)
            )
    return recording[args.input], recording[args.output]


def _box_jenkins(args: argparse.Namespace, u: Any, y: Any) -> tuple[dict[str, Any], Any]:
    from hydrowatch.sysid import BoxJenkins, preliminary_identification, search_orders

    start: dict[str, Any] = {}
    if args.orders:
        start.update(zip(("nb", "nf", "nc", "nd"), _int_list(args.orders, 4, "--orders")))
    if args.delay is not None:
        if args.delay < 0:
            raise ParameterError(f"--delay must be a non-negative number of samples. Got {args.delay}.")
        start["delay"] = args.delay
    preliminary = None
    extra: dict[str, Any]
    if len(start) < 5:
        preliminary = preliminary_identification(u, y)
        start = {**preliminary.orders, "delay": preliminary.delay, **start}
    if args.auto:
        search = search_orders(u, y, start)
        model, extra = search.model, {"search": search.history}
    else:
        model, extra = BoxJenkins(**start).fit(u, y), {}

    document = model.to_dict()
    if preliminary is not None:
        extra["preliminary"] = {"orders": preliminary.orders, "delay": preliminary.delay}
    return {**document, **extra}, model


def _narx(args: argparse.Namespace, u: Any, y: Any) -> tuple[dict[str, Any], Any]:
    from hydrowatch.sysid.narx import NARX

    nu, ny = _int_list(args.taps, 2, "--taps")
    model = NARX(input_delays=nu, output_delays=ny, hidden=args.hidden).fit(u, y)
    summary = model.summary()
    checks = model.residual_correlations(u, y)
    validation = {k: checks[k] for k in ("bound", "acf_inside", "ccf_inside", "max_lag", "n")}
    document = {
        "model": "narx",
        "network": summary,
        "validation": validation,
        "nrmse_one_step": summary["nrmse_one_step"],
    }
    return document, model


def _text(document: dict[str, Any]) -> str:
    lines = [f"model {document['model']}  nrmse_one_step {document['nrmse_one_step']:.4g}"]
    if document["model"] == "bj":
        o = document["orders"]
        lines.append(f"orders nb={o['nb']} nf={o['nf']} nc={o['nc']} nd={o['nd']}  delay {document['delay']}")
        for name, p in document["parameters"].items():
            lo, hi = p["ci95"]
            interval = "undetermined" if lo is None or hi is None else f"[{lo:+.5g}, {hi:+.5g}]"
            lines.append(f"  {name:>4} {p['value']:+.5g}  95% {interval}")
        v = document["validation"]
        lines.append(
            f"Q {v['Q']:.4g} (dof {v['Q_dof']}, p {v['Q_p']:.3g})  S {v['S']:.4g} (dof {v['S_dof']}, p {v['S_p']:.3g})"
        )
        lines.append(f"stable {v['stable']}  cancellations {len(v['cancellations'])}")
    else:
        lines += [f"  {k}: {v}" for k, v in document["network"].items()]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    u, y = _signals(args)
    document, model = _box_jenkins(args, u, y) if args.model == "bj" else _narx(args, u, y)
    if args.save:
        model.save(args.save)
    print(json.dumps(document) if args.json else _text(document))
    return 0
