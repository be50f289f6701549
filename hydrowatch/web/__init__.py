"""The live fleet page's library side: the fleet's state as a page shows it (``live``) and a headless
Chromium driven over the DevTools protocol (``browser``, for tests and benchmarks). The HTTP service that
serves the page is ``services.web`` (docs/web.md)."""

import socket

from hydrowatch.web.live import FleetLive, PageView, counts, select

DEFAULT_PORT = 8050
"""The fleet page's usual HTTP port (``hydrowatch web``, ``up``, ``demo``)."""


def web_port(requested: int | None = None) -> int:
    """The fleet page's port: ``requested``, else :data:`DEFAULT_PORT` when it is free on loopback, else any free
    port (``up`` and ``demo`` start the page beside whatever else runs on this machine)."""
    if requested is not None:
        return requested
    for port in (DEFAULT_PORT, 0):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(sock.getsockname()[1])
    raise OSError("no free TCP port on 127.0.0.1")


__all__ = ["DEFAULT_PORT", "FleetLive", "PageView", "counts", "select", "web_port"]
