"""The bus worker: paces setpoints, talks to the drive, enforces the safety limits.

It runs apart from the analysis (its own process on the realtime clock, with
the garbage collector frozen and timer slack lowered; a thread is enough on
the lockstep clock) and exchanges only small typed messages with the session
over a pipe: commands in, sample batches and bus health out. Whatever ends it
(a stop, an abort, a trip, an exception, Ctrl-C, the session vanishing), its
last act on the bus is a zero setpoint and, where the layout has one, the
disable frame (a CANopen drive: quick stop, disable voltage, NMT
pre-operational).
"""

from __future__ import annotations

import contextlib
import gc
import math
import select
import statistics
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

import numpy as np

from bodebench.bench.events import Health, PacingStats, SessionEnded
from bodebench.core.autointegration import MAX_COEFFICIENT
from bodebench.drivers.driver import Driver, FeedbackSample
from bodebench.drivers.errors import DriveFaultError, DriverError
from bodebench.drivers.layout import SETPOINT_ECHO
from bodebench.drivers.scheduling import SPIN_S, keep_to, lower_timer_slack, pacing_cpu, request_fifo, sleep_until
from bodebench.drivers.stop_signals import StopSignal, signals_held, stop_on_signals

if TYPE_CHECKING:
    from bodebench.drivers.layout import Layout
    from bodebench.io.tables import BenchConfig, SafetyConfig

MAX_SLEW_STEPS = 10_000
"""The most ticks the way out slews the setpoint to zero over, under safety.max_rate (after them it jumps)."""
ZERO_SETPOINTS = 3
"""Setpoints of zero the worker sends on its way out, after any slew to zero and before the disable frame: one lost
frame still leaves the drive at zero."""

# ------------------------------------------------------------------------------------------- messages to the worker


@dataclass(frozen=True)
class StartSine:
    """Ramp the running sine out (if any), then start ``amplitude*sin(2 pi f t)`` ramped in over whole periods."""

    frequency_hz: float
    amplitude: float
    ramp_in_periods: int
    ramp_out_periods: int


@dataclass(frozen=True)
class StartTable:
    """Ramp the running program out (if any), then send ``setpoints`` over and over, one a tick, ramped in over
    whole repetitions: a periodic excitation such as the overview's multisine (input units)."""

    setpoints: tuple[float, ...]
    ramp_in_periods: int
    ramp_out_periods: int


@dataclass(frozen=True)
class FinishSine:
    """Ramp the running program out, then send zero setpoints until the next start (a point measured, its dating
    still to be checked: ``Samples.dating_unchecked``)."""


@dataclass(frozen=True)
class Credit:
    """Lockstep: setpoints may be sent up to and including tick ``until_tick``."""

    until_tick: int


@dataclass(frozen=True)
class Stop:
    """End the session: ramp out (``abort``: slew straight to zero), zero setpoint, disable, exit."""

    reason: str
    abort: bool = False


# ----------------------------------------------------------------------------------------- messages from the worker


@dataclass(frozen=True)
class Ready:
    """The bus is open and the drive enabled; ``channels`` are the feedback columns of every Samples batch;
    ``drive_start``: what the driver did and measured to enable the drive, in words (empty for the frame layouts)."""

    channels: tuple[str, ...]
    period_s: float
    drive_start: str = ""


@dataclass(frozen=True)
class SineStarted:
    """The setpoint of tick ``tick`` (session time tick * period) is the new sine's phase zero."""

    frequency_hz: float
    tick: int


@dataclass(frozen=True)
class Samples:
    """Feedback samples: session time t (s), values (n, channels), and the setpoint sent at each sample's tick;
    ``held``: realtime clock, the stretches (start, end) of session time (s) since the last batch in which the drive
    held a stale setpoint, because one went out more than a control period late or the pacing skipped ticks;
    ``dating_unchecked``: samples returned so far may be dated wrongly until the driver has checked its link on an
    idle tick (``Driver.dating_unchecked``)."""

    t: np.ndarray
    values: np.ndarray
    setpoint: np.ndarray
    last_tick: int
    held: tuple[tuple[float, float], ...] = ()
    dating_unchecked: bool = False


@dataclass(frozen=True)
class Fault:
    """A trip or error; the worker has already zeroed and disabled the drive. kind: watchdog, feedback_limit,
    bus, drive, error."""

    kind: str
    message: str


