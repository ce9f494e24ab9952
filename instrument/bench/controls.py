"""The user's requests to a running sweep: :class:`SweepControls`, one object that the procedure and each of its
bench sessions share, set from any thread (the terminal UI's, a signal handler) and read between batches."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from bodebench.bench.events import SessionError
from bodebench.status import FaultKind

__all__ = ["ABORTED", "SweepControls"]

ABORTED = "aborted by the user"
"""What a run that the user's abort ended says."""


@dataclass
class SweepControls:
    """abort: stop the sweep (every case); skip: end the point being measured without a result (cleared as each
    point starts); pause: hold the analysis (on the realtime clock the drive goes on with its sine; on the lockstep
clock it waits for setpoints, which stop, and a drive watchdog with no heartbeat frame then trips after
frames.drive_watchdog_s); tolerance_percent: the tolerance of every point not
    yet started (None: the configuration's); remeasure: frequencies (Hz) to measure again, next, in the running
    session."""

    abort: threading.Event = field(default_factory=threading.Event)
    skip: threading.Event = field(default_factory=threading.Event)
    pause: threading.Event = field(default_factory=threading.Event)
    tolerance_percent: float | None = None
    remeasure: list[float] = field(default_factory=list)

    def request_abort(self) -> None:
        """Stop the sweep, every case of it."""
        self.abort.set()

    def request_skip(self) -> None:
        """End the point being measured without a result."""
        self.skip.set()

    def set_paused(self, paused: bool) -> None:
        """Pause or resume the analysis."""
        (self.pause.set if paused else self.pause.clear)()

    def set_tolerance(self, tolerance_percent: float) -> None:
        """The stopping tolerance (percent) of every point not yet started."""
        self.tolerance_percent = tolerance_percent

    def request_remeasure(self, frequency_hz: float) -> None:
        """Measure ``frequency_hz`` (Hz) again, next."""
        self.remeasure.append(frequency_hz)

    @property
    def aborted(self) -> bool:
        """Whether an abort was requested."""
        return self.abort.is_set()

    def check_abort(self) -> None:
        """SessionError (:attr:`FaultKind.ABORT`) where an abort was requested; nothing otherwise."""
        if self.aborted:
            raise SessionError(FaultKind.ABORT, ABORTED)
