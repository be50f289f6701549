"""A headless Chromium driven over the Chrome DevTools protocol, for the web page's tests and benchmark.

Neither Playwright nor Selenium is installed (and Playwright's own browser builds cannot be downloaded
here), so this talks to Debian's ``chromium`` directly: the browser is started with
``--remote-debugging-port=0``, prints the address of its DevTools websocket, and :class:`Chromium`
sends protocol commands (``Page.navigate``, ``Runtime.evaluate``, ``Page.captureScreenshot``) over a
small websocket client written on the standard library (RFC 6455 text frames, client masking, no
extensions). Only loopback addresses are ever used.
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import socket
import struct
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from hydrowatch.errors import DataError

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
ENV_BROWSER = "HYDROWATCH_CHROMIUM"
_LISTENING = re.compile(r"DevTools listening on (ws://\S+)")
NAVIGATED = "Inspected target navigated or closed"
"""DevTools' error when a navigation cuts off an evaluation (:meth:`Chromium.wait_for` polls again)."""


def find_chromium() -> str | None:
    """The Chromium executable: ``$HYDROWATCH_CHROMIUM``, else the first of :data:`CANDIDATES` on PATH; None
    when there is none (Debian: ``apt-get install chromium``)."""
    given = os.environ.get(ENV_BROWSER)
    if given:
        return given if shutil.which(given) else None
    return next((found for name in CANDIDATES if (found := shutil.which(name))), None)


