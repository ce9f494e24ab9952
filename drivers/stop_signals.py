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

__all__ = ["STOP_SIGNALS", "StopSignal", "stop_on_signals"]

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

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.raised is not None:
            self.ignored += 1  # the safe shutdown of the first one is under way
            return
        self.raised = StopSignal(signum)
        raise self.raised


@contextmanager
def stop_on_signals() -> Iterator[_Handler]:
    """Within the block, SIGINT, SIGTERM and SIGHUP raise ``StopSignal`` once (main thread only; elsewhere a
    no-op). The previous handlers are restored on leaving, after the block's own ``finally`` clauses ran."""
    if threading.current_thread() is not threading.main_thread():
        yield _Handler()
        return
    handler = _Handler()
    previous = {s: signal.signal(s, handler) for s in STOP_SIGNALS}
    try:
        yield handler
    finally:
        for s, old in previous.items():
            signal.signal(s, old)
