"""Exceptions of hydrowatch. They subclass builtins so callers may catch ``ValueError``.

Messages follow "<what> must be <constraint>. Got <value>." plus the fix, and name the file,
message or field concerned.
"""

from __future__ import annotations


class HydrowatchError(Exception):
    """Base class of every error hydrowatch raises on purpose (printed without a traceback)."""


class ParameterError(HydrowatchError, ValueError):
    """An invalid parameter value (negative volume, NaN, zero cracking pressure, bad order...)."""


class DataError(HydrowatchError, ValueError):
    """Bad input data: a file, message or column that is missing, malformed or inconsistent.

    Parameters
    ----------
    message : str
        What is wrong and what to change.
    source : str, optional
        The file path or key expression the data came from; prefixed to the message.
    """

    def __init__(self, message: str, source: str | None = None) -> None:
        self.source = source
        super().__init__(f"{source}: {message}" if source else message)


class NotFittedError(HydrowatchError, AttributeError):
    """A model was used before ``fit``."""
