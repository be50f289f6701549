"""``hydrowatch export FILE.mcap --out FILE.parquet`` (or .csv): MCAP to a table, checked."""

from __future__ import annotations

import argparse
from pathlib import Path

from hydrowatch.commands.import_ import summary_line
from hydrowatch.errors import DataError
from hydrowatch.io.recordings import convert

NAME = "export"
HELP = "convert an MCAP recording to Parquet or CSV (one machine's sensor channel), checking it on the way"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="MCAP recording")
    parser.add_argument("--out", type=Path, required=True, help="file to write: .parquet or .csv")
    parser.add_argument("--machine", help="which machine, when the file holds several")
    parser.add_argument(
        "--recover", action="store_true", help="export the complete chunks of an unfinished file (writer killed)"
    )


def run(args: argparse.Namespace) -> int:
    if args.out.suffix not in (".parquet", ".csv"):
        raise DataError(f"--out must end in .parquet or .csv. Got {args.out.suffix!r}.", str(args.out))
    recording = convert(args.file, args.out, machine=args.machine, recover=args.recover)
    print(summary_line(args.out, recording))
    return 0
