"""Pacing: when each setpoint goes out, one per tick, on one of two clocks.

- lockstep (``LockstepPacing``): the drive answers every setpoint and the next goes out once the reply is in, or
  counted lost; the worker sends as far as the session's credit allows (and through a sine's ramp in and first
  period unasked).
- realtime (``RealtimePacing``): setpoints go out on the wall clock at the control rate, a sleep then a short
  busy-wait before each deadline, in a process prepared for it (``prepare_realtime``). The send-time error
  against the schedule is the pacing statistics of the Health reports.
"""

from __future__ import annotations

import gc
import math
import statistics
import threading
import time

from bodebench.bench.worker.health import RoundTrips, SendErrorHistogram
from bodebench.bench.worker.messages import PacingStats, StartSine
from bodebench.bench.worker.safety import Watchdog
from bodebench.drivers.driver import Driver, FeedbackSample
from bodebench.drivers.scheduling import keep_to, lower_timer_slack, pacing_cpu, request_fifo

SPIN_S = 2e-4
"""Realtime clock: the worker sleeps until this long (at most 0.4 periods) before a tick's deadline and
busy-waits the rest, since a sleep can end this late. Some sleep every period matters under SCHED_FIFO: a task
that never sleeps is stopped for 50 ms a second by the kernel's realtime throttling."""
MIN_SLEEP_S = 2e-5
"""Realtime clock: shorter sleeps are not worth their wake-up delay."""

WORKER_PRIORITY = 20
"""SCHED_FIFO priority the worker process asks for on the realtime clock (above every normal task and a simulated
drive, below the kernel's interrupt threads at 50)."""

SUSPENDED_S = 0.1
"""Realtime clock: a loop this far (s) behind its schedule was suspended; it resumes from now."""
TYPICAL_ROUND_TRIPS = 64
"""Lockstep: the latest round trips whose median sets how long a reply is waited for."""
MIN_REPLY_WAIT_S = 2e-3
"""Lockstep: the shortest wait (s) for a setpoint's reply."""
RECEIVE_SLICE_S = 0.05
"""Lockstep: longest single receive (s) while a reply is awaited, so the watchdog is looked at in between."""


def prepare_realtime(cpu: int | None) -> str | None:
    """Ready this process or thread for the realtime clock: garbage collector frozen and disabled, timer slack
    lowered and, in a process of its own, SCHED_FIFO and the pacing CPU (``cpu``; None: the last it may use).
    Returns what the OS granted ("SCHED_FIFO 20, CPU 1"), or None when nothing was granted or asked for."""
    gc.collect()
    gc.freeze()
    gc.disable()
    lower_timer_slack()
    if threading.current_thread() is not threading.main_thread():  # a thread of the session's process
        return None
    granted = [f"SCHED_FIFO {WORKER_PRIORITY}"] if request_fifo(WORKER_PRIORITY) else []
    chosen = pacing_cpu(cpu)
    if chosen is not None and keep_to({chosen}):
        granted.append(f"CPU {chosen}")
    return ", ".join(granted) or None


class LockstepPacing:
    """Lockstep clock: the session's credit and the wait for each setpoint's reply."""

    def __init__(self, period_s: float, reply_timeout_s: float) -> None:
        """period_s: tick period (s); reply_timeout_s: the longest a reply is waited for once replies are
        coming."""
        self.h = period_s
        self.reply_timeout_s = reply_timeout_s
        self.credit = -1  # the last tick that may be sent
        self.missed_replies = 0  # setpoints whose reply did not come in time

    def grant(self, until_tick: int) -> None:
        """The session's credit: setpoints up to and including ``until_tick``."""
        self.credit = max(self.credit, until_tick)

    def grant_ramp(self, start: StartSine, tick: int) -> None:
        """A sine starting at ``tick``: its ramp in and first period need no asking."""
        self.grant(tick + math.ceil((start.ramp_in_periods + 1) / (start.frequency_hz * self.h)) + 1)

    def out_of_credit(self, tick: int) -> bool:
        """``tick`` may not be sent yet."""
        return tick > self.credit

    def reply_wait(self, first: bool, round_trips: RoundTrips, first_s: float) -> float:
        """How long (s) to wait for a setpoint's reply: ``first_s`` for the first (the drive may still be
        starting), after that a few typical round trips, at most reply_timeout_s."""
        if first:
            return first_s
        typical = round_trips.latest(TYPICAL_ROUND_TRIPS)
        return min(self.reply_timeout_s,
                   max(MIN_REPLY_WAIT_S, 8 * statistics.median(typical) if typical else MIN_REPLY_WAIT_S))

    def await_reply(self, driver: Driver, wait_s: float, watchdog: Watchdog) -> list[FeedbackSample]:
        """The samples answering the setpoint just sent; [] when its reply is lost (counted): nothing within
        ``wait_s`` (s), or a frame of it cut short on the line (it will not complete). The watchdog is looked at
        while waiting."""
        deadline = time.monotonic() + wait_s
        broken = driver.health.broken_frames
        while True:
            samples = driver.receive(max(0.0, min(RECEIVE_SLICE_S, deadline - time.monotonic())))
            if samples:
                return samples
            watchdog.check()
            if time.monotonic() >= deadline or driver.health.broken_frames != broken:
                self.missed_replies += 1
                return []


class RealtimePacing:
    """Realtime clock: the schedule of tick deadlines (``time.perf_counter``, s) and the send-time error."""

    def __init__(self, period_s: float) -> None:
        self.h = period_s
        self.spin_s = min(SPIN_S, 0.4 * period_s)  # busy-wait this long before each tick
        self.scheduled = 0.0  # deadline of the next tick
        self.send_errors = SendErrorHistogram()
        self.overruns = 0  # ticks sent later than a period after their deadline
        self.scheduling = "normal priority"  # what the OS granted the loop

    def start(self) -> None:
        """The first tick is due a period from now."""
        self.scheduled = time.perf_counter() + self.h

    def wait_for_tick(self) -> float:
        """Sleep most of the way to the tick's deadline, busy-wait the rest (sleeps end late); returns the time
        the wait ended."""
        scheduled = self.scheduled
        wait = scheduled - time.perf_counter()
        if wait > self.spin_s + MIN_SLEEP_S:
            time.sleep(wait - self.spin_s)
        while time.perf_counter() < scheduled:
            pass
        return time.perf_counter()

    def sent(self, at: float) -> None:
        """The tick's setpoint went out at ``at`` (``time.perf_counter``, s): its send-time error is counted."""
        self.send_errors.add(at - self.scheduled)
        if at - self.scheduled > self.h:
            self.overruns += 1

    def next_tick(self) -> int:
        """Move the schedule to the next tick; returns the ticks skipped (0 unless the loop was suspended: it
        resumes from now, skipping the ticks missed so that tick * period stays the time of the schedule, since
        the drive's clock went on and the session times points by ticks)."""
        self.scheduled += self.h
        behind = time.perf_counter() - self.scheduled
        if behind <= SUSPENDED_S:
            return 0
        missed = math.floor(behind / self.h) + 1
        self.scheduled += missed * self.h
        return missed

    def stats(self) -> PacingStats | None:
        """Pacing statistics so far (None before the first tick)."""
        e = self.send_errors
        if not e.count:
            return None
        return PacingStats(e.percentile(50), e.percentile(99), e.max, e.count, self.overruns, self.scheduling)
