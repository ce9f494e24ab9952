"""What the session and the bus worker send each other over their pipe, and the worker's configuration.

Every message is a small frozen dataclass, picklable, so the worker may run in a process of its own.
Commands go to the worker (``StartSine``, ``Credit``, ``Stop``); reports come back (``Ready``,
``SineStarted``, ``Samples``, ``Health``, ``Fault``, ``Stopped``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bodebench.drivers.driver import BusHealth
from bodebench.status import FaultKind

# ------------------------------------------------------------------------------------------- messages to the worker


@dataclass(frozen=True)
class StartSine:
    """Ramp the running sine out (if any), then start ``amplitude*sin(2 pi f t)`` ramped in over whole periods."""

    frequency_hz: float
    amplitude: float
    ramp_in_periods: int
    ramp_out_periods: int


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
    ``period_s``: the tick period (s)."""

    channels: tuple[str, ...]
    period_s: float


@dataclass(frozen=True)
class SineStarted:
    """The setpoint of tick ``tick`` (session time tick * period) is the new sine's phase zero."""

    frequency_hz: float
    tick: int


@dataclass(frozen=True)
class Samples:
    """Feedback samples: session time t (s), values (n, channels), and the setpoint sent at each sample's tick;
    ``last_tick``: the last tick whose setpoint had gone out when the batch was cut."""

    t: np.ndarray
    values: np.ndarray
    setpoint: np.ndarray
    last_tick: int


@dataclass(frozen=True)
class PacingStats:
    """Send-time error of paced setpoints against their schedule (s): p50, p99, max; overruns = ticks late by
    more than one period; ``scheduling`` says what the OS granted the pacing loop (e.g. "SCHED_FIFO 20, CPU 1")."""

    p50: float
    p99: float
    max: float
    count: int
    overruns: int
    scheduling: str


@dataclass(frozen=True)
class Health:
    """Bus health, round-trip delay (s; lockstep: setpoint to its sample), pacing, and samples dropped because
    their time did not increase (bursts read at once on the receive time base)."""

    bus: BusHealth
    round_trip_s: float
    pacing: PacingStats | None
    tick: int
    time_conflicts: int = 0
    invalid_samples: int = 0
    missed_replies: int = 0
    counter_anomalies: int = 0


@dataclass(frozen=True)
class Fault:
    """A trip or error; the worker has already zeroed and disabled the drive. ``kind``: watchdog, feedback_limit,
    bus or error."""

    kind: FaultKind
    message: str


@dataclass(frozen=True)
class Stopped:
    """The worker's last message: the last setpoint that went out, whether a zero setpoint went out after every
    other (``zero_sent``), whether the disable frame went out, and how many frames reached the bus at all."""

    reason: str
    last_setpoint: float
    disabled: bool
    zero_sent: bool = False
    frames_out: int = 0


# --------------------------------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class Limits:
    """Safety limits: |setpoint| <= max_amplitude, slew <= max_rate (units/s, None: none), feedback windows
    {channel: (low, high)}, watchdog_s (s) without feedback."""

    max_amplitude: float
    max_rate: float | None
    feedback_limits: dict[str, tuple[float, float]] = field(default_factory=dict)
    watchdog_s: float = 0.5


@dataclass(frozen=True)
class WorkerSpec:
    """Everything the worker needs, picklable: how to open the link (``open_link`` returns (port, layout,
    resources to close)), the pacing (``rate_hz``, Hz; ``clock``: lockstep or realtime), the time base
    (counter, timestamp or receive) and the limits; ``batch_s``, ``health_s``: how often (s) samples and health
    go to the session."""

    open_link: Any  # a picklable callable () -> tuple[FramePort, Layout, list[closeable]]
    rate_hz: float
    clock: str
    timebase: str
    limits: Limits
    batch_s: float = 0.01
    health_s: float = 0.1
    reply_timeout_s: float = 0.05  # lockstep: how long a setpoint's reply may take before it counts as lost
    pacing_cpu: int | None = None  # realtime: the CPU the worker process keeps to (None: the last it may use)
