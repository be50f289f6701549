"""What every long-running service shares: signal handling, logging, an entry point.

A service is ``add_arguments(parser)`` plus ``run(args, stop) -> int``; ``run`` loops until the
``stop`` event is set (SIGINT or SIGTERM), then drains and closes its resources (style rule 6).
"""

from __future__ import annotations

import argparse
import faulthandler
import gc
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

from hydrowatch.bus.heap import HeapTrimmer
from hydrowatch.errors import HydrowatchError
from hydrowatch.log import configure

SWITCH_INTERVAL_S = 0.0005
"""GIL switch interval of services: zenoh callbacks wait less for a busy main thread (stack-notes)."""

STOP_DUMP_S = 20.0
"""A service still running this many seconds after SIGINT or SIGTERM writes every thread's stack to stderr (its log):
a plant that did not exit within 30 s of SIGTERM was seen twice (2026-11-26 in tests/test_web_browser.py, 2026-11-27 in
tests/test_bus_topology.py, both under load, its last log line "plant started"), and a stack is what tells where."""

LINGER_S = 2.0
"""Seconds a publishing service stays on the bus after its last message: closing a session drops
what subscribers have not read from their sockets yet (seen at 1000 machines on a loaded host)."""

Run = Callable[[argparse.Namespace, threading.Event], int]


def freeze_heap() -> None:
    """Take every object alive now (a loaded model, torch, schemas, modules) out of the garbage collector's scans.

    Call once a service has loaded what it keeps, before its loop (again after loading a new model). The
    collector's full (generation 2) passes then look only at what the loop allocates: a scorer with a NARX
    bundle otherwise stopped for ~200 ms every ~3 s to walk torch's and the bundle's objects (verdict
    latency p99 244 → 47 ms of CPU at 1000 machines, docs/health-pipeline.md). Objects freed by reference
    counting are freed as before; only cycles among frozen objects stay until the next call.
    """
    gc.unfreeze()
    gc.collect()
    gc.freeze()


@contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An event set by SIGINT or SIGTERM while the block runs (main thread only); handlers restored after.

    The handler sets the event from a thread of its own: it runs in the main thread between two bytecodes, and where
    those are inside the event's own ``wait`` (which holds the event's lock, not reentrant, on its way in and out),
    ``set`` there would wait for that lock forever (a plant service waiting out its pacing hung so until killed,
    tests/test_web_browser.py, 2026-12-04)."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def handler(signum: int, frame: object) -> None:
        if not stop.is_set():
            faulthandler.dump_traceback_later(STOP_DUMP_S, exit=False)  # where a stop hangs (STOP_DUMP_S)
        threading.Thread(target=stop.set, name="stop-signal", daemon=True).start()

    for sig in previous:
        signal.signal(sig, handler)
    try:
        yield stop
    finally:
        faulthandler.cancel_dump_traceback_later()
        for sig, old in previous.items():
            signal.signal(sig, old)


def run_service(run: Run, args: argparse.Namespace) -> int:
    """Run a service until it returns or a signal stops it; sets the GIL switch interval for latency and gives
    freed memory back to the operating system once a minute (:class:`~hydrowatch.bus.heap.HeapTrimmer`)."""
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    with stop_on_signals() as stop, HeapTrimmer(stop):
        return int(run(args, stop) or 0)


def service_parser(
    name: str, help_text: str, add_arguments: Callable[[argparse.ArgumentParser], None]
) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.<name>``: ``-v`` plus the service's own flags."""
    parser = argparse.ArgumentParser(prog=f"python -m services.{name}", description=help_text)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    add_arguments(parser)
    return parser


def service_main(
    name: str,
    help_text: str,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    run: Run,
    argv: Sequence[str] | None = None,
) -> int:
    """Entry point of ``python -m services.<name>``: parse, configure logging, run, exit status.

    Errors hydrowatch raises on purpose print as one line and give exit status 2.
    """
    args = service_parser(name, help_text, add_arguments).parse_args(argv)
    configure(args.verbose)
    try:
        return run_service(run, args)
    except HydrowatchError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 2


def command_run(run: Run) -> Callable[[argparse.Namespace], int]:
    """``run(args)`` of a ``hydrowatch`` subcommand that runs service ``run`` with signal handling."""

    def run_command(args: argparse.Namespace) -> int:
        return run_service(run, args)

    return run_command
