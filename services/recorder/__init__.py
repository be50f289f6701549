"""Recorder service: subscribes to key expressions and writes per-machine MCAP recordings.

Every received payload is stored unchanged (Arrow IPC, one MCAP channel per key) after it has
decoded against its topic's schema; undecodable messages are counted and skipped. Files rotate
by size or time; chunks close every ``--chunk-size`` bytes or ``--flush`` seconds, so a
``kill -9`` loses at most that; SIGTERM/SIGINT drains the queue, finishes every file and exits.
``--shard i/n`` records only that shard of the fleet. By default the recorder records the fleet's
``sensors``; ``--topics`` names others of the contract (``expected``, ``health``, a rig's ``cycles`` and
``cycle_health``, …) and ``--keys`` any key expressions. ``--rig`` keeps a rig description in every file's
metadata, so that a recording of a rig's ``cycles`` is read as ``import --rig`` writes it (``score --data``).
A gap in a machine's sensor chunks is asked
for from the publisher's history and the recovered chunks are written too
(:mod:`hydrowatch.bus.recovery`); what no publisher could resend is logged and counted in the
heartbeat's ``messages_dropped`` (chunks), with status ``degraded``.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Sequence
from pathlib import Path

from hydrowatch.bus import Shard, StatusReporter, Subscriber, add_bus_arguments, key_expr, open_session, parse_shard
from hydrowatch.bus.keys import TOPICS
from hydrowatch.bus.recovery import GapRecovery
from hydrowatch.bus.service import service_main
from hydrowatch.bus.session import settings_from_args
from hydrowatch.bus.takeover import release, sharded
from hydrowatch.errors import ParameterError
from hydrowatch.log import event, get_logger
from services.recorder.files import RecordingFiles

NAME = "record"
HELP = "record key expressions of the bus into per-machine MCAP files, rotated by size or time"
QUIET_S = 0.2
"""On stop, the recorder keeps receiving until no message came for this long (at most ``--drain`` s), s."""
TAILS_AFTER_S = 0.5
"""When no message came for this long after some did, the recorder asks the publishers' history for every
machine's tail (a run's last chunks have no later chunk to show they are missing), s."""
BURST = 1000
"""Messages the recorder takes from its queue at a time (one clock read, one loop, per burst)."""
log = get_logger("services.recorder")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("recordings"), help="folder of the recordings")
    parser.add_argument("--keys", action="append", default=[], metavar="KEYEXPR",
                        help=f"key expression to record, repeatable (default {key_expr()})")
    parser.add_argument("--fleet", default="*", help="fleet to record when --keys is not given (default: all)")
    parser.add_argument("--topics", type=_topics, default=None, metavar="TOPIC[,TOPIC…]",
                        help=f"topics of --fleet to record when --keys is not given, of {', '.join(TOPICS)} "
                             "(default sensors)")
    parser.add_argument("--rig", metavar="NAME|FILE", default=None,
                        help="rig description kept in every file's metadata (as import --rig does), so that recorded "
                             "cycles read back with their description")
    parser.add_argument("--shard", type=parse_shard, default=Shard(), help="record only shard i/n of the machines")
    parser.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    parser.add_argument("--chunk-size", type=int, default=64 * 1024, help="bytes per MCAP chunk (default 65536)")
    parser.add_argument("--flush", type=float, default=1.0,
                        help="close a chunk after this many seconds at most: the most a kill -9 loses (default 1)")
    parser.add_argument("--rotate-mb", type=float, default=256.0, help="start a new file past this size, MB")
    parser.add_argument("--rotate-s", type=float, default=3600.0, help="start a new file after this many seconds")
    parser.add_argument("--seconds", type=float, default=None, help="stop after this many wall-clock seconds")
    parser.add_argument("--drain", type=float, default=20.0,
                        help="on stop, keep recording what is still arriving for up to this many seconds (default 20)")
    parser.add_argument("--no-recovery", action="store_true",
                        help="do not ask publishers' history for chunks missing from a machine's stream")
    parser.add_argument("--foxglove", action="store_true",
                        help="write JSON that Foxglove plots (*.foxglove.mcap) instead of Arrow: for a few machines; "
                             "hydrowatch export --foxglove converts Arrow recordings later")
    parser.add_argument("--heartbeat", type=float, default=1.0, metavar="SECONDS",
                        help="seconds between status heartbeats with the message counters (default 1)")
    add_bus_arguments(parser)


def _topics(text: str) -> list[str]:
    """``--topics``: a comma-separated list of contract topics."""
    topics = [t.strip() for t in text.split(",") if t.strip()]
    unknown = [t for t in topics if t not in TOPICS]
    if unknown or not topics:
        raise argparse.ArgumentTypeError(f"topics must be some of {', '.join(TOPICS)}, comma-separated. Got {text!r}.")
    return topics


def recorder_keys(args: argparse.Namespace) -> list[str]:
    """The key expressions the recorder subscribes to: ``--keys``, or ``--fleet``'s machines × ``--topics`` (default
    ``sensors``)."""
    if args.keys and args.topics:
        raise ParameterError("--topics names topics of --fleet; with --keys give whole key expressions instead "
                             "(e.g. hydro/lab/*/cycle_health).")
    return args.keys or [key_expr(args.fleet, "*", topic) for topic in (args.topics or ["sensors"])]


def run(args: argparse.Namespace, stop: threading.Event) -> int:
    """Record until ``stop`` (or ``--seconds``), then drain and finish every file; returns 0."""
    for name in ("chunk_size", "flush", "rotate_mb", "rotate_s", "heartbeat"):
        if not getattr(args, name) > 0:
            raise ParameterError(f"--{name.replace('_', '-')} must be > 0. Got {getattr(args, name)}.")
    keys = recorder_keys(args)
    metadata = {"recorder_keys": keys, "shard": str(args.shard)}
    if args.rig is not None:
        from hydrowatch.io.rig_cycles import RIG_TEXT_KEY
        from hydrowatch.rig.description import rig_text

        rig, metadata[RIG_TEXT_KEY] = rig_text(args.rig)
        metadata["rig"] = rig.name
    files = RecordingFiles(
        args.out, chunk_size=args.chunk_size, compression=args.compression, flush_s=args.flush,
        rotate_bytes=int(args.rotate_mb * 1024 * 1024), rotate_s=args.rotate_s,
        extra_metadata=metadata, foxglove=args.foxglove,
    )
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    fleet = args.fleet if args.fleet != "*" else "all"
    with open_session(settings_from_args(args)) as session:
        shard = sharded(session, args.fleet, NAME, args.shard)
        subscriber = Subscriber(session, keys, shard=shard)
        recovery = None if args.no_recovery else GapRecovery(session, shard=shard)
        reporter = StatusReporter(session, fleet, NAME, lambda: {
            "messages_in": subscriber.received, "messages_out": files.messages,
            "messages_undecodable": subscriber.undecodable_total,
            "messages_dropped": recovery.chunks_lost if recovery else 0,
        }, interval=args.heartbeat)
        try:
            reporter.start()
            reporter.status = "running"
            event(log, "recorder started", keys=",".join(keys), out=args.out, shard=str(args.shard))
            next_tick = time.monotonic() + args.flush
            last_message, tails_asked = time.monotonic(), True
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                received = subscriber.recv_many(BURST, timeout=min(0.1, args.flush))
                if recovery is None:
                    files.write_many(received)
                else:
                    files.write_many(recovery.observe(received))
                    files.write_many(recovery.collect())
                    if recovery.samples_lost:
                        reporter.status = "degraded"
                    if received:
                        last_message, tails_asked = time.monotonic(), False
                    elif not tails_asked and time.monotonic() - last_message > TAILS_AFTER_S:
                        recovery.ask_tails()
                        tails_asked = True
                if time.monotonic() >= next_tick:
                    if recovery is not None:
                        recovery.ask_stalled()
                    files.tick()
                    next_tick = time.monotonic() + args.flush
            last_message, tails_asked = time.monotonic(), True
            reporter.status = "draining"
            # what is still on its way arrives within a moment: keep receiving until the bus is quiet
            give_up = time.monotonic() + args.drain
            while time.monotonic() < give_up and (messages := subscriber.recv_many(BURST, timeout=QUIET_S)):
                files.write_many(recovery.observe(messages) if recovery else messages)
            subscriber.close()
            last = list(subscriber.drain())
            files.write_many(recovery.observe(last) if recovery else last)
            if recovery is not None:
                if not tails_asked:
                    recovery.ask_tails()
                files.write_many(recovery.wait())
        finally:
            subscriber.close()
            release(shard)
            files.close()
            reporter.stop()
    gaps = {} if recovery is None else {"gaps": recovery.gaps, "chunks_recovered": recovery.chunks_recovered,
                                        "samples_lost": recovery.samples_lost}
    event(log, "recorder stopped", messages=files.messages, files=len(files.files_written),
          undecodable=subscriber.undecodable_total, outside_shard=subscriber.outside_shard, **gaps)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.recorder``."""
    return service_main("recorder", HELP, add_arguments, run, argv)
