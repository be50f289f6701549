"""Rejected bus messages kept as they arrived, for whoever has to find out why they were rejected.

A subscriber counts an undecodable message, logs it once per key and goes on (:mod:`hydrowatch.bus.pubsub`); the
bytes themselves are gone. With ``HYDROWATCH_QUARANTINE`` set to a folder, each process also writes the first
:data:`LIMIT` rejected payloads there, byte for byte, each beside a JSON line of what was known about it: a
payload that turns out garbled on the way (not at the publisher) can then be compared with what was sent.

Files: ``<folder>/<pid>-<n>.bin`` (the payload) and ``<folder>/rejected.jsonl`` (one object per payload: ``file``,
``key``, ``reason``, ``bytes``, ``received_ns``, ``published_ns``, ``pid``). Writing never stops the subscriber: a
folder that cannot be written is logged once and the quarantine closes.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from pathlib import Path

from hydrowatch.log import event, get_logger

log = get_logger(__name__)

ENV_QUARANTINE = "HYDROWATCH_QUARANTINE"
"""Folder for rejected payloads (unset or empty: none kept)."""
LIMIT = 50
"""Most payloads one process keeps (the first ones: a burst of thousands says no more than its first few)."""


class Quarantine:
    """Keeps the first :data:`LIMIT` rejected payloads of this process in ``folder``.

    Parameters
    ----------
    folder : str or Path
        Created when the first payload arrives.
    limit : int
        Most payloads kept.
    """

    def __init__(self, folder: str | Path, limit: int = LIMIT) -> None:
        self.folder = Path(folder)
        self.limit = limit
        self.kept = 0
        self._lock = threading.Lock()
        self._closed = False

    @classmethod
    def from_env(cls, env: dict[str, str] | None = None) -> Quarantine | None:
        """The quarantine ``HYDROWATCH_QUARANTINE`` names, or None."""
        folder = (os.environ if env is None else env).get(ENV_QUARANTINE, "")
        return cls(folder) if folder else None

    def keep(self, key: str, payload: bytes, reason: str, received_ns: int = 0, published_ns: int = 0) -> bool:
        """Write ``payload`` and what is known of it; False once :attr:`limit` is reached or the folder failed."""
        with self._lock:
            if self._closed or self.kept >= self.limit:
                return False
            name = f"{os.getpid()}-{self.kept}.bin"
            try:
                self.folder.mkdir(parents=True, exist_ok=True)
                (self.folder / name).write_bytes(payload)
                with open(self.folder / "rejected.jsonl", "a") as out:
                    out.write(json.dumps({"file": name, "key": key, "reason": reason, "bytes": len(payload),
                                          "received_ns": received_ns, "published_ns": published_ns,
                                          "pid": os.getpid()}) + "\n")
            except OSError as exc:
                self._closed = True
                event(log, "quarantine closed: its folder cannot be written", logging.WARNING,
                      folder=str(self.folder), reason=exc)
                return False
            self.kept += 1
            return True
