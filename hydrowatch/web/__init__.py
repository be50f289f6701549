"""The live fleet page's library side: the fleet's state as a page shows it (``live``) and a headless
Chromium driven over the DevTools protocol (``browser``, for tests and benchmarks). The HTTP service that
serves the page is ``services.web`` (docs/web.md)."""

from hydrowatch.web.live import FleetLive, PageView, counts, select

__all__ = ["FleetLive", "PageView", "counts", "select"]
