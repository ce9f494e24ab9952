"""Statistics the worker keeps for its Health reports: round-trip delays, the send-time error histogram, and
the assembly of the Health message."""

from __future__ import annotations

import math
import statistics
import time
from collections import deque

import numpy as np

from bodebench.bench.worker.messages import Health, PacingStats
from bodebench.bench.worker.timebase import TimeBase
from bodebench.drivers.driver import BusHealth

ROUND_TRIPS_KEPT = 256
"""Round trips kept (the latest few, so that their median stays cheap)."""
ECHOES_KEPT = 256
"""Recent setpoint values whose echo is looked for."""


class SendErrorHistogram:
    """Send-time errors (s) binned for percentiles at constant cost per tick: 1 us bins up to 2 ms, 100 us bins
    up to 100 ms, one bin beyond; the largest error is kept exactly."""

    FINE_S = 1e-6
    FINE_BINS = 2000
    COARSE_S = 1e-4
    COARSE_BINS = 980

    def __init__(self) -> None:
        self.counts = np.zeros(self.FINE_BINS + self.COARSE_BINS + 1, dtype=np.int64)
        self.count = 0
        self.max = 0.0
        self._fine_top = self.FINE_BINS * self.FINE_S

    def add(self, error_s: float) -> None:
        """Count one error (its magnitude)."""
        e = abs(error_s)
        if e < self._fine_top:
            i = int(e * 1e6)
        else:
            i = min(self.FINE_BINS + int((e - self._fine_top) * 1e4), self.FINE_BINS + self.COARSE_BINS)
        self.counts[i] += 1
        self.count += 1
        if e > self.max:
            self.max = e

    def percentile(self, q: float) -> float:
        """The q-th percentile (s): the centre of the bin holding it (the exact max in the last bin), never above
        the max; NaN when empty."""
        if not self.count:
            return math.nan
        rank = max(1, math.ceil(q / 100.0 * self.count))
        i = int(np.searchsorted(np.cumsum(self.counts), rank))
        if i < self.FINE_BINS:
            centre = (i + 0.5) * self.FINE_S
        elif i < self.FINE_BINS + self.COARSE_BINS:
            centre = self._fine_top + (i - self.FINE_BINS + 0.5) * self.COARSE_S
        else:
            centre = self.max
        return min(centre, self.max)


class RoundTrips:
    """Round-trip delays (s), the latest few: lockstep, setpoint to its reply; realtime, setpoint to the first
    sample that echoes it (drives with a setpoint_echo channel)."""

    def __init__(self) -> None:
        self.recent: deque[float] = deque(maxlen=ROUND_TRIPS_KEPT)
        self._sent_at: dict[float, float] = {}  # realtime: recent setpoint values (float32) -> wall time sent (s)
        self._sent_order: deque[float] = deque()

    def add(self, delay_s: float) -> None:
        """One round trip (s)."""
        self.recent.append(delay_s)

    def median(self) -> float:
        """Median of the round trips kept (s); NaN before the first."""
        return statistics.median(self.recent) if self.recent else math.nan

    def latest(self, n: int) -> list[float]:
        """The latest ``n`` round trips (s), oldest first."""
        return list(self.recent)[-n:]

    def sent(self, u: float) -> None:
        """Realtime with an echo channel: a setpoint value going out now (a value already waiting keeps its
        first time)."""
        key = float(np.float32(u))
        if key not in self._sent_at:
            self._sent_at[key] = time.time()
            self._sent_order.append(key)
            if len(self._sent_order) > ECHOES_KEPT:
                self._sent_at.pop(self._sent_order.popleft(), None)

    def echoed(self, echo: float, receive_time: float) -> None:
        """Realtime round trip: a sample received at ``receive_time`` (wall clock, s) whose echoed setpoint is a
        value sent recently came back this long after that value went out (its first echo only; values the drive
        cannot echo exactly never match)."""
        sent = self._sent_at.pop(float(np.float32(echo)), None)
        if sent is not None and 0.0 <= receive_time - sent < 1.0:
            self.recent.append(receive_time - sent)


def health_report(bus: BusHealth, round_trips: RoundTrips, pacing: PacingStats | None, tick: int,
                  timebase: TimeBase, invalid_samples: int, missed_replies: int) -> Health:
    """The Health message: a copy of the bus health, the median round trip, the pacing statistics (None on the
    lockstep clock), the next tick and the sample counts."""
    return Health(bus.snapshot(), round_trips.median(), pacing, tick, timebase.time_conflicts, invalid_samples,
                  missed_replies, timebase.counter_anomalies)
