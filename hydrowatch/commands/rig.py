"""``hydrowatch rig RIG [--data PATH] [--json]``: check a rig description and, with data, import it."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from hydrowatch.io.rig_cycles import read_rig_data
from hydrowatch.io.wide import Cycles
from hydrowatch.rig import BUILTIN, RigDescription
from hydrowatch.rig.plant import any_rig

NAME = "rig"
HELP = "check a rig description (a .toml file, 'plant' or a shipped name) and, with --data, import and count its data"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("rig", help=f"a rig description .toml file, 'plant', or one of {', '.join(BUILTIN)}")
    parser.add_argument(
        "--data", type=Path, help="the rig's data: a folder of per-cycle files (wide) or a CSV/Parquet table (long)"
    )
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def summary(rig: RigDescription, data: Cycles | None) -> dict[str, Any]:
    """What the description declares and, when read, how many cycles or windows each label has."""
    out: dict[str, Any] = {
        "rig": rig.name,
        "layout": rig.layout,
        "window": {
            "kind": rig.window.kind,
            "length_s": rig.window.length_s,
            "hop_s": rig.window.hop_s,
            "grid_hz": rig.window.grid_hz,
        },
        "channels": {
            c.name: {
                "unit": c.unit,
                "role": c.role,
                "rate_hz": rig.sampling[c.name].rate_hz,
                "source": rig.sampling[c.name].source,
            }
            for c in rig.channels
        },
        "components": {
            label.name: {"values": list(label.values), "healthy": label.healthy}
            for label in rig.labels
            if label.component
        },
    }
    if data is not None:
        out["data"] = {
            "source": data.source,
            "windows": len(data),
            "channels": list(data.channels),
            "counts": {
                name: {str(v): int(n) for v, n in zip(*np.unique(column, return_counts=True), strict=True)}
                for name, column in data.labels.items()
            },
        }
    return out


def _lines(s: dict[str, Any]) -> str:
    w = s["window"]
    lines = [
        f"rig {s['rig']}: {s['layout']} layout, {w['kind']} windows of {w['length_s']:g} s every "
        f"{w['hop_s']:g} s on a {w['grid_hz']:g} Hz grid; {len(s['channels'])} channels"
    ]
    lines += [
        f"  {n}: {c['unit']}, {c['role']}, {c['rate_hz']:g} Hz from {c['source']}" for n, c in s["channels"].items()
    ]
    lines += [f"  {n}: {c['values']} (healthy {c['healthy']})" for n, c in s["components"].items()]
    if "data" in s:
        d = s["data"]
        lines.append(f"read {d['source']}: {d['windows']} windows of {len(d['channels'])} channels")
        lines += [f"  {n}: {counts}" for n, counts in d["counts"].items()]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    rig = any_rig(args.rig)
    data = None
    if args.data is not None:
        data = read_rig_data(args.data, rig)
    s = summary(rig, data)
    print(json.dumps(s, ensure_ascii=False) if args.json else _lines(s))
    return 0
