"""``hydrowatch info FILE.mcap``: channels, message counts, time range, metadata; recovers unfinished files."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hydrowatch.errors import DataError
from hydrowatch.io import format_summary, summarize

NAME = "info"
HELP = "show the channels, message counts, time range and metadata of an MCAP recording (recovers unfinished files)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="MCAP recording")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def run(args: argparse.Namespace) -> int:
    if args.file.suffix != ".mcap":
        raise DataError(
            f"file must be an MCAP recording (.mcap). Got {args.file.suffix!r}; "
            "use 'hydrowatch import' to convert CSV or Parquet.",
            str(args.file),
        )
    summary = summarize(args.file)
    print(json.dumps(summary, ensure_ascii=False) if args.json else format_summary(summary))
    return 0
