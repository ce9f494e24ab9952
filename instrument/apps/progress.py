"""Plain progress display of a bench session for a terminal or a log: points done, frequency, periods, ETA."""

from __future__ import annotations

import logging
import sys
import time
from typing import TextIO

from bodebench.bench.events import (
    BusStatus,
    OverviewProgress,
    PlanGrew,
    PointFinished,
    PointProgress,
    PointStarted,
    SessionStarted,
)
from bodebench.core.eta import SweepTimer

logger = logging.getLogger(__name__)


class ProgressPrinter:
    """A session listener writing to ``stream`` (stderr): one refreshed line on a terminal, a line per point
    otherwise. The count includes the points an interrupted sweep already holds; the ETA is the sweep's
    :class:`~bodebench.core.eta.SweepTimer` estimate (the current point's periods to go by its rule's progress,
    the others' from the points measured, at the bench's measured seconds per period)."""

    def __init__(self, label: str, total: int, stream: TextIO | None = None, quiet: bool = False,
                 refresh_s: float = 0.25) -> None:
        self.label = label
        self.total = total
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = self.stream.isatty()
        self.refresh_s = refresh_s
        self.timer: SweepTimer | None = None
        self._eta_failed = False
        self._last = 0.0
        self._freq = 0.0
        self._bus = ""

    @property
    def done(self) -> int:
        return self.timer.done if self.timer is not None else 0

    def _eta(self) -> str:
        if self.timer is None or self._eta_failed:
            return "--"
        try:
            left = self.timer.remaining(time.monotonic())
        except Exception:  # noqa: BLE001 - an estimate that fails must not stop the measurement
            logger.exception("the time-to-go estimate failed; the progress line shows none from now on")
            self._eta_failed = True
            return "--"
        return "--" if left is None else f"{left:.0f} s"

    def _line(self, text: str, final: bool) -> None:
        if self.quiet:
            return
        if self.tty:
            self.stream.write("\r\033[K" + text + ("\n" if final else ""))
        elif final:
            self.stream.write(text + "\n")
        self.stream.flush()

    def __call__(self, event: object) -> None:
        now = time.monotonic()
        if isinstance(event, SessionStarted):
            self.timer = event.timer()
            self.total = self.timer.total
            already = f", {self.timer.done} already measured" if self.timer.done else ""
            self._line(f"{self.label}: {len(event.frequencies_hz)} points on {event.where}{already}", True)
        elif isinstance(event, OverviewProgress):
            self._line(f"{self.label}: the overview first, period {event.periods}", event.periods % 10 == 0)
        elif isinstance(event, PlanGrew):
            if self.timer is not None:
                self.timer.extend(event.frequencies_hz, event.extra_periods, event.max_periods)
                self.total = self.timer.total
            self._line(f"{self.label}: the plan adds {len(event.frequencies_hz)} frequencies", True)
            for f, reason in zip(event.frequencies_hz, event.reasons, strict=True):
                self._line(f"  + {f:.6g} Hz: {reason}", True)
        elif isinstance(event, PointStarted):
            self._freq = event.frequency_hz
            if self.timer is not None:
                self.timer.point_started(event.frequency_hz, now)
        elif isinstance(event, PointProgress):
            if self.timer is not None:
                self.timer.progress(event.periods, event.states, now)
            if now - self._last >= self.refresh_s:
                self._last = now
                gaps = f" ({event.gaps()})" if event.discarded else ""
                self._line(f"{self.label}: {self.done}/{self.total} done, {event.frequency_hz:g} Hz, "
                           f"period {event.periods}{gaps}, ETA {self._eta()}{self._bus}", False)
        elif isinstance(event, PointFinished):
            worst = max((p.periods for p in event.points), default=None)  # none: skipped or refused, not timed
            if self.timer is not None:
                self.timer.point_finished(self._freq, worst, now)
            if event.refused:
                self._line(f"{self.label}: {self.done}/{self.total} {self._freq:g} Hz REFUSED, not written: "
                           f"{event.refused}", True)
            elif event.skipped:
                self._line(f"{self.label}: {self.done}/{self.total} {self._freq:g} Hz skipped", True)
            else:
                state = "converged" if all(p.converged for p in event.points) else "NOT converged"
                discarded = max(p.periods_discarded for p in event.points)
                gaps = f" (+{discarded} discarded for gaps in the feedback)" if discarded else ""
                self._line(f"{self.label}: {self.done}/{self.total} {self._freq:g} Hz {state} in {worst} periods"
                           f"{gaps}, ETA {self._eta()}", True)
        elif isinstance(event, BusStatus):
            h = event.health.bus
            rejected = " ".join(f"{cause} {n}" for cause, n in h.rejected.items() if n)
            self._bus = (f", bus in {h.frames_in} out {h.frames_out} err {h.errors} lost {h.lost_samples}"
                         + (f" rejected {rejected}" if rejected else "")
                         + (f" dated by rhythm {h.dated_by_rhythm}" if h.dated_by_rhythm else ""))
        # a fault and the end of the session are the command's last line (with what the drive was sent), once
