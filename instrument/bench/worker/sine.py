"""The setpoint program: a sine with whole-period linear ramps in and out, and the sine asked for next.

Times are in ticks (one setpoint each); ``period_s`` is the tick period (s).
"""

from __future__ import annotations

import math

from bodebench.bench.worker.messages import StartSine


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
        """Whether the ramp out is over by ``tick`` (the setpoint is zero from then on)."""
        if self.out_tick is None:
            return False
        return self.ramp_out == 0 or (tick - self.out_tick) * self.h * self.f >= self.ramp_out

    def value(self, tick: int) -> float:
        """The setpoint of ``tick`` (the amplitude's units)."""
        t = (tick - self.tick0) * self.h
        if t < 0 or self.finished(tick):
            return 0.0
        gain = 1.0 if self.ramp_in == 0 else min(1.0, t * self.f / self.ramp_in)
        if self.out_tick is not None and self.ramp_out:
            gain *= max(0.0, 1.0 - (tick - self.out_tick) * self.h * self.f / self.ramp_out)
        return self.amplitude * gain * math.sin(2.0 * math.pi * self.f * t)


class SineSequence:
    """The sine on the drive and the one asked for next: a requested sine starts at the first tick after the
    running one has ramped out."""

    def __init__(self, period_s: float) -> None:
        """period_s: tick period (s)."""
        self.h = period_s
        self.program: SineProgram | None = None
        self.pending: StartSine | None = None

    @property
    def running(self) -> bool:
        """A sine is on the drive (possibly ramping out)."""
        return self.program is not None

    def request(self, start: StartSine, tick: int) -> None:
        """Ramp the running sine out from ``tick`` and start ``start`` after it."""
        if self.program is not None:
            self.program.finish(tick)
        self.pending = start

    def finish(self, tick: int, at_once: bool) -> None:
        """Ramp the running sine out from ``tick`` (``at_once``: no ramp)."""
        if self.program is not None:
            self.program.finish(tick, at_once=at_once)

    def finished(self, tick: int) -> bool:
        """No sine is on the drive at ``tick``."""
        return self.program is None or self.program.finished(tick)

    def advance(self, tick: int, may_start: bool) -> StartSine | None:
        """Drop a sine that has ramped out by ``tick`` and, when ``may_start``, start the requested one there;
        returns the request that started now (None: none did)."""
        if self.program is not None and self.program.finished(tick):
            self.program = None
        if self.program is None and self.pending is not None and may_start:
            p = self.pending
            self.pending = None
            self.program = SineProgram(p.frequency_hz, p.amplitude, p.ramp_in_periods, p.ramp_out_periods, tick,
                                       self.h)
            return p
        return None

    def value(self, tick: int) -> float:
        """The setpoint of ``tick`` (zero without a sine)."""
        return self.program.value(tick) if self.program is not None else 0.0
