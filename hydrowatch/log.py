"""Structured, quiet-by-default logging: one ``key=value`` line per event on stderr."""

from __future__ import annotations

import logging
import sys
from typing import Any

_CONFIGURED = False


class _KeyValueFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        fields: dict[str, Any] = getattr(record, "fields", {})
        extra = "".join(f" {k}={_quote(v)}" for k, v in fields.items())
        return (
            f"{self.formatTime(record, '%Y-%m-%dT%H:%M:%S')} {record.levelname.lower()} "
            f"{record.name} {record.getMessage()}{extra}"
        )


def _quote(value: Any) -> str:
    text = str(value)
    return f'"{text}"' if (" " in text or not text) else text


def configure(verbosity: int = 0) -> None:
    """Set up the root ``hydrowatch`` logger: warnings only (0), info (1) or debug (2+)."""
    global _CONFIGURED
    level = logging.WARNING if verbosity <= 0 else logging.INFO if verbosity == 1 else logging.DEBUG
    logger = logging.getLogger("hydrowatch")
    if not _CONFIGURED:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(_KeyValueFormatter())
        logger.addHandler(handler)
        logger.propagate = False
        _CONFIGURED = True
    logger.setLevel(level)


def get_logger(name: str) -> logging.Logger:
    """Logger under the ``hydrowatch`` hierarchy, e.g. ``get_logger(__name__)``."""
    return logging.getLogger(name if name.startswith("hydrowatch") else f"hydrowatch.{name}")


def event(logger: logging.Logger, message: str, level: int = logging.INFO, **fields: Any) -> None:
    """Log one structured event: ``event(log, "window closed", machine="m1", n=1000)``."""
    logger.log(level, message, extra={"fields": fields})
