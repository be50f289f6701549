"""The ``hydrowatch`` command line.

Each subcommand is a module in :mod:`hydrowatch.commands` that defines ``NAME`` (str), ``HELP``
(one line), ``add_arguments(parser)`` and ``run(args) -> int``. Modules are discovered, so adding a
command never touches this file. Errors that hydrowatch raises on purpose (``HydrowatchError``)
print as one line and exit 2; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence
from types import ModuleType

from hydrowatch import __version__, commands
from hydrowatch.errors import HydrowatchError
from hydrowatch.log import configure


def _command_modules() -> list[ModuleType]:
    modules = []
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        modules.append(importlib.import_module(f"hydrowatch.commands.{info.name}"))
    return modules


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per command module."""
    parser = argparse.ArgumentParser(
        prog="hydrowatch",
        description="Which part of a hydrostatic transmission is wearing out, from three sensors.",
    )
    parser.add_argument("--version", action="version", version=f"hydrowatch {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in _command_modules():
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hydrowatch`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    configure(args.verbose)
    try:
        return int(args._run(args) or 0)
    except HydrowatchError as exc:
        print(f"hydrowatch {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # `hydrowatch info X | head`: the reader went away; that is not an error of ours.
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
