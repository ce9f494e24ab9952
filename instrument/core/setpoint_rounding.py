"""The excitation the drive is given, where the setpoint's frame rounds the sine the host sends.

The host sends ``A sin(2 pi f (c - c0) h)`` at each tick c, and a frame carries it rounded to its signal's step (an
integer count of its scale; a CANopen object's ``setpoint_scale``). The drive is given that staircase, whose
fundamental is ``rho`` times the sine's (complex: size and phase). On a whole number of ticks a period the rounding
is the same every period and no averaging removes it: an amplitude of 20 steps moves the fundamental by about
0.5 %. ``rho`` follows from the ticks and the frame's rounding alone, so each point is taken against the staircase's
fundamental instead of the sine's, as two-channel mode takes it against a reference's: harmonic k's coefficient is
turned back by k times rho's phase and divided by its size. Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace

import numpy as np

from bodebench.core.response import ResponsePoint

__all__ = ["SIGNIFICANT", "rounding_ratios", "taken_against"]

SIGNIFICANT = 0.01
"""Share of a point's tolerance (relative) below which ``|rho - 1|`` leaves the point as measured."""

_CHUNK = 1 << 20  # ticks worked on at once


def rounding_ratios(carried: Callable[[np.ndarray], np.ndarray], amplitude: float, frequency_hz: float,
                    tick_s: float, tick0: int, t0: float, periods: Iterable[int]) -> dict[int, complex]:
    """For each n of ``periods``: the fundamental over periods 1..n after ``t0`` (s) of the setpoints as their frames
    carry them (``carried``: physical values in, rounded values out), over that of the sine sent at ticks of
    ``tick_s`` (s) from phase zero at tick ``tick0``; 1 where the sine sent has no fundamental there."""
    wanted = sorted({int(n) for n in periods if n >= 1})
    if not wanted:
        return {}
    f, last = frequency_hz, wanted[-1]
    first_tick = math.ceil(t0 / tick_s - 1e-9)
    stop_tick = math.ceil((t0 + last / f) / tick_s - 1e-9)
    sums = np.zeros((2, last), dtype=np.complex128)  # (carried, sent) per period
    for start in range(first_tick, stop_tick, _CHUNK):
        c = np.arange(start, min(stop_tick, start + _CHUNK), dtype=np.float64)
        sent = amplitude * np.sin(2.0 * math.pi * f * (c - tick0) * tick_s)
        turns = f * (c * tick_s - t0)
        weight = np.exp(-2j * math.pi * turns)
        period = np.clip(np.floor(turns + 1e-9).astype(np.int64), 0, last - 1)
        for row, values in enumerate((carried(sent), sent)):
            product = values * weight
            sums[row] += np.bincount(period, product.real, last) + 1j * np.bincount(period, product.imag, last)
    cumulative = np.cumsum(sums, axis=1)
    out = {}
    for n in wanted:
        carried_sum, sent_sum = cumulative[0, n - 1], cumulative[1, n - 1]
        out[n] = complex(carried_sum / sent_sum) if sent_sum != 0 else 1.0 + 0.0j
    return out


def taken_against(points: Sequence[ResponsePoint], ratios: dict[int, complex]) -> list[ResponsePoint]:
    """``points`` taken against the staircase's fundamental: each point of harmonic k, whose periods have the ratio
    rho (:func:`rounding_ratios`), turned back by k times rho's phase and divided by its size, its intervals too;
    left as measured where ``|rho - 1|`` is under :data:`SIGNIFICANT` of its tolerance."""
    out = []
    for p in points:
        rho = ratios.get(p.periods, 1.0 + 0.0j)
        if abs(rho - 1.0) <= SIGNIFICANT * p.tolerance_percent / 100.0 or rho == 0:
            out.append(p)
            continue
        size = abs(rho)
        z = complex(p.p, p.q) * cmath.exp(-1j * p.harmonic * cmath.phase(rho)) / size
        out.append(replace(p, p=z.real, q=z.imag, uncertainty=p.uncertainty / size,
                           uncertainty_1d=p.uncertainty_1d / size))
    return out