class WebSocket:
    """A minimal blocking websocket client (text messages) for a DevTools endpoint on loopback."""

    def __init__(self, url: str, timeout: float = 10.0) -> None:
        parts = urlsplit(url)
        if parts.scheme != "ws" or parts.hostname not in ("127.0.0.1", "localhost", "::1"):
            raise DataError(f"DevTools websocket must be a ws:// address on this machine. Got {url!r}.")
        self._sock = socket.create_connection((parts.hostname, parts.port or 80), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        request = (f"GET {parts.path or '/'} HTTP/1.1\r\nHost: {parts.netloc}\r\nUpgrade: websocket\r\n"
                   f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n")
        self._sock.sendall(request.encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self._sock.recv(4096)
            if not chunk:
                raise DataError(f"DevTools websocket {url} closed during the handshake")
            head += chunk
        status, _, rest = head.partition(b"\r\n\r\n")
        if b" 101 " not in status.split(b"\r\n")[0]:
            raise DataError(f"DevTools websocket {url} refused the upgrade: {status.splitlines()[0]!r}")
        self._buffer = rest

    def _read(self, n: int) -> bytes:
        while len(self._buffer) < n:
            chunk = self._sock.recv(max(65536, n - len(self._buffer)))
            if not chunk:
                raise ConnectionError("DevTools websocket closed")
            self._buffer += chunk
        out, self._buffer = self._buffer[:n], self._buffer[n:]
        return out

    def _frame(self, opcode: int, payload: bytes) -> None:
        mask = os.urandom(4)
        n = len(payload)
        if n < 126:
            head = struct.pack("!BB", 0x80 | opcode, 0x80 | n)
        elif n < 1 << 16:
            head = struct.pack("!BBH", 0x80 | opcode, 0x80 | 126, n)
        else:
            head = struct.pack("!BBQ", 0x80 | opcode, 0x80 | 127, n)
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self._sock.sendall(head + mask + masked)

    def send(self, text: str) -> None:
        """Send one text message."""
        self._frame(0x1, text.encode())

    def recv(self, timeout: float | None = None) -> str:
        """The next text message (answers pings; raises ``TimeoutError``, ``ConnectionError``)."""
        self._sock.settimeout(timeout)
        parts: list[bytes] = []
        while True:
            b0, b1 = self._read(2)
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack("!H", self._read(2))[0]
            elif n == 127:
                n = struct.unpack("!Q", self._read(8))[0]
            mask = self._read(4) if b1 & 0x80 else None
            payload = self._read(n)
            if mask:
                payload = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
            opcode = b0 & 0x0F
            if opcode == 0x8:
                raise ConnectionError("DevTools websocket closed by the browser")
            if opcode == 0x9:
                self._frame(0xA, payload)
                continue
            if opcode in (0x0, 0x1, 0x2):
                parts.append(payload)
                if b0 & 0x80:
                    return b"".join(parts).decode()

    def close(self) -> None:
        try:
            self._frame(0x8, b"")
        except OSError:
            pass
        self._sock.close()


class Chromium:
    """Headless Chromium with one page, driven over the DevTools protocol; use as a context manager.

    Parameters
    ----------
    executable : str or None
        The browser (None: :func:`find_chromium`).
    width, height : int
        Window size, CSS pixels (screenshots have this size).
    """

    def __init__(self, executable: str | None = None, *, width: int = 1280, height: int = 800) -> None:
        self.executable = executable
        self.width = width
        self.height = height
        self.events: list[dict[str, Any]] = []
        self._next_id = 0

    def __enter__(self) -> Chromium:
        exe = self.executable or find_chromium()
        if exe is None:
            raise DataError("no Chromium found. Install it (Debian: apt-get install chromium) or set "
                            f"{ENV_BROWSER}.")
        self._profile = tempfile.mkdtemp(prefix="hydrowatch-chromium-")
        self._proc = subprocess.Popen(
            [exe, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--no-default-browser-check",
             "--disable-extensions", "--disable-background-networking", "--disable-dev-shm-usage",
             "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0", f"--user-data-dir={self._profile}",
             f"--window-size={self.width},{self.height}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            browser_url = self._devtools_url(timeout=30.0)
            self._ws = WebSocket(browser_url)
            target = self.call("Target.createTarget", url="about:blank")["targetId"]
            self._session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            self.page("Page.enable")
            self.page("Runtime.enable")
        except BaseException:
            self.__exit__()
            raise
        return self

    def _devtools_url(self, timeout: float) -> str:
        found: list[str] = []
        lines: list[str] = []

        def read() -> None:
            assert self._proc.stderr is not None
            for line in self._proc.stderr:
                lines.append(line)
                match = _LISTENING.search(line)
                if match and not found:
                    found.append(match.group(1))
            # keep draining so that the browser never blocks on a full pipe

        threading.Thread(target=read, daemon=True).start()
        deadline = time.monotonic() + timeout
        while not found:
            if self._proc.poll() is not None or time.monotonic() > deadline:
                raise DataError(f"Chromium did not open its DevTools port: {''.join(lines[-5:]).strip()!r}")
            time.sleep(0.02)
        return found[0]

    def __exit__(self, *exc: object) -> None:
        ws = getattr(self, "_ws", None)
        if ws is not None:
            ws.close()
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        shutil.rmtree(self._profile, ignore_errors=True)

    def call(self, method: str, session: str | None = None, timeout: float = 30.0, **params: Any) -> dict[str, Any]:
        """Send one protocol command and return its result (events that arrive meanwhile go to :attr:`events`)."""
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        self._ws.send(json.dumps(message))
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"DevTools command {method} got no answer in {timeout} s")
            answer = json.loads(self._ws.recv(timeout=left))
            if answer.get("id") == self._next_id:
                if "error" in answer:
                    raise DataError(f"DevTools command {method} failed: {answer['error']}")
                return dict(answer.get("result", {}))
            self.events.append(answer)

    def page(self, method: str, **params: Any) -> dict[str, Any]:
        """A protocol command to the page."""
        return self.call(method, self._session, **params)

    def navigate(self, url: str, timeout: float = 30.0) -> float:
        """Load ``url`` and wait for its ``load`` event; returns the seconds that took."""
        t0 = time.monotonic()
        self.events.clear()
        self.page("Page.navigate", url=url)
        self.wait_for("document.readyState === 'complete' && location.href !== 'about:blank'", timeout)
        return time.monotonic() - t0

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (awaited when it is a promise)."""
        result = self.page("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise DataError(f"JavaScript error in {expression!r}: {result['exceptionDetails'].get('text')} "
                            f"{result['exceptionDetails'].get('exception', {}).get('description', '')}")
        return result.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout: float = 10.0, poll: float = 0.02) -> Any:
        """Poll ``expression`` until it is truthy; returns its value (``TimeoutError`` after ``timeout`` s).

        An evaluation that a navigation cuts off ("Inspected target navigated or closed": the page of a link just
        clicked replaces the one polled) counts as not yet true; the next poll asks the new page."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                value = self.evaluate(expression)
            except DataError as exc:
                if NAVIGATED not in str(exc):
                    raise
                value = None
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError(f"{expression!r} still false after {timeout} s")
            time.sleep(poll)

    def exceptions(self) -> list[str]:
        """The uncaught JavaScript exceptions of the page seen so far (since the last :meth:`navigate`)."""
        self.evaluate("0")  # takes in the events that came meanwhile
        return [e["params"]["exceptionDetails"].get("exception", {}).get("description", "?")
                for e in self.events if e.get("method") == "Runtime.exceptionThrown"]

    def screenshot(self, path: Path, full_page: bool = False, palette: bool = False) -> Path:
        """Save what the window shows (``full_page``: the whole page) as a PNG (``palette``: 256 colours, about a
        third of the size, for screenshots kept in the repository; needs Pillow, which matplotlib brings)."""
        params: dict[str, Any] = {"format": "png"}
        if full_page:
            size = self.page("Page.getLayoutMetrics")["cssContentSize"]
            params.update(captureBeyondViewport=True, clip={"x": 0, "y": 0, "width": size["width"],
                                                            "height": size["height"], "scale": 1})
        data = self.page("Page.captureScreenshot", **params)["data"]
        path = Path(path)
        path.write_bytes(base64.b64decode(data))
        if palette:
            from PIL import Image

            with Image.open(path) as image:
                small = image.convert("RGB").quantize(256)
            small.save(path, optimize=True)
        return path