@dataclass(frozen=True)
class Stopped:
    """The worker's last message: the last setpoint that went out, whether a zero setpoint went out after every
    other (``zero_sent``), whether the disable frame went out (a CANopen drive: whether it was seen disabled), how
    many frames reached the bus at all, and what the driver did to take the drive out of operation beyond the
    disable frame (``shutdown``, in words; empty for the frame layouts), and why the bus log stopped recording
    before the end (``log_failure``; "" when it did not, or there was none)."""

    reason: str
    last_setpoint: float
    disabled: bool
    zero_sent: bool = False
    frames_out: int = 0
    shutdown: str = ""
    log_failure: str = ""


# --------------------------------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class Limits:
    """Safety limits: |setpoint| <= max_amplitude, slew <= max_rate (units/s, None: none), feedback windows
    {channel: (low, high)}, watchdog_s without feedback."""

    max_amplitude: float
    max_rate: float | None
    feedback_limits: dict[str, tuple[float, float]] = field(default_factory=dict)
    watchdog_s: float = 0.5


@dataclass(frozen=True)
class WorkerSpec:
    """Everything the worker needs, picklable: how to open the link (``open_link`` returns (port, layout,
    resources to close)), the pacing, the time base and the limits."""

    open_link: Any  # a picklable callable () -> tuple[FramePort, Layout, list[closeable]]; with a make_driver(port,
    # layout) method where the drive needs a driver of its own (CANopen)
    rate_hz: float
    clock: str
    timebase: str
    limits: Limits
    batch_s: float = 0.01
    health_s: float = 0.1
    reply_timeout_s: float = 0.05  # lockstep: how long a setpoint's reply may take before it counts as lost
    pacing_cpu: int | None = None  # realtime: the CPU the worker process keeps to (None: the last it may use)


def worker_spec(open_link: Any, bench: BenchConfig, safety: SafetyConfig) -> WorkerSpec:
    """The worker's spec for a bench case: its link (``open_link``), [bench]'s pacing and time base, [safety]'s
    limits."""
    limits = Limits(safety.max_amplitude, safety.max_rate,
                    {k: (float(v[0]), float(v[1])) for k, v in safety.feedback_limits.items()}, safety.watchdog_s)
    return WorkerSpec(open_link, bench.rate_hz, bench.clock, bench.timebase, limits, batch_s=bench.batch_ms / 1000.0,
                      reply_timeout_s=bench.reply_timeout_s, pacing_cpu=bench.pacing_cpu)


def session_ended(reason: str, completed: bool, stopped: Stopped | None, layout: Layout) -> SessionEnded:
    """How a run of the worker ended, from the worker's last report (None: it did not report) and the layout's
    disable frame and drive watchdog."""
    return SessionEnded(reason, completed, stopped.last_setpoint if stopped else math.nan,
                        stopped.disabled if stopped else False, stopped.zero_sent if stopped else False,
                        stopped.frames_out if stopped else 0, stopped is not None, layout.disable is not None,
                        layout.drive_watchdog_s, stopped.shutdown if stopped else "")


class _Trip(Exception):
    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


# ---------------------------------------------------------------------------------------------- the sine program


class SineProgram:
    """Setpoint at each tick: a sine with whole-period linear ramps in and out, then zero.

    tick0: the tick of phase zero; period_s: tick period (s).
    """

    def __init__(self, frequency_hz: float, amplitude: float, ramp_in_periods: int, ramp_out_periods: int,
                 tick0: int, period_s: float) -> None:
        self.f = frequency_hz
        self.amplitude = amplitude
        self.ramp_in = ramp_in_periods
        self.ramp_out = ramp_out_periods
        self.tick0 = tick0
        self.h = period_s
        self.out_tick: int | None = None

    def finish(self, tick: int, at_once: bool = False) -> None:
        """Start ramping out at ``tick`` (``at_once``: no ramp)."""
        if self.out_tick is None:
            self.out_tick = tick
            if at_once:
                self.ramp_out = 0

    def finished(self, tick: int) -> bool:
        if self.out_tick is None:
            return False
        return self.ramp_out == 0 or (tick - self.out_tick) * self.h * self.f >= self.ramp_out

    def ramping(self, tick: int) -> bool:
        """Whether ``tick`` is in a ramp (in or out), or before or after the program."""
        return self.out_tick is not None or (tick - self.tick0) * self.h * self.f < self.ramp_in

    def value(self, tick: int) -> float:
        t = (tick - self.tick0) * self.h
        if t < 0 or self.finished(tick):
            return 0.0
        gain = 1.0 if self.ramp_in == 0 else min(1.0, t * self.f / self.ramp_in)
        if self.out_tick is not None and self.ramp_out:
            gain *= max(0.0, 1.0 - (tick - self.out_tick) * self.h * self.f / self.ramp_out)
        return self.amplitude * gain * math.sin(2.0 * math.pi * self.f * t)


