"""``hydrowatch import FILE --out FILE.mcap [--label STATE]``: CSV or Parquet to MCAP, checked.

``--rig NAME|FILE``: a rig's data (a folder of per-cycle files for a wide description, a CSV/Parquet table for a
long one) read through its description and written as ``rig_cycles`` messages (docs/rigs.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.io.recordings import convert
from hydrowatch.recording import Recording

NAME = "import"
HELP = ("convert a CSV or Parquet recording (or, with --rig, a rig's data) to MCAP, checking columns, units, time base "
        "and labels")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path,
                        help="recording to import (.csv, .parquet or .mcap); with --rig the rig's data (a folder of "
                             "per-cycle files for a wide description, a .csv/.parquet table for a long one)")
    parser.add_argument("--out", type=Path, required=True, help="MCAP file to write")
    parser.add_argument(
        "--label", metavar="STATE", help="health label of the whole recording, e.g. healthy, load_alert"
    )
    parser.add_argument("--rig", metavar="NAME|FILE", default=None,
                        help="read FILE through this rig description (a shipped name such as uci-hydraulic, or a "
                             ".toml file) and write its cycles (hydro/<fleet>/<machine>/cycles, the description kept "
                             "in the file)")
    parser.add_argument("--fleet", help="fleet id of the channel hydro/<fleet>/<machine>/sensors (default: 'default')")
    parser.add_argument("--machine", help="machine id (default: the file's own, else the input file name)")
    parser.add_argument("--recover", action="store_true", help="accept an unfinished MCAP input (complete chunks only)")


def summary_line(out: Path, recording: Recording) -> str:
    """One line saying what was written."""
    state = recording.state or ("per-row labels" if recording.meta.get("labels") is not None else "unlabelled")
    recovered = f"; {recording.meta['recovered']}" if "recovered" in recording.meta else ""
    return (
        f"wrote {out}: {len(recording)} samples, {recording.t[0]:.3f}-{recording.t[-1]:.3f} s, "
        f"channels {','.join(recording.channels)}, {state}{recovered}"
    )


def run(args: argparse.Namespace) -> int:
    if args.out.suffix != ".mcap":
        raise DataError(
            f"--out must end in .mcap. Got {args.out.suffix!r}; use 'hydrowatch export' for Parquet or CSV.",
            str(args.out),
        )
    if args.rig is not None:
        return _import_rig(args)
    recording = convert(
        args.file, args.out, label=args.label, fleet=args.fleet, machine=args.machine, recover=args.recover
    )
    print(summary_line(args.out, recording))
    return 0


def _import_rig(args: argparse.Namespace) -> int:
    """``--rig``: the rig's data through its description to ``rig_cycles`` messages."""
    from hydrowatch.io.recordings import DEFAULT_FLEET
    from hydrowatch.io.rig_cycles import read_rig_data, write_rig_recording
    from hydrowatch.rig.description import rig_text

    if args.label is not None or args.recover:
        raise ParameterError("--rig takes the labels from the rig description; leave --label and --recover out.")
    if args.file.suffix == ".mcap":
        raise DataError("with --rig the input must be the rig's data (a folder or a .csv/.parquet table). Got an MCAP "
                        "file: it is imported already.", str(args.file))
    rig, text = rig_text(args.rig)
    cycles = read_rig_data(args.file, rig)
    machine = args.machine or args.file.stem.split(".")[0] or rig.name
    write_rig_recording(args.out, cycles, rig, text, fleet=args.fleet or DEFAULT_FLEET, machine=machine)
    counts = ", ".join(f"{name} {len(set(map(str, column)))} values" for name, column in cycles.labels.items())
    mixed = getattr(cycles, "mixed", 0)
    print(f"wrote {args.out}: {len(cycles)} {rig.window.kind}s of rig {rig.name}, {len(cycles.channels)} channels "
          f"on a {rig.window.grid_hz:g} Hz grid, labels {counts or 'none'}"
          + (f"; {mixed} windows left out (their labels change inside)" if mixed else ""))
    return 0
