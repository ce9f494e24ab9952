"""The time base: each feedback sample's session time (s), from its counter, its timestamp or its receive time.

The driver hands over samples with the counter and timestamp already unwrapped (monotonic). The time base
aligns them once, on the first sample, to the session's time (tick * period); on the lockstep clock the
alignment is a whole number of periods, and a sample dated too late for the setpoint it answers is a counter
anomaly (dropped; after three in a row the alignment follows the counter's jump). A sample whose time does not
increase is a time conflict (dropped).
"""

from __future__ import annotations

import math
import time

from bodebench.bench.worker.safety import Trip
from bodebench.drivers.driver import FeedbackSample
from bodebench.status import FaultKind

ANOMALIES_TO_REALIGN = 3
"""Counter anomalies in a row after which the drive's counter is taken to have jumped for good."""


class TimeBase:
    """Session times of feedback samples on the time base ``source`` (counter, timestamp or receive); period_s:
    the tick period (s)."""

    def __init__(self, source: str, period_s: float) -> None:
        self.source = source
        self.h = period_s
        self.wall0 = 0.0  # wall time (s) of session time zero, for receive times
        self.offset: float | None = None  # s: session time = raw time - offset
        self.last_t = -math.inf
        self.time_conflicts = 0  # samples dropped because their time did not increase
        self.counter_anomalies = 0  # lockstep samples whose counter disagreed with the setpoint they answer
        self._anomalies_in_row = 0

    def start(self) -> None:
        """Session time zero is now (wall clock)."""
        self.wall0 = time.time()

    @property
    def aligned(self) -> bool:
        """The first sample has set the alignment."""
        return self.offset is not None

    def place(self, s: FeedbackSample, answered_tick: int | None) -> float | None:
        """The session time (s) of ``s``, or None when it is dropped (a counter anomaly or a time conflict).
        answered_tick: lockstep, the tick whose setpoint ``s`` answers (None: realtime)."""
        t = self.time_of(s, answered_tick)
        if answered_tick is not None and self._counter_anomaly(t, answered_tick):
            return None
        if t <= self.last_t:  # receive times of samples read in one burst: keep the first only
            self.time_conflicts += 1
            return None
        self.last_t = t
        return t

    def time_of(self, s: FeedbackSample, answered_tick: int | None) -> float:
        """Session time of a sample: its counter, timestamp or receive time, aligned once on the first sample."""
        base = self.source
        if base == "counter" and s.counter is not None:
            raw = s.counter * self.h
        elif base == "timestamp" and s.timestamp is not None:
            raw = s.timestamp
        else:
            raw = s.receive_time - self.wall0
            if base != "receive":
                raise Trip(FaultKind.BUS, f"feedback without the {base} the time base needs")
        if self.offset is None:
            if answered_tick is not None:
                # lockstep: the controller's clock runs a whole number of periods ahead of the session's,
                # so round the offset to periods (a jittered first sample must not shift the whole timeline)
                self.offset = round((raw - (answered_tick + 1) * self.h) / self.h) * self.h
            else:
                self.offset = raw - (s.receive_time - self.wall0)
        return raw - self.offset

    def _counter_anomaly(self, t: float, answered_tick: int) -> bool:
        """Lockstep: a sample dated more than half a period after the setpoint just sent could have answered is a
        counter fault (dropped, counted); after three in a row the drive's counter has jumped for good and the time
        base is realigned."""
        expected = (answered_tick + 1) * self.h
        if t <= expected + 0.5 * self.h:  # on time, or a late reply to an earlier setpoint (its time is right)
            self._anomalies_in_row = 0
            return False
        self.counter_anomalies += 1
        self._anomalies_in_row += 1
        if self._anomalies_in_row >= ANOMALIES_TO_REALIGN:
            self.offset = (self.offset or 0.0) + round((t - expected) / self.h) * self.h
            self._anomalies_in_row = 0
        return True
