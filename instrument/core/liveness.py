"""Is the drive still answering the sine? A watch over a point's feedback that notices a channel holding one value.

A drive that tripped, was disabled, or was sent a setpoint below the wire's resolution goes on streaming valid frames,
but what they carry no longer answers the excitation: the same value, sample after sample (a disabled drive's zero,
a frozen position, an echo of 0). Averaged, such samples give a response of exactly nothing with an interval of
nothing, which would read as a measured point. A real sensor that answers a sine changes within a period, so a
channel whose every sample over ``FLAT_PERIODS`` whole periods of the excitation is bit for bit the same is taken as
a drive that stopped answering. Pure numerics: no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from bodebench.core.response import ResponsePoint
from bodebench.status import PointStatus

__all__ = ["FLAT_PERIODS", "FlatWatch", "no_fundamental"]

FLAT_PERIODS = 2.0
"""Periods of the excitation over which a channel holding one value means the drive stopped answering."""


class FlatWatch:
    """Tracks, per channel, how long (s) it has held its current value while the host drove the sine.

    channels: the names of the columns fed (outputs, and the setpoint echo where the drive sends one);
    frequency_hz: the excitation frequency f (Hz); periods: how many periods of f a held value may last.
    """

    def __init__(self, channels: Sequence[str], frequency_hz: float, periods: float = FLAT_PERIODS) -> None:
        self.channels = tuple(channels)
        self.frequency_hz = frequency_hz
        self.limit_s = periods / frequency_hz
        self._value = np.full(len(self.channels), math.nan)
        self._held = np.zeros(len(self.channels))  # driven time (s) the current value has been held
        self._last_t = math.nan

    def add(self, t: np.ndarray, values: np.ndarray, driven: np.ndarray | None = None) -> None:
        """Samples: times (n,) in s, increasing, and values (n, channels); driven: (n,) False where the host's
        setpoint did not move (a host that stalled, a sine not yet started). The interval up to a sample counts
        towards a held value only where the host drove it: no drive is blamed for holding still while the host
        did, and a stall neither restarts nor lengthens the count."""
        if t.size == 0:
            return
        t = np.asarray(t, dtype=np.float64)
        v = np.asarray(values, dtype=np.float64)
        dt = np.diff(t, prepend=t[0] if math.isnan(self._last_t) else self._last_t)
        if driven is not None:
            dt = np.where(np.asarray(driven, dtype=bool), dt, 0.0)
        counted = np.cumsum(dt[::-1])[::-1]  # driven time from each sample's interval to the last sample
        changed = np.vstack((v[:1] != self._value, v[1:] != v[:-1]))  # (n, channels): differs from the sample before
        for c in range(v.shape[1]):
            moves = np.flatnonzero(changed[:, c])
            if moves.size:  # held since that sample: the driven time after it
                k = moves[-1]
                self._held[c] = counted[k + 1] if k + 1 < t.size else 0.0
            else:
                self._held[c] += counted[0]
        self._value = v[-1].copy()
        self._last_t = float(t[-1])

    def stuck(self) -> str:
        """'' while every channel moves; else one line naming the first channel that has held one value for longer
        than the limit (driven time), with the value and for how long."""
        for c, name in enumerate(self.channels):
            held = self._held[c]
            if held > self.limit_s:
                return (f"{name} held {self._value[c]:g} for {held:.3g} s ({held * self.frequency_hz:.3g} periods) "
                        "while the sine ran")
        return ""


def no_fundamental(points: Sequence[ResponsePoint]) -> str:
    """'' when every channel answered the sine; else one line naming the first channel whose harmonic 1 is zero to
    within the instrument's resolution (a drive that stopped following, a plant at rest): no response to measure."""
    for p in points:
        if p.harmonic == 1 and p.status == PointStatus.BELOW_RESOLUTION:
            return (f"{p.channel} shows no response at harmonic 1 (|Z| = {p.magnitude:.3g}, below the resolution of "
                    "the channel's largest coefficient)")
    return ""
