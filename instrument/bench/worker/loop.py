"""The bus worker itself: the loop that joins pacing, safety, the time base and the statistics, and its start
in a thread or a process of its own."""

from __future__ import annotations

import math
import threading
import time
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from bodebench.bench.worker.health import RoundTrips, health_report
from bodebench.bench.worker.messages import (
    Credit,
    Ready,
    Samples,
    SineStarted,
    StartSine,
    Stop,
    Stopped,
    WorkerSpec,
)
from bodebench.bench.worker.pacing import LockstepPacing, RealtimePacing, prepare_realtime
from bodebench.bench.worker.pipe import SessionPipe
from bodebench.bench.worker.safety import (
    FeedbackWindows,
    Heartbeat,
    SetpointLimiter,
    Trip,
    Watchdog,
    stop_reason,
    zero_and_disable,
)
from bodebench.bench.worker.sine import SineSequence
from bodebench.bench.worker.timebase import TimeBase
from bodebench.drivers.driver import Driver, FeedbackSample
from bodebench.drivers.layout import SETPOINT_ECHO
from bodebench.drivers.stop_signals import stop_on_signals

IDLE_POLL_S = 0.5
"""Lockstep: the longest wait (s) for a command while out of credit (shorter when the loop sends heartbeats)."""


class _Batch:
    """Samples taken since the last batch went to the session: times (s), values, setpoints."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.values: list[tuple[float, ...]] = []
        self.setpoints: list[float] = []

    def add(self, t: float, values: tuple[float, ...], setpoint: float) -> None:
        self.t.append(t)
        self.values.append(values)
        self.setpoints.append(setpoint)

    def samples(self, last_tick: int) -> Samples:
        return Samples(np.array(self.t), np.array(self.values, dtype=float).reshape(len(self.t), -1),
                       np.array(self.setpoints), last_tick)

    def clear(self) -> None:
        self.t, self.values, self.setpoints = [], [], []


class BusWorker:
    """The pacing loop. ``run`` never raises: every way out zeroes the drive and ends with ``Stopped``."""

    def __init__(self, spec: WorkerSpec, conn: Connection) -> None:
        self.spec = spec
        self.session = SessionPipe(conn)
        self.h = 1.0 / spec.rate_hz
        self.lockstep = spec.clock == "lockstep"
        self.tick = 0  # next setpoint's tick
        self.last_sent = 0.0  # the last setpoint that went out
        self.stopping: Stop | None = None
        self.driver: Driver | None = None
        self.resources: list[Any] = []
        self.channels: tuple[str, ...] = ()
        self.sine = SineSequence(self.h)
        self.lockstep_pacing = LockstepPacing(self.h, spec.reply_timeout_s)
        self.realtime_pacing = RealtimePacing(self.h)
        self.limiter = SetpointLimiter(spec.limits, self.h)
        self.windows = FeedbackWindows(spec.limits)
        self.watchdog = Watchdog(spec.limits.watchdog_s)
        self.heartbeat = Heartbeat()
        self.timebase = TimeBase(spec.timebase, self.h)
        self.round_trips = RoundTrips()
        self.batch = _Batch()
        self.invalid_samples = 0  # samples with NaN or infinite values, dropped
        self.reply_owed = False  # lockstep: no valid sample came back for the last setpoint sent
        self._echo_index: int | None = None  # the setpoint_echo channel, when the drive has one

    def run(self) -> None:
        """Open the link, enable the drive and pace setpoints until a Stop or a fault; then zero, disable, report
        ``Stopped`` and close."""
        reason = "stopped"
        try:
            reason = self._run()
        except BaseException as exc:  # noqa: BLE001 - any failure must still leave the drive safe
            reason, fault = stop_reason(exc)
            self.session.report(fault)
        finally:
            zero_sent, disabled = self._make_safe()
            try:
                self._ship()
            except Trip:
                pass
            frames_out = self.driver.port.frames_out if self.driver is not None else 0
            self.session.report(Stopped(reason, self.last_sent, disabled, zero_sent, frames_out))
            self._close()

    def _run(self) -> str:
        if not self.lockstep:
            self.realtime_pacing.scheduling = prepare_realtime(self.spec.pacing_cpu) or \
                self.realtime_pacing.scheduling
        port, layout, self.resources = self.spec.open_link()
        self.driver = Driver(port, layout)
        self.channels = layout.channels
        if SETPOINT_ECHO in self.channels:
            self._echo_index = self.channels.index(SETPOINT_ECHO)
        self.driver.enable()
        self.heartbeat.start(self.driver)
        self.session.post(Ready(layout.channels, self.h))
        self.timebase.start()
        self.watchdog.feed()
        next_ship = next_health = time.monotonic()
        self.realtime_pacing.start()
        while True:
            self._poll_commands()
            self.heartbeat.keep_alive()
            if self.stopping is not None and self.sine.finished(self.tick):
                return self.stopping.reason
            if self.lockstep:
                if not self._lockstep_step():
                    continue
            else:
                self._realtime_tick()
                self.tick += self.realtime_pacing.next_tick()
            now = time.monotonic()
            # on the realtime clock a session that falls behind must not stall the pacing: samples wait
            # (in a bigger batch) and health skips a turn until the pipe can take them without blocking
            if now >= next_ship and (self.lockstep or self.session.can_take()):
                self._ship()
                next_ship = now + self.spec.batch_s
            if now >= next_health and (self.lockstep or self.session.can_take()):
                self._health()
                next_health = now + self.spec.health_s

    # --- commands
    def _command(self, message: object) -> None:
        if isinstance(message, Credit):
            self.lockstep_pacing.grant(message.until_tick)
        elif isinstance(message, StartSine):
            self.sine.request(message, self.tick)
        elif isinstance(message, Stop):
            self.stopping = message
            self.sine.finish(self.tick, at_once=message.abort)

    def _poll_commands(self, timeout_s: float = 0.0) -> None:
        self.session.receive(self._command, timeout_s)

    # --- the two clocks
    def _lockstep_step(self) -> bool:
        """Lockstep: send the next setpoint and await its reply when the credit allows (True), else wait for a
        command (False)."""
        pacing = self.lockstep_pacing
        # without credit the worker waits, except to ramp out and start a requested sine, and after a setpoint
        # the drive did not answer: a silent drive gives the session no samples to grant credit for, so the worker
        # goes on asking (beyond the credit) until a valid sample comes back or the watchdog trips
        if pacing.out_of_credit(self.tick) and self.sine.pending is None and not self.reply_owed and \
                not (self.stopping is not None and self.sine.running):
            self._ship()
            self._health()
            beat = self.heartbeat.period_s
            self._poll_commands(min(IDLE_POLL_S, beat) if beat else IDLE_POLL_S)
            # a lockstep drive answers setpoints only: its silence while none is asked for (a paused
            # or slow session) is not a fault, so the watchdog counts from the next setpoint
            self.watchdog.feed()
            return False
        assert self.driver is not None
        u = self._setpoint()
        sent = time.perf_counter()
        self._send(u)
        # the drive answers each setpoint; a reply that does not come in time is lost (counted) and the sweep
        # goes on: only the watchdog, with no feedback at all for watchdog_s, stops it. The first reply (the drive
        # may still be starting) may take up to the watchdog time; the others a few typical round trips.
        wait = pacing.reply_wait(not self.timebase.aligned, self.round_trips, self.spec.limits.watchdog_s)
        samples = pacing.await_reply(self.driver, wait, self.watchdog)
        answered = False
        if samples:
            self.round_trips.add(time.perf_counter() - sent)
            answered = self._accept(samples, self.tick)
        self.reply_owed = not answered
        self.tick += 1
        if pacing.out_of_credit(self.tick):
            self._ship()
        return True

    def _realtime_tick(self) -> None:
        assert self.driver is not None
        pacing = self.realtime_pacing
        u = self._setpoint()  # ready before the deadline: only the send is left at it
        at = pacing.wait_for_tick()
        self._send(u)
        if self._echo_index is not None:
            self.round_trips.sent(u)
        pacing.sent(at)
        self._accept(self.driver.receive(0.0), None)
        self.watchdog.check()
        self.tick += 1

    # --- setpoints and feedback
    def _setpoint(self) -> float:
        """The setpoint of this tick within the limits; a requested sine starts here (reported to the session)."""
        started = self.sine.advance(self.tick, may_start=self.stopping is None)
        if started is not None:
            self.session.post(SineStarted(started.frequency_hz, self.tick))
            if self.lockstep:
                self.lockstep_pacing.grant_ramp(started, self.tick)
        return self.limiter.limit(self.sine.value(self.tick), self.last_sent)

    def _send(self, u: float) -> None:
        assert self.driver is not None
        self.driver.send_setpoint(u, self.tick)
        self.last_sent = u

    def _send_next(self, u: float) -> None:
        """Send ``u`` as this tick's setpoint and move on to the next tick."""
        self._send(u)
        self.tick += 1

    def _accept(self, samples: list[FeedbackSample], answered_tick: int | None) -> bool:
        """Check and time feedback samples and add them to the batch; answered_tick: lockstep, the tick whose
        setpoint they answer (None: realtime). Whether any was valid (taken)."""
        taken = False
        for s in samples:
            if not all(math.isfinite(v) for v in s.values):  # NaN or inf on the wire: not a measurement
                self.invalid_samples += 1
                continue
            self.windows.check(s.values, self.channels)
            t = self.timebase.place(s, answered_tick)
            if t is None:
                continue
            if self._echo_index is not None and answered_tick is None:
                self.round_trips.echoed(s.values[self._echo_index], s.receive_time)
            self.watchdog.feed()
            self.batch.add(t, s.values, self.last_sent)
            taken = True
        return taken

    # --- reports to the session
    def _ship(self) -> None:
        if self.batch.t:
            self.session.post(self.batch.samples(self.tick - 1))
            self.batch.clear()

    def _health(self) -> None:
        assert self.driver is not None
        self.session.post(health_report(self.driver.health, self.round_trips, self.realtime_pacing.stats(),
                                        self.tick, self.timebase, self.invalid_samples,
                                        self.lockstep_pacing.missed_replies))

    # --- the way out
    def _make_safe(self) -> tuple[bool, bool]:
        """Zero setpoint (slewed if a rate limit asks for it) and disable; (whether the zero setpoint went out,
        whether the disable frame went out)."""
        driver = self.driver
        if driver is None:
            return False, False

        def between_steps() -> None:
            if self.lockstep:
                driver.receive(0.0)
            else:
                time.sleep(self.h)

        return zero_and_disable(driver, self.limiter, self.last_sent, self._send_next, between_steps)

    def _close(self) -> None:
        if self.driver is not None:
            try:
                self.driver.close()
            except Exception:  # noqa: BLE001
                pass
        for r in self.resources:
            try:
                r.close()
            except Exception:  # noqa: BLE001
                pass


def worker_main(spec: WorkerSpec, conn: Connection) -> None:
    """Entry point of the worker process or thread (in a process of its own, SIGTERM and SIGHUP end it through
    the same safe shutdown as Ctrl-C)."""
    with stop_on_signals():
        BusWorker(spec, conn).run()
    try:
        conn.close()
    except OSError:
        pass


def start_worker(spec: WorkerSpec, mode: str) -> tuple[Connection, Any]:
    """Start the worker in its own process (``process``) or a thread; returns (session end of the pipe, handle)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    ours, theirs = ctx.Pipe(duplex=True)
    if mode == "process":
        proc = ctx.Process(target=worker_main, args=(spec, theirs), name="bodebench-bus", daemon=True)
        proc.start()
        theirs.close()
        return ours, proc
    thread = threading.Thread(target=worker_main, args=(spec, theirs), name="bodebench-bus", daemon=True)
    thread.start()
    return ours, thread
