"""Signals that end a sweep: Ctrl-C (SIGINT), SIGTERM (``timeout``, systemd, ``docker stop``) and SIGHUP (a closed
terminal or SSH session) all raise ``KeyboardInterrupt`` in the main thread, so every ``finally`` that zeroes and
disables the drive runs. The first signal raises; later ones, while that shutdown runs, are noted and ignored, so a
second Ctrl-C cannot cut the zero setpoint short.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

__all__ = ["STOP_SIGNALS", "StopSignal", "signals_held", "stop_on_signals"]

STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))
"""The signals that end a sweep safely."""


class StopSignal(KeyboardInterrupt):
    """A stop signal arrived (``signame``: "SIGINT", "SIGTERM", "SIGHUP"); handled wherever Ctrl-C is."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        self.signame = signal.Signals(signum).name
        super().__init__(self.signame)


class _Handler:
    def __init__(self) -> None:
        self.raised: StopSignal | None = None
        self.ignored = 0
        self.holding = 0  # depth of signals_held() blocks under way
        self.held: int | None = None  # the first signal that arrived within them

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.raised is not None:
            self.ignored += 1  # the safe shutdown of the first one is under way
            return
        if self.holding:
            if self.held is None:
                self.held = signum
            return
        self._raise(signum)

    def _raise(self, signum: int) -> None:
        self.raised = StopSignal(signum)
        raise self.raised


_active: _Handler | None = None  # the handler of the stop_on_signals block under way in the main thread


@contextmanager
def signals_held() -> Iterator[None]:
    """Within the block a stop signal waits: it raises ``StopSignal`` as the block ends, so that what the block does
    (a message read from or written to a pipe, which an exception half-way through would leave torn for every
    later one) is done whole. A no-op outside ``stop_on_signals`` and off the main thread."""
    handler = _active
    if handler is None or threading.current_thread() is not threading.main_thread():
        yield
        return
    handler.holding += 1
    try:
        yield
    finally:
        handler.holding -= 1
        if not handler.holding and handler.held is not None:
            signum, handler.held = handler.held, None
            if handler.raised is None:
                handler._raise(signum)


@contextmanager
def stop_on_signals() -> Iterator[_Handler]:
    """Within the block, SIGINT, SIGTERM and SIGHUP raise ``StopSignal`` once (main thread only; elsewhere a
    no-op). The previous handlers are restored on leaving, after the block's own ``finally`` clauses ran."""
    if threading.current_thread() is not threading.main_thread():
        yield _Handler()
        return
    global _active
    handler = _Handler()
    outer, _active = _active, handler
    previous = {s: signal.signal(s, handler) for s in STOP_SIGNALS}
    try:
        yield handler
    finally:
        for s, old in previous.items():
            signal.signal(s, old)
        _active = outer
