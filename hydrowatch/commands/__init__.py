"""Subcommands of the ``hydrowatch`` CLI, one module each (see :mod:`hydrowatch.cli`)."""
