"""Stopping a run from outside: Ctrl-C, ``kill``, ``timeout``, ``docker stop``, systemd, a
closed terminal. SIGINT, SIGTERM and SIGHUP all finish the frame in flight and stop, so the
outputs stay complete; a second signal stops at once. Before the loop starts (set-up), a
signal interrupts straight away: nothing has been written yet.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["STOP_SIGNALS", "StopRequest", "graceful_stop", "interrupt_on_signals"]

# SIGHUP does not exist on Windows.
STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


class StopRequest:
    """Set by the first stop signal; ``reason`` says which: "interrupted" (Ctrl-C) or
    "terminated" (SIGTERM, SIGHUP)."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self.reason: str | None = None

    def request(self, signum: int) -> None:
        self.reason = "interrupted" if signum == signal.SIGINT else "terminated"
        self._event.set()

    def is_set(self) -> bool:
        return self._event.is_set()

    def set(self) -> None:
        """A stop asked for in code (not by a signal): reported as interrupted."""
        self.request(signal.SIGINT)


def _install(handler) -> dict:
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {s: signal.signal(s, handler) for s in STOP_SIGNALS}


def _restore(previous: dict) -> None:
    for s, h in previous.items():
        signal.signal(s, h)


@contextmanager
def graceful_stop(stop: StopRequest) -> Iterator[StopRequest]:
    """The first stop signal sets ``stop`` (the loop ends after the frame in flight); a
    second one raises KeyboardInterrupt."""

    def handler(signum, frame):
        if stop.is_set():
            raise KeyboardInterrupt
        stop.request(signum)

    previous = _install(handler)
    try:
        yield stop
    finally:
        _restore(previous)


@contextmanager
def interrupt_on_signals(stop: StopRequest) -> Iterator[StopRequest]:
    """Any stop signal raises KeyboardInterrupt at once (set-up), its reason kept on
    ``stop``."""

    def handler(signum, frame):
        stop.request(signum)
        raise KeyboardInterrupt

    previous = _install(handler)
    try:
        yield stop
    finally:
        _restore(previous)
