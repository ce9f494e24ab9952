"""Safety: what the drive may be sent, what its feedback may read, how long it may stay silent, and how every
way out of the worker leaves it.

- ``SetpointLimiter``: every setpoint within +-max_amplitude and at most max_rate (units/s) from the last one;
- ``FeedbackWindows``: a feedback value outside its [low, high] window trips the worker;
- ``Watchdog``: no valid feedback for watchdog_s (s) trips it;
- ``Heartbeat``: keeps the drive's own watchdog fed (drivers/PROTOCOL.md section 5);
- ``stop_reason`` and ``zero_and_disable``: whatever ends the worker (a stop, a trip, a bus error, an
  exception, Ctrl-C, SIGTERM), it reports why, then sends a zero setpoint (slewed at max_rate) and the disable
  frame.
"""

from __future__ import annotations

import math
import time
from typing import Callable

from bodebench.bench.worker.messages import Fault, Limits
from bodebench.drivers.driver import Driver
from bodebench.drivers.errors import DriverError
from bodebench.drivers.stop_signals import StopSignal
from bodebench.status import FaultKind

ZERO_REPEATS = 3
"""Zero setpoints sent after the slew to zero, before the disable frame."""
MAX_SLEW_STEPS = 10_000
"""Most setpoints the slew to zero takes; a zero setpoint follows them in any case."""


class Trip(Exception):
    """A condition that ends the sweep at once: ``kind`` says which, the message what was seen."""

    def __init__(self, kind: FaultKind, message: str) -> None:
        super().__init__(message)
        self.kind: FaultKind = kind


class SetpointLimiter:
    """Clamp and slew limit of every setpoint sent: a value that is not finite becomes zero."""

    def __init__(self, limits: Limits, period_s: float) -> None:
        """period_s: tick period (s): at most ``max_rate * period_s`` between successive setpoints."""
        self.max_amplitude = limits.max_amplitude
        self.step = None if limits.max_rate is None else limits.max_rate * period_s

    def limit(self, u: float, last_sent: float) -> float:
        """``u`` as it may go out after ``last_sent``."""
        if not math.isfinite(u):
            u = 0.0
        u = max(-self.max_amplitude, min(self.max_amplitude, u))
        if self.step is not None:
            u = max(last_sent - self.step, min(last_sent + self.step, u))
        return u

    def steps_to_zero(self, last_sent: float) -> int:
        """Setpoints the slew limit needs to bring ``last_sent`` to zero (0 without a rate limit)."""
        if self.step is None:
            return 0
        return min(MAX_SLEW_STEPS, math.ceil(abs(last_sent) / self.step))


class FeedbackWindows:
    """The feedback windows {channel: (low, high)}: a value outside its window trips the worker."""

    def __init__(self, limits: Limits) -> None:
        self.windows = limits.feedback_limits

    def check(self, values: tuple[float, ...], channels: tuple[str, ...]) -> None:
        """Trip (feedback_limit) when a windowed channel of ``values`` (in ``channels`` order) is outside."""
        for name, (lo, hi) in self.windows.items():
            v = values[channels.index(name)]
            if not lo <= v <= hi:
                raise Trip(FaultKind.FEEDBACK_LIMIT, f"{name} = {v:g} outside [{lo:g}, {hi:g}]")


class Watchdog:
    """Trips (watchdog) when no valid feedback came for ``limit_s`` (s, monotonic clock)."""

    def __init__(self, limit_s: float) -> None:
        self.limit_s = limit_s
        self.last_feedback = 0.0

    def feed(self) -> None:
        """Valid feedback now (or a silence that does not count ends now)."""
        self.last_feedback = time.monotonic()

    def check(self) -> None:
        """Trip when the feedback has been silent for longer than the limit."""
        if time.monotonic() - self.last_feedback > self.limit_s:
            raise Trip(FaultKind.WATCHDOG, f"no valid feedback for {self.limit_s:g} s")


class Heartbeat:
    """Keeps the drive's watchdog fed: the layout's heartbeat repeated by the port itself where it can
    (python-can's periodic send), else sent from the worker's loop (``keep_alive``)."""

    def __init__(self) -> None:
        self.period_s = 0.0  # s between heartbeats the loop sends (0: none, or the port repeats it itself)
        self._next = 0.0
        self._driver: Driver | None = None

    def start(self, driver: Driver) -> None:
        """Start the heartbeat of ``driver``'s layout (if it has one)."""
        self._driver = driver
        if driver.layout.heartbeat is not None and not driver.start_heartbeat():
            self.period_s = driver.layout.heartbeat_period_s
            self._next = time.monotonic()
            self.keep_alive()

    def keep_alive(self) -> None:
        """Send the heartbeat when it is due (ports without a periodic send of their own)."""
        if self.period_s and time.monotonic() >= self._next:
            assert self._driver is not None
            self._driver.heartbeat()
            self._next += self.period_s
            if self._next < time.monotonic():  # fell behind (a stall): the next one a period from now
                self._next = time.monotonic() + self.period_s


def stop_reason(exc: BaseException) -> tuple[str, Fault]:
    """Why the worker stops on ``exc`` (its Stopped reason) and the Fault it reports."""
    if isinstance(exc, Trip):
        return f"{exc.kind}: {exc}", Fault(exc.kind, str(exc))
    if isinstance(exc, DriverError):
        return f"bus: {exc}", Fault(FaultKind.BUS, str(exc))
    if isinstance(exc, KeyboardInterrupt):
        reason = f"interrupted ({exc.signame})" if isinstance(exc, StopSignal) else "interrupted"
        return reason, Fault(FaultKind.ERROR, reason)
    return f"error: {type(exc).__name__}: {exc}", Fault(FaultKind.ERROR, f"{type(exc).__name__}: {exc}")


def zero_and_disable(driver: Driver, limiter: SetpointLimiter, last_sent: float, send: Callable[[float], None],
                     between_steps: Callable[[], None]) -> tuple[bool, bool]:
    """Bring the drive to rest: setpoints slewed to zero at the rate limit from ``last_sent`` (``between_steps``
    after each), a zero setpoint ``ZERO_REPEATS`` times, then the disable frame. ``send`` sends one setpoint at
    the next tick. Returns (whether a zero setpoint went out, whether the disable frame went out); an error on
    the bus ends the attempt, since nothing more can be done on it."""
    zero_sent = disabled = False
    try:
        u = last_sent
        for _ in range(limiter.steps_to_zero(last_sent)):
            u = limiter.limit(0.0, u)
            send(u)
            between_steps()
        for _ in range(ZERO_REPEATS):
            send(0.0)
            zero_sent = True
        driver.disable()
        disabled = driver.layout.disable is not None
    except Exception:  # noqa: BLE001 - the bus may be what failed; nothing more can be done on it
        pass
    return zero_sent, disabled
