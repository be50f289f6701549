"""A zenoh FIFO channel read by the consumer's thread, with a waker thread for when it runs dry.

Why not a Python callback: zenoh calls it on its receive thread, which must take the GIL for
every sample; against a busy consumer (the recorder) that cost ~100 µs of CPU per message. Why
not polling: an idle consumer would spin. Here zenoh's threads never run Python: samples wait in
a bounded zenoh channel (full: zenoh's thread waits, which with ``BLOCK`` publishers slows the
publishers instead of losing data). The consumer takes them with ``try_recv``; only when every
channel is empty does it hand each channel to its waker thread, which blocks in ``recv`` without
the GIL and hands back the first sample that arrives. One GIL hand-over per idle spell, not per
sample.

Order: while a waker may be inside ``recv`` (its ``idle`` flag is set) the consumer does not read
that channel itself; the sample the waker took is the oldest, and the consumer takes it first.
"""

from __future__ import annotations

import threading
from collections import deque

import zenoh


class WakingChannel:
    """The zenoh channel of one subscription, plus its waker thread.

    Parameters
    ----------
    handler : zenoh.handlers.Handler
        The subscriber's ``handler`` (it keeps what arrived after the subscriber is undeclared).
    ready : threading.Event
        Set when the waker hands over a sample (shared by every channel of a subscriber).
    """

    def __init__(self, handler: zenoh.handlers.Handler, ready: threading.Event) -> None:
        self._handler = handler
        self._ready = ready
        self._held: deque[zenoh.Sample] = deque()
        self._idle = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._wake, name="subscriber-waker", daemon=True)
        self._thread.start()

    def _wake(self) -> None:
        while True:
            self._idle.wait()
            try:
                sample = self._handler.recv()  # blocks without the GIL
            except zenoh.ZError:  # undeclared and empty
                return
            self._held.append(sample)
            self._idle.clear()
            self._ready.set()
            if self._closed:
                return

    def take(self) -> zenoh.Sample | None:
        """The oldest sample, or None when there is none (or the waker is watching the channel)."""
        if self._held:
            return self._held.popleft()
        if self._idle.is_set() and self._thread.is_alive():
            return None
        try:
            return self._handler.try_recv()
        except zenoh.ZError:  # undeclared and empty
            return None

    def watch(self) -> bool:
        """Hand the channel to the waker (the consumer found it empty and is going to wait).

        Returns True when the waker already holds a sample (so there is no need to wait).
        """
        self._idle.set()
        return bool(self._held)

    def close(self) -> None:
        """After the subscriber is undeclared: stop the waker; what is still queued stays readable."""
        self._closed = True
        self._idle.set()
        self._thread.join(timeout=5.0)
