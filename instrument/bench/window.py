"""Which of a bench point's samples are analysed, and from when: :class:`PointWindow`. Pure: no I/O, no clock.

Period 1 of a point starts at t0, after the ramp and the settle periods. The window hands the analysis the samples
after t0, led by the last sample at or before t0 (the integrator takes a stream that starts at or before t0, and
starts period 1 on the first sample at or after it); moves t0 on by
whole periods when the drive's first sample of the point comes after it (the excitation's phase stays zero at t0);
and leaves out the samples of stretches in which the drive held a stale setpoint for longer than the longest gap a
period may hold (the realtime clock: a setpoint sent late, ticks skipped), whose feedback answers no sine.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

__all__ = ["PointWindow", "Taken", "outside"]


def outside(t: np.ndarray, stretches: list[tuple[float, float]]) -> np.ndarray:
    """(n,) True for each time of ``t`` (s) in none of the closed ``stretches`` [(start, end), ...] (s)."""
    keep = np.ones(t.shape, dtype=bool)
    for a, b in stretches:
        keep &= (t < a) | (t > b)
    return keep


class Taken(NamedTuple):
    """What :meth:`PointWindow.take` makes of a batch: the times (s) and values to analyse, whether t0 moved (the
    analysis then starts again from the new t0), and how many samples of stale stretches were left out."""

    t: np.ndarray
    values: np.ndarray
    moved: bool
    stale: int


class PointWindow:
    """The analysed samples of one point at ``frequency_hz`` (Hz), period 1 starting at ``t0`` (s); stale stretches
    longer than ``longest_gap_s`` (s) are left out (module docstring)."""

    def __init__(self, t0: float, frequency_hz: float, longest_gap_s: float) -> None:
        self.t0 = t0
        """Start of period 1 (s); moves by whole periods where the drive's first sample came after it."""
        self.frequency_hz = frequency_hz
        self.longest_gap_s = longest_gap_s
        self._held: tuple[float, np.ndarray] | None = None  # the last sample at or before t0 (inf once handed on)
        self._stale: list[tuple[float, float]] = []

    def take(self, t: np.ndarray, values: np.ndarray, held: Iterable[tuple[float, float]] = ()) -> Taken:
        """One batch of samples: times ``t`` (s, increasing), ``values`` (n, columns), and ``held``, the stretches
        (start, end in s) in which the drive held a stale setpoint."""
        self._stale.extend((a, b) for a, b in held if b - a > self.longest_gap_s)
        stale = 0
        if self._stale and t.size:
            self._stale = [(a, b) for a, b in self._stale if b >= t[0]]
            fresh = outside(t, self._stale) | (t <= self.t0)  # before period 1 (the ramp) nothing is integrated
            if not fresh.all():
                stale = int(fresh.size - np.count_nonzero(fresh))
                t, values = t[fresh], values[fresh]
        moved = False
        if self._held is None and t.size and t[0] > self.t0:
            self.t0 += math.ceil((t[0] - self.t0) * self.frequency_hz) / self.frequency_hz
            moved = True
        keep = t > self.t0
        if self._held is None or not np.all(keep):
            before = np.flatnonzero(~keep)
            if before.size:
                self._held = (float(t[before[-1]]), values[before[-1]])
        t, values = t[keep], values[keep]
        if t.size and self._held is not None and self._held[0] <= self.t0:
            t = np.concatenate([[self._held[0]], t])
            values = np.vstack([self._held[1][None, :], values])
            self._held = (math.inf, self._held[1])
        return Taken(t, values, moved, stale)
