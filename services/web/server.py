"""The HTTP side of the web service: static pages, two JSON endpoints and two server-sent event streams.

Standard library only (``http.server.ThreadingHTTPServer``: one thread per connection, which an open
event stream holds). Routes:

* ``/`` the fleet page, ``/machine?id=<fleet>/<machine>`` a machine page, ``/static/<file>`` their files;
* ``/api/fleet?state=&fleet=&machine=`` the rows shown (JSON), ``/api/machine?id=`` one machine (JSON, 404 unknown);
* ``/events?state=&fleet=&machine=`` the fleet page's stream (:class:`hydrowatch.web.live.PageView` messages),
  ``/events/machine?id=`` a machine page's stream (the machine, each time it changes).

Every read of the fleet happens under ``condition`` (the bus loop writes under it and notifies).
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from collections.abc import Callable, Generator
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from hydrowatch.errors import ParameterError
from hydrowatch.log import get_logger
from hydrowatch.web.live import FleetLive, PageView, counts, select

log = get_logger("services.web")
STATIC = Path(__file__).with_name("static")
TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
         ".css": "text/css; charset=utf-8", ".svg": "image/svg+xml", ".png": "image/png"}
KEEPALIVE_S = 15.0
"""An event stream with nothing to say sends a comment this often (and so notices a closed page)."""
COALESCE_S = 0.015
"""After sending, a stream waits this long so that a burst of verdicts goes out as one message."""
SENSORS_EVERY_S = 0.5
"""A machine page whose machine got only new sensor samples is sent them at most this often."""


class WebServer:
    """Serves the pages of ``live`` on ``host:port`` from a background thread; use as a context manager.

    Parameters
    ----------
    live : FleetLive
    condition : threading.Condition
        Held while ``live`` is read; notified by whoever writes it.
    host : str
        Address to bind (default loopback only).
    port : int
        TCP port (0: any free one; :attr:`url` tells which).
    """

    def __init__(self, live: FleetLive, condition: threading.Condition, host: str = "127.0.0.1",
                 port: int = 0) -> None:
        self.live = live
        self.condition = condition
        self.closing = threading.Event()
        self.streams = 0
        self._watched: Counter[str] = Counter()
        handler = type("Handler", (_Handler,), {"app": self})
        try:
            self._httpd = ThreadingHTTPServer((host, port), handler)
        except OSError as exc:
            raise ParameterError(f"the web page's address must be free to serve on. Got {host}:{port}: {exc.strerror}. "
                                 "Pick another --port (0: any free one) or stop what serves there.") from None
        self._httpd.daemon_threads = True
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="web-http", daemon=True)

    @property
    def url(self) -> str:
        """The fleet page's address, e.g. ``http://127.0.0.1:8050/``."""
        host, port = self._httpd.server_address[:2]
        host = host.decode() if isinstance(host, bytes) else host
        return f"http://{host}:{port}/"

    def __enter__(self) -> WebServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.closing.set()
        with self.condition:
            self.condition.notify_all()
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=5)

    def watched(self) -> set[str]:
        """Machines (``fleet/machine``) whose page is open now: the service gathers their sensor samples."""
        with self.condition:
            return {ident for ident, n in self._watched.items() if n > 0}

    def read(self, what: Callable[[FleetLive], Any]) -> Any:
        """``what(live)`` under the lock."""
        with self.condition:
            return what(self.live)

    def wait(self, seen: int, chunks: int | None = None, ident: str = "", timeout: float = KEEPALIVE_S) -> bool:
        """Wait until the fleet changed after ``seen`` (or machine ``ident`` got sensor chunks beyond ``chunks``),
        or closing (True), or ``timeout`` s passed (False)."""
        with self.condition:
            return self.condition.wait_for(lambda: self.live.seq != seen or self.closing.is_set() or (
                chunks is not None and self.live.sensor_chunks(ident) != chunks), timeout)

    def fleet_events(self, view: PageView) -> Generator[dict[str, Any] | None, None, None]:
        """The fleet page's messages; None where a keep-alive is due (nothing to say for :data:`KEEPALIVE_S`)."""
        while not self.closing.is_set():
            message = self.read(view.update)
            if message is not None:
                yield message
            if not self.wait(view.seq, timeout=KEEPALIVE_S):
                yield None
            time.sleep(COALESCE_S)

    def machine_events(self, ident: str) -> Generator[dict[str, Any] | None, None, None]:
        """A machine page's messages: the machine each time its verdict or evidence changes, and with new sensor
        samples at most every :data:`SENSORS_EVERY_S`; while the page is open its machine is :meth:`watched`."""
        seen, chunks, sent = -1, -1, 0.0
        with self.condition:
            self._watched[ident] += 1
        try:
            while not self.closing.is_set():
                with self.condition:
                    live = self.live
                    changed = seen < 0 or ident in live.changed(seen)
                    more = live.sensor_chunks(ident) != chunks
                    due = changed or (more and time.monotonic() - sent >= SENSORS_EVERY_S)
                    message = live.machine(ident) if due else None
                    seen = live.seq  # what changed up to here is looked at
                    if due:
                        chunks, sent = live.sensor_chunks(ident), time.monotonic()
                if message is not None:
                    yield message
                elif more and not due:
                    time.sleep(max(0.0, SENSORS_EVERY_S - (time.monotonic() - sent)))
                    continue
                if not self.wait(seen, chunks, ident, KEEPALIVE_S):
                    yield None
                time.sleep(COALESCE_S)
        finally:
            with self.condition:
                self._watched[ident] -= 1


