"""Replay service: publishes MCAP recordings back on the bus, in log-time order.

Payloads go out unchanged (original sample times inside), at the recording's own pace
(``--speed 1``), k times faster (``--speed k``) or as fast as possible (``--speed inf``). Several
files are merged by log time. Unfinished files (a recorder killed with ``kill -9``) are replayed
up to their last complete chunk.
"""

from __future__ import annotations

import argparse
import heapq
import math
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from hydrowatch.bus import Publisher, StatusReporter, add_bus_arguments, key, open_session, parse_key
from hydrowatch.bus.service import LINGER_S, service_main
from hydrowatch.bus.session import settings_from_args
from hydrowatch.errors import DataError, ParameterError
from hydrowatch.io.mcap_io import expected_schema, iter_records
from hydrowatch.log import event, get_logger

NAME = "replay"
HELP = "publish MCAP recordings back on the bus at their own pace, k times faster, or as fast as possible"
log = get_logger("services.replay")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", nargs="+", type=Path, help="MCAP files or folders of them (searched recursively)")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="recorded seconds per wall-clock second; inf: as fast as possible (default 1)")
    parser.add_argument("--fleet", default=None, help="publish under this fleet id instead of the recorded one")
    parser.add_argument("--wait-subscribers", type=float, default=0.0, metavar="SECONDS",
                        help="before the first message on a key, wait up to this long for a subscriber")
    parser.add_argument("--linger", type=float, default=LINGER_S, metavar="SECONDS",
                        help=f"after the last message, wait this long before leaving the bus (default {LINGER_S:g})")
    add_bus_arguments(parser)


def recording_files(paths: Sequence[Path]) -> list[Path]:
    """The MCAP files named, or found under the folders named, sorted; DataError when there are none."""
    found: list[Path] = []
    for path in paths:
        if path.is_dir():
            found += sorted(path.rglob("*.mcap"))
        elif path.is_file():
            found.append(path)
        else:
            raise DataError("path must be an MCAP file or a folder. Got nothing there.", str(path))
    if not found:
        raise DataError(f"folders must hold at least one .mcap file. Got none under {[str(p) for p in paths]}.")
    return found


def _messages(path: Path) -> Iterator[tuple[int, int, str, bytes]]:
    for order, (channel, schema, message) in enumerate(iter_records(path)):
        if expected_schema(channel, schema) is not None:
            yield message.log_time, order, channel.topic, message.data


def run(args: argparse.Namespace, stop: threading.Event) -> int:
    """Publish every message of the recordings in log-time order; returns 0."""
    if not args.speed > 0:
        raise ParameterError(f"--speed must be > 0 (or inf). Got {args.speed}.")
    files = recording_files(args.data)
    merged = heapq.merge(*(_messages(p) for p in files))
    first_log: int | None = None
    announced: set[str] = set()
    with open_session(settings_from_args(args)) as session:
        publisher = Publisher(session)
        reporter = StatusReporter(session, args.fleet or "all", NAME, lambda: {"messages_out": publisher.messages_out})
        try:
            reporter.start()
            reporter.status = "running"
            event(log, "replay started", files=len(files), speed=args.speed)
            wall0 = time.monotonic()
            for log_time, _, topic, data in merged:
                if stop.is_set():
                    break
                if args.fleet:
                    parsed = parse_key(topic)
                    topic = key(args.fleet, parsed.machine, parsed.topic)
                if args.wait_subscribers > 0 and topic not in announced:
                    announced.add(topic)
                    publisher.wait_for_subscribers([topic], args.wait_subscribers, stop=stop)
                    wall0 = time.monotonic() - (0.0 if first_log is None else (log_time - first_log) / 1e9 / args.speed)
                if first_log is None:
                    first_log = log_time
                if math.isfinite(args.speed):
                    ahead = wall0 + (log_time - first_log) / 1e9 / args.speed - time.monotonic()
                    if ahead > 0 and stop.wait(ahead):
                        break
                publisher.put_payload(topic, data)
            reporter.status = "draining"
            # what is still in the sockets is lost if this session closes before subscribers read it
            time.sleep(args.linger)
        finally:
            reporter.stop()
            publisher.close()
    event(log, "replay stopped", messages=publisher.messages_out)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.replay``."""
    return service_main(NAME, HELP, add_arguments, run, argv)
