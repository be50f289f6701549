"""``hydrowatch export FILE.mcap --out FILE.parquet`` (or .csv): MCAP to a table, checked;
``--foxglove --out OUT.mcap``: the same messages as JSON that Foxglove plots (docs/formats.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hydrowatch.commands.import_ import summary_line
from hydrowatch.errors import DataError, ParameterError
from hydrowatch.io.recordings import convert

NAME = "export"
HELP = ("convert an MCAP recording to Parquet or CSV (one machine's sensor channel), checking it on the way, "
        "or with --foxglove to an MCAP file that Foxglove plots")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="MCAP recording")
    parser.add_argument("--out", type=Path, required=True, help="file to write: .parquet or .csv (--foxglove: .mcap)")
    parser.add_argument("--foxglove", action="store_true",
                        help="write samples, verdicts, relative entropies and forecasts as JSON with JSON Schema "
                             "(Foxglove)")
    parser.add_argument("--machine", help="which machine, when the file holds several (not with --foxglove)")
    parser.add_argument(
        "--recover", action="store_true", help="export the complete chunks of an unfinished file (writer killed)"
    )


def run(args: argparse.Namespace) -> int:
    if args.foxglove:
        from hydrowatch.io.foxglove import export_foxglove

        if args.out.suffix != ".mcap":
            raise DataError(f"--out must end in .mcap with --foxglove. Got {args.out.suffix!r}.", str(args.out))
        if args.machine is not None:
            raise ParameterError("--machine must be left out with --foxglove: every machine's channels are exported.")
        print(export_foxglove(args.file, args.out, recover=args.recover).describe())
        return 0
    if args.out.suffix not in (".parquet", ".csv"):
        raise DataError(f"--out must end in .parquet or .csv (or .mcap with --foxglove). Got {args.out.suffix!r}.",
                        str(args.out))
    recording = convert(args.file, args.out, machine=args.machine, recover=args.recover)
    print(summary_line(args.out, recording))
    return 0
