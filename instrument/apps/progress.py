"""Plain progress display of a bench session for a terminal or a log: points done, frequency, periods, ETA."""

from __future__ import annotations

import sys
import time
from typing import TextIO

from bodebench.bench.events import BusStatus, PointFinished, PointProgress, PointStarted, SessionStarted


class ProgressPrinter:
    """A session listener writing to ``stream`` (stderr): one refreshed line on a terminal, a line per point
    otherwise. ETA assumes the remaining points take as long as the average so far."""

    def __init__(self, label: str, total: int, stream: TextIO | None = None, quiet: bool = False,
                 refresh_s: float = 0.25) -> None:
        self.label = label
        self.total = total
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = self.stream.isatty()
        self.refresh_s = refresh_s
        self.done = 0
        self.started = time.monotonic()
        self._last = 0.0
        self._freq = 0.0
        self._bus = ""

    def _eta(self) -> str:
        if not self.done:
            return "--"
        left = (time.monotonic() - self.started) / self.done * (self.total - self.done)
        return f"{left:.0f} s"

    def _line(self, text: str, final: bool) -> None:
        if self.quiet:
            return
        if self.tty:
            self.stream.write("\r\033[K" + text + ("\n" if final else ""))
        elif final:
            self.stream.write(text + "\n")
        self.stream.flush()

    def __call__(self, event: object) -> None:
        if isinstance(event, SessionStarted):
            self.started = time.monotonic()
            self._line(f"{self.label}: {len(event.frequencies_hz)} points on {event.where}", True)
        elif isinstance(event, PointStarted):
            self._freq = event.frequency_hz
        elif isinstance(event, PointProgress):
            now = time.monotonic()
            if now - self._last >= self.refresh_s:
                self._last = now
                gaps = f" ({event.discarded} discarded for gaps)" if event.discarded else ""
                self._line(f"{self.label}: {self.done}/{self.total} done, {event.frequency_hz:g} Hz, "
                           f"period {event.periods}{gaps}, ETA {self._eta()}{self._bus}", False)
        elif isinstance(event, PointFinished):
            self.done += 1
            if event.refused:
                self._line(f"{self.label}: {self.done}/{self.total} {self._freq:g} Hz REFUSED, not written: "
                           f"{event.refused}", True)
            elif event.skipped:
                self._line(f"{self.label}: {self.done}/{self.total} {self._freq:g} Hz skipped", True)
            else:
                worst = max(p.periods for p in event.points)
                state = "converged" if all(p.converged for p in event.points) else "NOT converged"
                discarded = max(p.periods_discarded for p in event.points)
                gaps = f" (+{discarded} discarded for gaps in the feedback)" if discarded else ""
                self._line(f"{self.label}: {self.done}/{self.total} {self._freq:g} Hz {state} in {worst} periods"
                           f"{gaps}, ETA {self._eta()}", True)
        elif isinstance(event, BusStatus):
            h = event.health.bus
            rejected = " ".join(f"{cause} {n}" for cause, n in h.rejected.items() if n)
            self._bus = (f", bus in {h.frames_in} out {h.frames_out} err {h.errors} lost {h.lost_samples}"
                         + (f" rejected {rejected}" if rejected else ""))
        # a fault and the end of the session are the command's last line (with what the drive was sent), once
