"""What a sweep tells its listeners (the command line, the terminal UI): typed, immutable events.

A listener is any callable taking one event; it runs on the sweep's thread and must only record or queue
what it is given (the terminal UI posts it to its own thread). Fault kinds are :class:`bodebench.status.FaultKind`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodebench.core.autointegration import SeriesState
from bodebench.core.eta import SweepTimer
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.drivers.driver import BusHealth
from bodebench.status import FaultKind


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
class SessionStarted:
    """A sweep of ``frequencies_hz`` (Hz, every one of the case's, in order) starts on ``where``.

    measured: frequencies already on disk from an interrupted sweep, with the periods their slowest series
    took (not measured again); extra_periods: per frequency, the periods a point spends besides those
    integrated (ramp in, settle, ramp out); max_periods: the cap on integrated periods (per frequency: each
    point's budget); realtime: the bench paces periods in real time (a period lasts 1/f s).
    """

    frequencies_hz: tuple[float, ...]
    channels: tuple[str, ...]
    where: str
    measured: tuple[tuple[float, int], ...] = ()
    extra_periods: tuple[float, ...] = ()
    max_periods: int | tuple[int, ...] | None = None
    realtime: bool = False

    def timer(self) -> SweepTimer:
        """A timer of this sweep, the frequencies already measured counted done."""
        timer = SweepTimer(self.frequencies_hz, self.extra_periods or 0.0, self.max_periods,
                           1.0 if self.realtime else None)
        timer.already_measured(dict(self.measured))
        return timer


@dataclass(frozen=True)
class OverviewProgress:
    """The overview an adaptive plan runs first (``from_overview``) for case ``case`` has measured ``periods``
    whole periods of its multisine."""

    case: str
    periods: int


@dataclass(frozen=True)
class PlanGrew:
    """An adaptive plan adds ``frequencies_hz`` (Hz, ascending) to the sweep, each for the reason at the same place in
    ``reasons``; ``extra_periods`` and ``max_periods`` as :class:`SessionStarted` gives them, per added frequency."""

    frequencies_hz: tuple[float, ...]
    reasons: tuple[str, ...]
    extra_periods: tuple[float, ...] = ()
    max_periods: tuple[int, ...] = ()


@dataclass(frozen=True)
class PointStarted:
    """Point ``index`` (the index-th point of the session) starts at ``frequency_hz`` (Hz), judged by the rule
    ``criterion`` at ``tolerance_percent`` (percent)."""

    index: int
    frequency_hz: float
    tolerance_percent: float = math.nan
    criterion: str = ""


@dataclass(frozen=True)
class PointProgress:
    """The current point after the latest batch of periods; ``scope``: recent (t, setpoint, output) samples;
    ``discarded``: periods not integrated so far for gaps in the feedback (``periods`` counts the whole ones);
    ``discard_limit``: the most periods the point may discard before it fails whatever comes (one more fails it;
    -1: not known)."""

    index: int
    frequency_hz: float
    periods: int
    states: tuple[SeriesState, ...]
    scope: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    discarded: int = 0
    discard_limit: int = -1

    def gaps(self) -> str:
        """The periods discarded for gaps so far and the most allowed, for a progress display ("" without any)."""
        if not self.discarded:
            return ""
        allowed = f", at most {self.discard_limit} allowed" if self.discard_limit >= 0 else ""
        return f"{self.discarded} discarded for gaps{allowed}"


@dataclass(frozen=True)
class PointFinished:
    """A point done: its ``points`` (one per channel and harmonic) on disk; ``skipped`` by the user, or
    ``refused`` (the reason: not a physical response, or too many periods with gaps in the feedback; nothing
    written)."""

    index: int
    points: tuple[ResponsePoint, ...]
    skipped: bool = False
    refused: str = ""


@dataclass(frozen=True)
class BusStatus:
    health: Health


@dataclass(frozen=True)
class SessionFault:
    """The sweep stopped early; ``kept`` points are on disk."""

    kind: FaultKind
    message: str
    kept: int


@dataclass(frozen=True)
class SessionEnded:
    """How the sweep ended and what the drive was last sent: ``last_setpoint`` (NaN: unknown, the worker did not
    report), whether a zero setpoint and the disable frame went out after every other setpoint, whether the bus
    worker reported at all (``reported``) and how many frames it sent; ``has_disable``: the layout has a disable
    frame; ``drive_watchdog_s``: the drive's own watchdog time (0: the layout declares none); ``shutdown``: what
    the driver did beyond the disable frame and what the drive then reported (a CANopen drive's quick stop,
    disable voltage and NMT pre-operational)."""

    reason: str
    completed: bool
    last_setpoint: float
    disabled: bool
    zero_sent: bool = False
    frames_out: int = 0
    reported: bool = True
    has_disable: bool = True
    drive_watchdog_s: float = 0.0
    shutdown: str = ""

    def drive_state(self) -> str:
        """What the drive was actually sent, in words (the last line of a command)."""
        watchdog = (f"the drive's watchdog zeroes and disables it {self.drive_watchdog_s:g} s after the last frame "
                    "it received (frames.drive_watchdog_s)" if self.drive_watchdog_s > 0 else
                    "the layout declares no drive watchdog (frames.drive_watchdog_s): make the drive safe by hand")
        if not self.reported:
            return f"the bus worker ended without reporting: the drive's state is unknown; {watchdog}"
        if self.frames_out == 0:
            return "nothing was sent to the drive"
        if self.shutdown:
            zero = ("drive left at setpoint 0" if self.zero_sent else
                    f"could not send the zero setpoint (the last setpoint out was {self.last_setpoint:g})")
            return f"{zero}, {'seen disabled' if self.disabled else 'NOT seen disabled'}: {self.shutdown}"
        if not self.zero_sent:
            return (f"could not send the zero setpoint: the last setpoint that went out was {self.last_setpoint:g}"
                    f"{'' if self.disabled else ', no disable frame sent'}; {watchdog}")
        if self.disabled:
            return "drive left at setpoint 0, disabled"
        if not self.has_disable:
            return "drive left at setpoint 0 (the layout has no disable frame)"
        return f"drive left at setpoint 0, but the disable frame could not be sent; {watchdog}"


Listener = Callable[[object], None]


class SessionError(RuntimeError):
    """The sweep could not complete; the drive was left at zero. ``kind`` says why."""

    def __init__(self, kind: FaultKind, message: str) -> None:
        super().__init__(f"{kind}: {message}")
        self.kind = kind


def point_not_written(directory: object, frequency_hz: float, exc: OSError) -> SessionError:
    """The output fault of a point at ``frequency_hz`` (Hz) the disk would not take in ``directory``."""
    return SessionError(FaultKind.OUTPUT, f"{directory}: cannot write the point at {frequency_hz:g} Hz: "
                                          f"{exc.strerror or exc}")


@dataclass(frozen=True)
class CaseBegins:
    """The sweep procedure starts case ``index`` (``frequency_hz``: only that frequency, measured again)."""

    index: int
    name: str
    directory: Path
    frequency_hz: float | None = None


@dataclass(frozen=True)
class CaseSaved:
    """Case ``index`` is on disk in ``directory``: its ``response`` and the plot ``files``."""

    index: int
    response: FrequencyResponse
    directory: Path
    files: tuple[Path, ...] = ()