class _Handler(BaseHTTPRequestHandler):
    app: WebServer
    protocol_version = "HTTP/1.1"
    server_version = "hydrowatch-web"

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (the base class's name)
        log.debug("%s " + format, self.address_string(), *args)

    def _send(self, status: int, body: bytes, content_type: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, value: Any, status: int = HTTPStatus.OK) -> None:
        self._send(status, json.dumps(value, separators=(",", ":")).encode(), "application/json")

    def _file(self, name: str) -> None:
        path = STATIC / name
        if "/" in name or name.startswith(".") or not path.is_file():
            self._send(HTTPStatus.NOT_FOUND, b"not found", "text/plain")
            return
        self._send(HTTPStatus.OK, path.read_bytes(), TYPES.get(path.suffix, "application/octet-stream"))

    def do_HEAD(self) -> None:  # noqa: N802 (http.server's name)
        self.do_GET()

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        url = urlsplit(self.path)
        query = {k: v[-1] for k, v in parse_qs(url.query).items()}
        state, fleet, machine, ident = query.get("state"), query.get("fleet"), query.get("machine"), query.get("id", "")
        if url.path in ("/", "/index.html"):
            self._file("fleet.html")
        elif url.path == "/machine":
            self._file("machine.html")
        elif url.path.startswith("/static/"):
            self._file(url.path.removeprefix("/static/"))
        elif url.path == "/api/fleet":
            rows = self.app.read(lambda live: live.rows())
            shown = select(rows, state=state, fleet=fleet, machine=machine)
            self._json({"rows": shown, "counts": counts(select(rows, fleet=fleet))})
        elif url.path == "/api/machine":
            found = self.app.read(lambda live: live.machine(ident))
            self._json(found if found is not None else {"error": f"no verdict of machine {ident!r} yet"},
                       HTTPStatus.OK if found is not None else HTTPStatus.NOT_FOUND)
        elif url.path == "/events":
            self._stream(self.app.fleet_events(PageView(state, fleet, machine)))
        elif url.path == "/events/machine":
            self._stream(self.app.machine_events(ident))
        else:
            self._send(HTTPStatus.NOT_FOUND, b"not found", "text/plain")

    def _stream(self, messages: Generator[dict[str, Any] | None, None, None]) -> None:
        """Server-sent events: one ``data:`` line of JSON per message, a comment as keep-alive."""
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        with self.app.condition:
            self.app.streams += 1
        try:
            for message in messages:
                text = ": keep-alive\n\n" if message is None else (
                    "data: " + json.dumps(message, separators=(",", ":")) + "\n\n")
                self.wfile.write(text.encode())
                self.wfile.flush()
        except (BrokenPipeError, ConnectionResetError):
            pass  # the page went away
        finally:
            messages.close()  # runs the stream's own clean-up (a machine page stops being watched)
            with self.app.condition:
                self.app.streams -= 1