class TableProgram(SineProgram):
    """Setpoint at each tick: a table of setpoints repeated, one a tick, with whole-repetition linear ramps in and
    out, then zero. Its frequency is that of the repetition, 1 / (len(table) * period_s)."""

    def __init__(self, setpoints: tuple[float, ...], ramp_in_periods: int, ramp_out_periods: int, tick0: int,
                 period_s: float) -> None:
        super().__init__(1.0 / (len(setpoints) * period_s), 1.0, ramp_in_periods, ramp_out_periods, tick0, period_s)
        self.table = setpoints

    def finished(self, tick: int) -> bool:
        if self.out_tick is None:
            return False
        return self.ramp_out == 0 or tick - self.out_tick >= self.ramp_out * len(self.table)

    def value(self, tick: int) -> float:
        n = tick - self.tick0
        if n < 0 or self.finished(tick):
            return 0.0
        size = len(self.table)
        gain = 1.0 if self.ramp_in == 0 else min(1.0, n / (self.ramp_in * size))
        if self.out_tick is not None and self.ramp_out:
            gain *= max(0.0, 1.0 - (tick - self.out_tick) / (self.ramp_out * size))
        return gain * self.table[n % size]


# ------------------------------------------------------------------------------------------------------ the loop


COMMAND_POLL_S = 1e-3
"""The pacing loop looks for the session's commands (credit, a new sine, stop) at most this often (s): a look at
the pipe costs more than a tick's own work, and a stop waits at most this long for it."""

REPLY_WAIT_TICKS = 64
"""Lockstep clock: the wait for a reply is set from the median of this many latest round trips, renewed as often."""

WORKER_PRIORITY = 20
"""SCHED_FIFO priority the worker process asks for on the realtime clock (above every normal task and a simulated
drive, below the kernel's interrupt threads at 50)."""


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


class MessagePipe:
    """One end of the pipe between the session and the worker. A stop signal never tears a message: it waits until
    the message being sent or received is through (``signals_held``), so the messages after it, the worker's
    report of how it left the drive among them, still read. A message whose reception the signal then interrupts
    is kept for the next ``recv``."""

    def __init__(self, conn: Connection) -> None:
        self._conn = conn
        self._kept: list[object] = []

    def send(self, message: object) -> None:
        with signals_held():
            self._conn.send(message)

    def recv(self) -> object:
        if not self._kept:
            with signals_held():
                self._kept.append(self._conn.recv())
        return self._kept.pop()

    def poll(self, timeout: float = 0.0) -> bool:
        """Whether a message is waiting, after up to ``timeout`` s."""
        return bool(self._kept) or self._conn.poll(timeout)

    def fileno(self) -> int:
        return self._conn.fileno()

    def close(self) -> None:
        self._conn.close()


DROPPED = ("samples invalid (NaN, inf, beyond any sensor)", "samples with a counter out of turn",
           "samples whose time did not increase", "repeated or stale counters", "incomplete samples",
           "frames rejected or broken", "counter restarts", "replies not in time")
"""What the watchdog's trip counts as dropped between two valid samples (:meth:`BusWorker._counts`)."""


