"""The ``hydrowatch`` command line.

Each subcommand is a module in :mod:`hydrowatch.commands` that defines ``NAME`` (str), ``HELP``
(one line), ``add_arguments(parser)`` and ``run(args) -> int``. Modules are discovered, so adding a
command never touches this file; the command's name is the module's name without a trailing ``_``
(``import_.py`` is ``hydrowatch import``). Only the module of the command being run is imported:
the others would pull in torch, mlflow and zenoh for nothing (seconds of start-up). Their help lines
are read from the source with :mod:`ast`.

Errors that hydrowatch raises on purpose (``HydrowatchError``) print as one line and exit 2;
anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import pkgutil
import sys
from collections.abc import Sequence
from pathlib import Path

from hydrowatch import __version__, commands
from hydrowatch.errors import HydrowatchError
from hydrowatch.log import configure


def command_modules() -> dict[str, str]:
    """Command name → module name in :mod:`hydrowatch.commands`, sorted by command name."""
    names = [m.name for m in pkgutil.iter_modules(commands.__path__) if not m.name.startswith("_")]
    return {name.rstrip("_"): name for name in sorted(names, key=lambda n: n.rstrip("_"))}


def _help_line(module_name: str) -> str:
    """The module's ``HELP``: its string literal read from the source, else imported."""
    path = Path(commands.__path__[0]) / f"{module_name}.py"
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(isinstance(t, ast.Name) and t.id == "HELP" for t in targets) and isinstance(
                node.value, ast.Constant
            ):
                return str(node.value.value)
    return str(importlib.import_module(f"hydrowatch.commands.{module_name}").HELP)


def _chosen(argv: Sequence[str]) -> str | None:
    """The command named on the command line (the first word that is not an option)."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The top-level parser.

    With ``argv=None`` every command's full parser is built (for tools and tests that check
    command lines); otherwise only the command that ``argv`` names gets its arguments.
    """
    parser = argparse.ArgumentParser(
        prog="hydrowatch",
        description="Which part of a hydrostatic transmission is wearing out, from three sensors.",
    )
    parser.add_argument("--version", action="version", version=f"hydrowatch {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="subcommand", metavar="COMMAND")  # not "command": simulate has --command
    chosen = None if argv is None else _chosen(argv)
    for name, module_name in command_modules().items():
        if argv is None or name == chosen:
            module = importlib.import_module(f"hydrowatch.commands.{module_name}")
            p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
        else:
            line = _help_line(module_name)
            sub.add_parser(name, help=line, description=line)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hydrowatch`` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    configure(args.verbose)
    try:
        return int(args._run(args) or 0)
    except HydrowatchError as exc:
        print(f"hydrowatch {args.subcommand}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # `hydrowatch info X | head`: the reader went away; that is not an error of ours.
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
