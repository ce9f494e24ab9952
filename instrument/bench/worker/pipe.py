"""The worker's end of its pipe to the session: commands in, reports out."""

from __future__ import annotations

import select
from multiprocessing.connection import Connection
from typing import Callable

from bodebench.bench.worker.safety import Trip
from bodebench.status import FaultKind


class SessionPipe:
    """Messages to and from the session. A session that has gone away is an error (``Trip``) while the worker
    runs; on its way out the worker reports what it can and ignores the rest."""

    def __init__(self, conn: Connection) -> None:
        self.conn = conn

    def post(self, message: object) -> None:
        """Send ``message``; Trip (error) when the session is gone."""
        try:
            self.conn.send(message)
        except (OSError, EOFError, BrokenPipeError):
            raise Trip(FaultKind.ERROR, "session went away") from None

    def report(self, message: object) -> None:
        """Send ``message`` if the session can still receive it."""
        try:
            self.conn.send(message)
        except (OSError, EOFError, BrokenPipeError, ValueError):
            pass

    def can_take(self) -> bool:
        """Whether a message to the session goes out now without blocking (its end of the pipe has room)."""
        try:
            return bool(select.select([], [self.conn.fileno()], [], 0)[1])
        except (OSError, ValueError):
            return True  # post reports a pipe that is gone

    def receive(self, handle: Callable[[object], None], timeout_s: float = 0.0) -> None:
        """Pass every command waiting to ``handle``, after waiting up to ``timeout_s`` (s) for the first; Trip
        (error) when the session is gone."""
        try:
            while self.conn.poll(timeout_s):
                handle(self.conn.recv())
                timeout_s = 0.0
        except (OSError, EOFError):
            raise Trip(FaultKind.ERROR, "session went away") from None