class BusWorker:
    """The pacing loop. ``run`` never raises: every way out zeroes the drive and ends with ``Stopped``."""

    def __init__(self, spec: WorkerSpec, conn: MessagePipe) -> None:
        self.spec = spec
        self.conn = conn
        self.h = 1.0 / spec.rate_hz
        self.lockstep = spec.clock == "lockstep"
        self.tick = 0                 # next setpoint's tick
        self.credit = -1              # lockstep: last tick allowed
        self.program: SineProgram | None = None
        self.pending: StartSine | StartTable | None = None
        self.stopping: Stop | None = None
        self.last_sent = 0.0
        self.driver: Driver | None = None
        self.resources: list[Any] = []
        self.last_feedback = 0.0
        self.offset: float | None = None     # session time = raw time - offset
        self.wall0 = 0.0
        # s, the latest (few, so their median stays cheap); lockstep: setpoint to its reply; realtime: to its echo
        self.round_trips: deque[float] = deque(maxlen=256)
        # lockstep: how long a reply is waited for (s), until this tick
        self._reply_wait = 2e-3
        self._reply_wait_until = 0
        self._echo_index: int | None = None  # realtime: the setpoint_echo channel, when the drive has one
        self._sent_at: dict[float, float] = {}  # realtime: recent setpoint values (float32) -> wall time sent
        self._sent_order: deque[float] = deque()
        self.send_errors = SendErrorHistogram()
        self.overruns = 0
        # realtime: busy-wait this long before each tick (scheduling.SPIN_S, at most 0.4 periods: some sleep every
        # period matters under SCHED_FIFO, where a task that never sleeps is stopped 50 ms a second by the kernel)
        self.spin_s = min(SPIN_S, 0.4 * self.h)
        self.scheduling = "normal priority"  # realtime: what the OS granted the loop
        self._t: list[float] = []
        self._v: list[tuple[float, ...]] = []
        self._u: list[float] = []
        self._held: list[tuple[float, float]] = []  # realtime: stretches of session time with a stale setpoint
        self._credit_shipped = -1  # lockstep: the credit whose end the session has been told of
        self._last_t = -math.inf
        self.time_conflicts = 0  # samples dropped because their time did not increase
        self.invalid_samples = 0  # samples with NaN or infinite values, dropped
        self.missed_replies = 0  # lockstep setpoints whose reply did not come within reply_timeout_s
        self.counter_anomalies = 0  # lockstep samples whose counter disagreed with the setpoint they answer
        self._anomalies_in_row = 0
        self._heartbeat_s = 0.0  # s between heartbeats this loop sends (0: none, or the port repeats it itself)
        self._next_heartbeat = 0.0
        # monotonic time of the last frame this loop sent that feeds the drive's watchdog (a setpoint, a heartbeat);
        # None while nothing is known of it: before the enable frame, or where the port repeats the heartbeat itself
        self._last_fed: float | None = None
        # the counts when the last valid sample came, and the longest time (s) between two turns of this loop since:
        # a watchdog trip says what happened in the silence (setpoints unanswered, replies dropped, a stalled host)
        self._at_last_feedback: tuple[int, ...] = (0,) * (2 + len(DROPPED))
        self._turn_at = 0.0
        self._longest_turn_gap = 0.0

    # --- plumbing
    def _post(self, message: object) -> None:
        try:
            self.conn.send(message)
        except (OSError, EOFError, BrokenPipeError):
            raise _Trip("error", "session went away") from None

    def _ship(self, even_empty: bool = False) -> None:
        """Post the samples gathered since the last batch; ``even_empty``: a batch of none too (lockstep, at the
        end of the credit: the session answers every batch with the next credit, so it must hear of this stretch
        even when every reply in it was lost)."""
        if self._t or even_empty:
            assert self.driver is not None
            self._post(Samples(np.array(self._t, dtype=float),
                               np.array(self._v, dtype=float).reshape(len(self._t), len(self.layout_channels)),
                               np.array(self._u, dtype=float), self.tick - 1, tuple(self._held),
                               self.driver.dating_unchecked))
            self._t, self._v, self._u, self._held = [], [], [], []

    def _session_can_take(self) -> bool:
        """Whether a message to the session goes out now without blocking (its end of the pipe has room)."""
        try:
            return bool(select.select([], [self.conn.fileno()], [], 0)[1])
        except (OSError, ValueError):
            return True  # _post reports a pipe that is gone

    def _health(self) -> None:
        assert self.driver is not None
        pacing = None
        e = self.send_errors
        if e.count:
            pacing = PacingStats(e.percentile(50), e.percentile(99), e.max, e.count, self.overruns, self.scheduling)
        rt = statistics.median(self.round_trips) if self.round_trips else math.nan
        self._post(Health(self.driver.health.snapshot(), rt, pacing, self.tick, self.time_conflicts,
                          self.invalid_samples, self.missed_replies, self.counter_anomalies))

    def _command(self, message: object) -> None:
        if isinstance(message, Credit):
            self.credit = max(self.credit, message.until_tick)
        elif isinstance(message, (StartSine, StartTable)):
            if self.program is not None:
                self.program.finish(self.tick)
            self.pending = message
        elif isinstance(message, FinishSine):
            if self.program is not None:
                self.program.finish(self.tick)
        elif isinstance(message, Stop):
            self.stopping = message
            if self.program is not None:
                self.program.finish(self.tick, at_once=message.abort)

    def _poll_commands(self, timeout: float = 0.0) -> None:
        try:
            while self.conn.poll(timeout):
                self._command(self.conn.recv())
                timeout = 0.0
        except (OSError, EOFError):
            raise _Trip("error", "session went away") from None

    # --- setpoints
    def _limit(self, u: float) -> float:
        lim = self.spec.limits
        if not math.isfinite(u):
            u = 0.0
        u = max(-lim.max_amplitude, min(lim.max_amplitude, u))
        if lim.max_rate is not None:
            step = lim.max_rate * self.h
            u = max(self.last_sent - step, min(self.last_sent + step, u))
        return u

    def _next_setpoint(self) -> float:
        if self.program is not None and self.program.finished(self.tick):
            self.program = None
        if self.program is None and self.pending is not None and self.stopping is None:
            p = self.pending
            self.pending = None
            if isinstance(p, StartTable):
                self.program = TableProgram(p.setpoints, p.ramp_in_periods, p.ramp_out_periods, self.tick, self.h)
            else:
                self.program = SineProgram(p.frequency_hz, p.amplitude, p.ramp_in_periods, p.ramp_out_periods,
                                           self.tick, self.h)
            self._post(SineStarted(self.program.f, self.tick))
            if self.lockstep:  # the ramp in and the first period need no asking
                ramp_ticks = math.ceil((p.ramp_in_periods + 1) / (self.program.f * self.h))
                self.credit = max(self.credit, self.tick + ramp_ticks + 1)
        return self.program.value(self.tick) if self.program is not None else 0.0

    def _send(self, u: float) -> None:
        assert self.driver is not None
        self._check_fed()
        self.driver.send_setpoint(u, self.tick, self.program is None or self.program.ramping(self.tick))
        self.last_sent = u
        if self._last_fed is not None:
            self._last_fed = time.monotonic()

    def _check_fed(self) -> None:
        """The host's own silence: longer than the drive's watchdog (frames.drive_watchdog_s), and the drive has
        zeroed and disabled itself (PROTOCOL.md section 5), so whatever it answers next is not its response."""
        limit = self.layout.drive_watchdog_s
        if limit and self._last_fed is not None:
            silent = time.monotonic() - self._last_fed
            if silent > limit:
                raise _Trip("watchdog", f"the host sent the drive nothing for {silent:.3g} s, longer than its watchdog "
                                        f"(frames.drive_watchdog_s = {limit:g} s): the drive has zeroed and disabled "
                                        "itself, and what it answers now is not its response")

    # --- feedback
    def _time_of(self, s: FeedbackSample, answered_tick: int | None) -> float:
        """Session time of a sample: its counter (time base "sync": the host tick the driver dated it by), timestamp
        or receive time, aligned once on the first sample."""
        base = self.spec.timebase
        if base in ("counter", "sync") and s.counter is not None:
            raw = s.counter * self.h
        elif base == "timestamp" and s.timestamp is not None:
            raw = s.timestamp
        elif base == "sync" and answered_tick is not None:
            raw = (answered_tick + 1) * self.h  # a drive called in lockstep answers the very tick it was sent
        else:
            raw = s.receive_time - self.wall0
            if base != "receive":
                raise _Trip("bus", f"feedback without the {base} the time base needs")
        if self.offset is None:
            if base in ("counter", "sync") and self.driver is not None and self.driver.counts_host_ticks:
                self.offset = 0.0  # the driver dates each sample by the host tick it answers (CANopen SYNC)
            elif answered_tick is not None:
                # lockstep: the controller's clock runs a whole number of periods ahead of the session's,
                # so round the offset to periods (a jittered first sample must not shift the whole timeline)
                self.offset = round((raw - (answered_tick + 1) * self.h) / self.h) * self.h
            else:
                self.offset = raw - (s.receive_time - self.wall0)
        return raw - self.offset

    def _accept(self, samples: list[FeedbackSample], answered_tick: int | None) -> None:
        lim = self.spec.limits
        channels = self.layout_channels
        for s in samples:
            # NaN, inf or a value beyond any sensor on the wire: not a measurement, and it feeds no watchdog
            if not all(abs(v) <= MAX_COEFFICIENT for v in s.values):
                self.invalid_samples += 1
                continue
            for name, (lo, hi) in lim.feedback_limits.items():
                v = s.values[channels.index(name)]
                if not lo <= v <= hi:
                    raise _Trip("feedback_limit", f"{name} = {v:g} outside [{lo:g}, {hi:g}]")
            t = self._time_of(s, answered_tick)
            if answered_tick is not None and self._counter_anomaly(t, answered_tick):
                continue
            if t <= self._last_t:  # receive times of samples read in one burst: keep the first only
                self.time_conflicts += 1
                continue
            self._last_t = t
            if self._echo_index is not None and answered_tick is None:
                self._match_echo(s)
            self.last_feedback = time.monotonic()
            self._at_last_feedback = self._counts()
            self._longest_turn_gap = 0.0
            self._t.append(t)
            self._v.append(s.values)
            self._u.append(self.last_sent)

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
        if self._anomalies_in_row >= 3:
            self.offset = (self.offset or 0.0) + round((t - expected) / self.h) * self.h
            self._anomalies_in_row = 0
        return True

    def _remember_sent(self, u: float) -> None:
        """Realtime with an echo channel: the wall time (s) a new setpoint value went out."""
        key = float(np.float32(u))
        if key not in self._sent_at:
            self._sent_at[key] = time.time()
            self._sent_order.append(key)
            if len(self._sent_order) > 256:
                self._sent_at.pop(self._sent_order.popleft(), None)

    def _match_echo(self, s: FeedbackSample) -> None:
        """Realtime round trip: a sample whose echoed setpoint is a value sent recently came back this long after
        that value went out (its first echo only; values the drive cannot echo exactly never match)."""
        assert self._echo_index is not None
        sent = self._sent_at.pop(float(np.float32(s.values[self._echo_index])), None)
        if sent is not None and 0.0 <= s.receive_time - sent < 1.0:
            self.round_trips.append(s.receive_time - sent)

    def _start_heartbeat(self) -> None:
        """Keep the drive's watchdog fed: the layout's heartbeat repeated by the port itself where it can (python-can's
        periodic send), else sent from this loop (``_keep_alive``)."""
        assert self.driver is not None
        if self.layout.heartbeat is not None and not self.driver.start_heartbeat():
            self._heartbeat_s = self.layout.heartbeat_period_s
            self._next_heartbeat = time.monotonic()
            self._keep_alive()

    def _keep_alive(self) -> None:
        """Send the heartbeat when it is due (ports without a periodic send of their own)."""
        if self._heartbeat_s and time.monotonic() >= self._next_heartbeat:
            assert self.driver is not None
            self._check_fed()
            self.driver.heartbeat()
            if self._last_fed is not None:
                self._last_fed = time.monotonic()
            self._next_heartbeat += self._heartbeat_s
            if self._next_heartbeat < time.monotonic():  # fell behind (a stall): the next one a period from now
                self._next_heartbeat = time.monotonic() + self._heartbeat_s

    def _counts(self) -> tuple[int, ...]:
        """Setpoints sent, frames received on the bus (feedback or not), then what was dropped on the way to a
        sample (in the order of :data:`DROPPED`), so far."""
        h = self.driver.health if self.driver is not None else None
        return (self.tick, h.frames_in if h else 0, self.invalid_samples, self.counter_anomalies, self.time_conflicts,
                h.duplicates if h else 0, h.incomplete_samples if h else 0, h.rejected_total + h.errors if h else 0,
                h.counter_restarts if h else 0, self.missed_replies)

    def _turn(self) -> None:
        """A turn of the loop: the longest gap between turns since the last valid sample grows."""
        now = time.monotonic()
        if self._turn_at:
            self._longest_turn_gap = max(self._longest_turn_gap, now - self._turn_at)
        self._turn_at = now

    def _watchdog(self) -> None:
        limit = self.spec.limits.watchdog_s
        if time.monotonic() - self.last_feedback <= limit:
            return
        sent, frames, *dropped = (now - then for now, then in zip(self._counts(), self._at_last_feedback,
                                                                  strict=True))
        seen = [f"{n} {what}" for n, what in zip(dropped, DROPPED, strict=True) if n]
        said = (f"{sent} setpoints sent and {frames} frames received on the bus in that time; dropped: "
                f"{', '.join(seen) if seen else 'none'}")
        if self._longest_turn_gap > 0.25 * limit:
            said += f"; this loop did not run for {self._longest_turn_gap:.3g} s of it (a stalled or overloaded host)"
        raise _Trip("watchdog", f"no valid feedback for {limit:g} s ({said})")

    # --- main loops
    def _lockstep_tick(self) -> None:
        assert self.driver is not None
        u = self._limit(self._next_setpoint())
        sent = time.perf_counter()
        self._send(u)
        # the drive answers each setpoint; a reply that does not come in time is lost (counted) and the sweep
        # goes on: only the watchdog, with no feedback at all for watchdog_s, stops it. The first reply (the drive
        # may still be starting) may take up to the watchdog time; the others a few typical round trips.
        if self.offset is None:
            wait = self.spec.limits.watchdog_s
        else:
            if self.tick >= self._reply_wait_until:
                typical = list(self.round_trips)[-REPLY_WAIT_TICKS:]
                self._reply_wait = min(self.spec.reply_timeout_s,
                                       max(2e-3, 8 * statistics.median(typical) if typical else 2e-3))
                self._reply_wait_until = self.tick + REPLY_WAIT_TICKS
            wait = self._reply_wait
        deadline = time.monotonic() + wait
        broken = self.driver.health.broken_frames
        while True:
            samples = self.driver.receive(max(0.0, min(0.05, deadline - time.monotonic())))
            if samples:
                self.round_trips.append(time.perf_counter() - sent)
                self._accept(samples, self.tick)
                self._watchdog()  # frames that carry nothing valid (NaN, a failed check) feed nothing
                break
            self._watchdog()
            # a reply cut short on the line will not complete: it is lost now, not after the wait
            if time.monotonic() >= deadline or self.driver.health.broken_frames != broken:
                self.missed_replies += 1
                break
        self.tick += 1

    def _realtime_tick(self, scheduled: float) -> None:
        assert self.driver is not None
        u = self._limit(self._next_setpoint())  # ready before the deadline: only the send is left at it
        sleep_until(scheduled, self.spin_s)
        actual = time.perf_counter()
        self._send(u)
        if self._echo_index is not None:
            self._remember_sent(u)
        self.send_errors.add(actual - scheduled)
        if actual - scheduled > self.h:  # the drive held the previous setpoint for that long
            self.overruns += 1
            self._held.append((self.tick * self.h, self.tick * self.h + actual - scheduled))
        self._accept(self.driver.receive(0.0), None)
        self._watchdog()
        self.tick += 1

    def run(self) -> None:
        reason = "stopped"
        disabled = False
        try:
            if not self.lockstep:
                gc.collect()
                gc.freeze()
                gc.disable()
                lower_timer_slack()
                if threading.current_thread() is threading.main_thread():  # a process of its own
                    granted = [f"SCHED_FIFO {WORKER_PRIORITY}"] if request_fifo(WORKER_PRIORITY) else []
                    cpu = pacing_cpu(self.spec.pacing_cpu)
                    if cpu is not None and keep_to({cpu}):
                        granted.append(f"CPU {cpu}")
                    self.scheduling = ", ".join(granted) or self.scheduling
            port, self.layout, self.resources = self.spec.open_link()
            make_driver = getattr(self.spec.open_link, "make_driver", None)
            try:
                self.driver = make_driver(port, self.layout) if make_driver is not None else Driver(port, self.layout)
            except BaseException:
                port.close()
                raise
            self.layout_channels = self.layout.channels
            if SETPOINT_ECHO in self.layout_channels:
                self._echo_index = self.layout_channels.index(SETPOINT_ECHO)
            self.driver.enable()
            self._start_heartbeat()
            # the host's silence is known where this loop sends every frame that feeds the drive's watchdog
            if self.layout.heartbeat is None or self._heartbeat_s:
                self._last_fed = time.monotonic()
            self._post(Ready(self.layout.channels, self.h, self.driver.start_account))
            self.wall0 = time.time()
            self.last_feedback = time.monotonic()
            next_ship = next_health = next_poll = now = time.monotonic()
            scheduled = time.perf_counter() + self.h
            while True:
                self._turn()
                if now >= next_poll:
                    self._poll_commands()
                    next_poll = now + COMMAND_POLL_S
                self._keep_alive()
                if self.stopping is not None and (self.program is None or self.program.finished(self.tick)):
                    reason = self.stopping.reason
                    break
                if self.lockstep:
                    # without credit the worker waits, except to ramp out and start a requested sine
                    if self.tick > self.credit and self.pending is None and not (self.stopping and self.program):
                        idle_from = time.monotonic()
                        self._ship(even_empty=self.program is not None and self._credit_shipped != self.credit)
                        self._credit_shipped = self.credit
                        self._health()
                        self._poll_commands(min(0.5, self._heartbeat_s) if self._heartbeat_s else 0.5)
                        # a lockstep drive answers setpoints only: its silence while none is asked for (a paused
                        # or slow session) is not a fault, so that time is left out of the watchdog's count; the
                        # time it was asked and gave nothing valid (NaN, failed checks) stays in it
                        self.last_feedback += time.monotonic() - idle_from
                        self._turn_at = time.monotonic()
                        continue
                    self._lockstep_tick()
                    if self.tick > self.credit:
                        self._ship()
                else:
                    self._realtime_tick(scheduled)
                    scheduled += self.h
                    behind = time.perf_counter() - scheduled
                    if behind > 0.1:
                        # suspended: resume from now, skipping the ticks missed so that tick * period stays the
                        # time of the schedule (the drive's clock went on; the session times points by ticks)
                        missed = math.floor(behind / self.h) + 1
                        self._held.append((self.tick * self.h, (self.tick + missed) * self.h))
                        self.tick += missed
                        scheduled += missed * self.h
                now = time.monotonic()
                # on the realtime clock a session that falls behind must not stall the pacing: samples wait
                # (in a bigger batch) and health skips a turn until the pipe can take them without blocking
                if now >= next_ship and (self.lockstep or self._session_can_take()):
                    self._ship()
                    next_ship = now + self.spec.batch_s
                if now >= next_health and (self.lockstep or self._session_can_take()):
                    self._health()
                    next_health = now + self.spec.health_s
        except _Trip as trip:
            reason = f"{trip.kind}: {trip}"
            self._report(Fault(trip.kind, str(trip)))
        except DriveFaultError as exc:
            reason = f"drive: {exc}"
            self._last_health()
            self._report(Fault("drive", str(exc)))
        except DriverError as exc:
            reason = f"bus: {exc}"
            self._last_health()
            self._report(Fault("bus", str(exc)))
        except KeyboardInterrupt as exc:
            reason = f"interrupted ({exc.signame})" if isinstance(exc, StopSignal) else "interrupted"
            self._report(Fault("error", reason))
        except BaseException as exc:  # noqa: BLE001 - any failure must still leave the drive safe
            reason = f"error: {type(exc).__name__}: {exc}"
            self._report(Fault("error", f"{type(exc).__name__}: {exc}"))
        finally:
            zero_sent, disabled = self._make_safe()
            with contextlib.suppress(_Trip):
                self._ship()
            frames_out = self.driver.port.frames_out if self.driver is not None else 0
            shutdown = self.driver.shutdown_account if self.driver is not None else ""
            log_failure = ""
            if self.driver is not None:  # the log is complete with the zero setpoint and the disable frame
                with contextlib.suppress(Exception):  # a log's end never stands in the way of the report
                    self.driver.port.end_log()
                log_failure = self.driver.port.log_failure
            self._report(Stopped(reason, self.last_sent, disabled, zero_sent, frames_out, shutdown, log_failure))
            self._close()

    def _last_health(self) -> None:
        """The bus health as the fault left it, for the run's record (nothing where the session is gone)."""
        if self.driver is not None:
            with contextlib.suppress(_Trip):
                self._health()

    def _report(self, message: object) -> None:
        with contextlib.suppress(OSError, EOFError, BrokenPipeError, ValueError):
            self.conn.send(message)

    def _make_safe(self) -> tuple[bool, bool]:
        """Zero setpoint (slewed if a rate limit asks for it) and disable; (whether the zero setpoint went out,
        whether the disable frame went out, or the drive was seen disabled). Each step is tried whatever the one
        before it met: a drive that stops answering during the slew (faulted, or its bus gone quiet) is paced by
        the clock from then on, and a bus that fails to take the slew still gets the zero and the disable tried."""
        if self.driver is None:
            return False, False
        zero_sent = disabled = False
        self._last_fed = None  # the way out is sent whatever the host's silence was
        lim = self.spec.limits
        steps = 0
        if lim.max_rate is not None:
            steps = min(MAX_SLEW_STEPS, math.ceil(abs(self.last_sent) / (lim.max_rate * self.h)))
        answering = self.lockstep
        for _ in range(steps):
            try:
                self._send(self._limit(0.0))
            except Exception:  # noqa: BLE001 - the bus may be what failed: the zero and the disable are still tried
                break
            self.tick += 1
            if answering:
                try:
                    self.driver.receive(0.0)
                except Exception:  # noqa: BLE001 - no answer: the rest of the slew is paced by the clock
                    answering = False
            if not answering:
                time.sleep(self.h)
        for _ in range(ZERO_SETPOINTS):
            try:
                self._send(0.0)
            except Exception:  # noqa: BLE001 - nothing more can be sent on this bus
                break
            self.tick += 1
            zero_sent = True
        with contextlib.suppress(Exception):  # the disable is tried even where the setpoints could not go out
            disabled = self.driver.disable()
        return zero_sent, disabled

    def _close(self) -> None:
        if self.driver is not None:
            with contextlib.suppress(Exception):  # closing what may have failed: the others are closed all the same
                self.driver.close()
        for r in self.resources:
            with contextlib.suppress(Exception):
                r.close()


def worker_main(spec: WorkerSpec, conn: Connection) -> None:
    """Entry point of the worker process or thread (in a process of its own, SIGTERM and SIGHUP end it through
    the same safe shutdown as Ctrl-C)."""
    with stop_on_signals():
        BusWorker(spec, MessagePipe(conn)).run()
    with contextlib.suppress(OSError):
        conn.close()


def start_worker(spec: WorkerSpec, mode: str) -> tuple[MessagePipe, Any]:
    """Start the worker in its own process (``process``) or a thread; returns (session end of the pipe, handle)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    ours, theirs = ctx.Pipe(duplex=True)
    if mode == "process":
        proc = ctx.Process(target=worker_main, args=(spec, theirs), name="bodebench-bus", daemon=True)
        proc.start()
        theirs.close()
        return MessagePipe(ours), proc
    thread = threading.Thread(target=worker_main, args=(spec, theirs), name="bodebench-bus", daemon=True)
    thread.start()
    return MessagePipe(ours), thread
