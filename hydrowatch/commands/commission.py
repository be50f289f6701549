"""``hydrowatch commission``: adapt a fleet model to one machine from its healthy operation (contract: commission).

Writes the machine's bundle to ``--out`` (``score --model OUT`` and the scorer's
``--commissioning FOLDER`` read it). A recording that cannot commission the unit is refused with
the reason, nothing is written and the machine keeps the fleet model. The work is
:func:`hydrowatch.training.commissioning.commission_bundle`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

NAME = "commission"
HELP = "adapt a trained parity model to one machine from >= 5 min of its healthy operation on any working command"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--model``, ``--data``, ``--machine``, ``--out``, ``--json``, ``--tracking-uri``, ``--register``."""
    parser.add_argument("--model", required=True, help="fleet model bundle folder or models:/NAME@ALIAS")
    parser.add_argument("--data", required=True, type=Path, help="the machine's healthy recording(s): a file or folder")
    parser.add_argument("--machine", required=True, help="the machine's id (as in its plant messages)")
    parser.add_argument("--out", required=True, type=Path, help="where to write the machine's bundle (a folder)")
    parser.add_argument("--json", action="store_true", help="print the commissioning as one JSON object")
    parser.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for models:/ (default as train)")
    parser.add_argument("--register", default=None, metavar="NAME",
                        help="also log the commissioning to MLflow and register it as NAME (alias champion), e.g. "
                             "hydrowatch-m7 for the scorer's --commissioning models:/hydrowatch-{machine}@champion")


def run(args: argparse.Namespace) -> int:
    """Commission and save; returns 0 (a refusal raises CommissioningError: exit 2 with the reason)."""
    from hydrowatch.io import read_recording
    from hydrowatch.training import load_bundle, recording_files
    from hydrowatch.training.commissioning import commission_bundle

    fleet = load_bundle(args.model, args.tracking_uri)
    recordings = []
    for path in recording_files(args.data):
        rec = read_recording(path)
        rec.meta.setdefault("source", str(path))
        recordings.append(rec)
    bundle = commission_bundle(fleet, recordings, args.machine)
    bundle.save(args.out)
    info = {"machine": args.machine, "out": str(args.out), "version": bundle.version, **bundle.manifest["commissioned"]}
    if args.register:
        from hydrowatch.training.commissioning import REGISTRY_ALIAS
        from hydrowatch.training.tracking import log_training

        unit = info["unit"]
        logged = log_training(params={"machine": args.machine, "base_version": info["base_version"],
                                      "sources": ",".join(info["sources"])},
                              metrics={"seconds": unit["seconds"], "healthy_share": unit["healthy_share"]},
                              bundle=bundle, bundle_dir=args.out, tracking=args.tracking_uri,
                              experiment="hydrowatch-commissioning",
                              run_name=f"commission {args.machine}", model_name=args.register, alias=REGISTRY_ALIAS,
                              tags={"machine": args.machine, "kind": "commissioning"})
        info["model_uri"], info["run_id"] = logged["model_uri"], logged["run_id"]
    if args.json:
        print(json.dumps(info))
    else:
        print("\n".join(summary_lines(info)))
    return 0


def summary_lines(info: dict[str, Any]) -> list[str]:
    """What ``commission`` says to a person about the commissioning ``info`` (its ``--json`` object), a line each:
    the unit, and what the recording left undetermined with what to record to determine it."""
    from hydrowatch.condition.commission import CAPACITY_MARGIN, relief_open
    from hydrowatch.condition.unit_checks import PUMP_LIMIT_SHARE, relief_barely_seen

    said: list[str] = []
    unit = info["unit"]
    said.append(f"{info['machine']}: commissioned from {info['base_version']} on {unit['seconds']:.0f} s "
                f"(healthy {100 * unit['healthy_share']:.0f} % of its own windows; supply {unit['supply']}) "
                f"-> {info['out']} ({info['version']})")
    if relief_open(unit["supply"], unit["split_disagreement"]):
        said.append("  the recording does not determine the relief (its halves disagree): the load states follow each "
                    "window's relief, and a worn relief spring may read as a weak valve coil on this unit; to "
                    "tell them apart, commission on 5 minutes of filtered noise over the command range (the "
                    "identification command of `hydrowatch simulate`)")
    at_limit = unit.get("pump_at_limit_share")
    if at_limit is not None and at_limit < PUMP_LIMIT_SHARE and "Dp" not in unit["left_to_prior"]:
        said.append(f"  the pump was at its limit in {100 * at_limit:.2f} % of the samples: the recording does not "
                    "determine its capacity (it trades with the relief's setting), and pump_leak levels rest on the "
                    "identified one; pump_leak has no degradation index until a worn pump's windows at its limit "
                    "determine it; a few seconds of steps to full stroke show it if the valve can then draw more than "
                    "the pump delivers (a pump that outdelivers the valve never shows it healthy)")
    if at_limit is not None and relief_barely_seen(at_limit):
        said.append(f"  the pump was at its limit (the relief shut) in {100 * at_limit:.0f} % of the samples: the "
                    "relief's gain is barely seen, and on this unit a weak relief spring may read as a weak valve "
                    "coil: neither has a degradation index in early wear (below 0.25), and until told apart their "
                    "forecasts share one index and name each other (untold_from); on simulated units a second "
                    "recording with the relief open did not determine the gain (docs/degradation.md, Limits)")
    if unit["supply"] == "identified" and unit.get("left_to_prior"):
        kept = ", ".join(unit["left_to_prior"])
        said.append(f"  not informed by the recording, kept near the trained unit's values: {kept}")
        if "Dp" in unit["left_to_prior"]:
            said.append("  the pump was never at its limit: its capacity is taken as at most "
                        f"{1 + CAPACITY_MARGIN:.2f} x what the recording drew from it; for pump_leak levels at higher "
                        "demand add a few seconds of steps to the top of the command range")
        if "omega_s" in unit["left_to_prior"]:
            said.append("  the recording never came near standstill: the brake's low-speed shape (omega_s) is the "
                        "trained unit's; a few seconds of commands near 0 V would identify it")
    return said
