"""``hydrowatch import FILE --out FILE.mcap [--label STATE]``: CSV or Parquet to MCAP, checked."""

from __future__ import annotations

import argparse
from pathlib import Path

from hydrowatch.errors import DataError
from hydrowatch.io.recordings import convert
from hydrowatch.recording import Recording

NAME = "import"
HELP = "convert a CSV or Parquet recording to MCAP, checking columns, units, time base and labels"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="recording to import (.csv, .parquet or .mcap)")
    parser.add_argument("--out", type=Path, required=True, help="MCAP file to write")
    parser.add_argument(
        "--label", metavar="STATE", help="health label of the whole recording, e.g. healthy, load_alert"
    )
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
    recording = convert(
        args.file, args.out, label=args.label, fleet=args.fleet, machine=args.machine, recover=args.recover
    )
    print(summary_line(args.out, recording))
    return 0
