"""From the session's thread to the UI: a listener that never waits and Textual messages.

The session calls :class:`SessionBridge` on its own thread. Rare events (a point starts or ends, a fault,
the end) are posted at once as :class:`SessionEvent` messages (``post_message`` only queues, it is
thread-safe). The frequent ones are coalesced for the UI's refresh timer: progress as a bounded queue of
small per-update summaries plus the latest full event (for the scope), bus health as the latest reading.
Every call is O(number of series) and takes no lock that the UI could hold.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from textual.message import Message

from bodebench.bench.events import BusStatus, Health, PointProgress
from bodebench.core.autointegration import SeriesState

#: progress summaries kept between two refreshes of the UI (older ones are dropped first)
PROGRESS_BACKLOG = 4096


class SessionEvent(Message):
    """A session event (SessionStarted, PointStarted, PointFinished, SessionFault, SessionEnded) of run ``run``."""

    def __init__(self, event: object, run: int) -> None:
        super().__init__()
        self.event = event
        self.run = run


class WorkerReport(Message):
    """The sweep thread of run ``run`` has ended: ``error`` (empty when none) says what went wrong, ``aborted``
    whether the user stopped it, ``saved`` the directory holding its points (empty: none)."""

    def __init__(self, run: int, completed: bool, error: str, saved: str, aborted: bool = False) -> None:
        super().__init__()
        self.run = run
        self.completed = completed
        self.error = error
        self.saved = saved
        self.aborted = aborted


@dataclass(frozen=True)
class ProgressSummary:
    """What the convergence plot and the ETA need from one PointProgress; ``at``: when it came (monotonic s)."""

    index: int
    periods: int
    states: tuple[SeriesState, ...]
    at: float


class SessionBridge:
    """The session listener of one run; ``post`` queues a message to the app (thread-safe, non-blocking)."""

    def __init__(self, post: Callable[[Message], object], run: int) -> None:
        self._post = post
        self.run = run
        self.progress: deque[ProgressSummary] = deque(maxlen=PROGRESS_BACKLOG)
        self.latest_progress: PointProgress | None = None
        self.latest_health: tuple[float, Health] | None = None
        self.calls = 0

    def __call__(self, event: object) -> None:
        self.calls += 1
        if isinstance(event, PointProgress):
            self.progress.append(ProgressSummary(event.index, event.periods, event.states, time.monotonic()))
            self.latest_progress = event
        elif isinstance(event, BusStatus):
            self.latest_health = (time.monotonic(), event.health)
        else:
            self._post(SessionEvent(event, self.run))
