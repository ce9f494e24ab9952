"""What every stopping rule is: the :class:`StoppingRule` interface, its :class:`Verdict`, the statuses a
finished series can carry and the tolerance a value is judged against.

Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

from bodebench.core.rules.history import SeriesHistory
from bodebench.core.rules.intervals import _BLOCKS, settled_estimate
from bodebench.status import PointStatus

# statuses a finished series can carry
CONVERGED = PointStatus.CONVERGED
BELOW_RESOLUTION = PointStatus.BELOW_RESOLUTION
FIXED = PointStatus.FIXED
CAPPED = PointStatus.CAPPED
NOISE_LIMITED = PointStatus.NOISE_LIMITED

@dataclass(frozen=True)
class Verdict:
    """What a rule decided about a series at period ``period``.

    p, q: the coefficient estimate (output units). uncertainty: radius of the 95 % confidence disc of (p, q),
    output units (statistical part plus a bound on the transient left; NaN where the history gives no basis
    for one). uncertainty_1d: 95 % half-width of the estimate's projection on any one direction (the radial
    one bounds the gain, the tangential one the phase), output units. status: converged, below_resolution,
    fixed, capped or noise_limited. method: how the estimate was formed. within_eps: the stated uncertainty
    is within the tolerance (false for a printed rule whose stop its own history does not support).
    periods_needed: for a noise-limited point, the periods the requested eps would take (0: not estimated).
    """

    period: int
    p: float
    q: float
    uncertainty: float
    status: str
    method: str
    uncertainty_1d: float = math.nan
    within_eps: bool = False
    periods_needed: int = 0

    @property
    def converged(self) -> bool:
        return self.status in (CONVERGED, BELOW_RESOLUTION, FIXED)


RESOLUTION = 1e-3
"""Absolute floor of the tolerance, as a fraction of the channel's largest coefficient."""


def _tolerance(e: float, size: float, floor: float) -> float:
    """e max(size, floor): the tolerance of a value of magnitude ``size`` (output units), e = eps / 100, floor the
    absolute floor (RESOLUTION times the channel scale, output units)."""
    return e * max(size, floor)


class StoppingRule(ABC):
    """Decides, period after period, when a series is measured.

    tolerance_percent: eps (%); skip_periods: n_k, periods never analysed. Whatever the rule, a verdict
    states the honest uncertainty of its value from the same history (:meth:`verdict`).
    """

    name: str = ""

    def __init__(self, tolerance_percent: float, skip_periods: int) -> None:
        self.eps = tolerance_percent
        self.skip = skip_periods

    def tolerance(self, z: complex, channel_scale: float) -> float:
        """eps/100 * max(|z|, RESOLUTION * channel_scale), output units."""
        return _tolerance(self.eps / 100.0, abs(z), RESOLUTION * channel_scale)

    @abstractmethod
    def check(self, hist: SeriesHistory, n: int, channel_scale: float) -> Verdict | None:
        """Verdict at period n (n <= hist.n), or None to go on integrating.

        channel_scale: magnitude of the channel's largest coefficient (output units),
        the scale against which a coefficient near zero is judged.
        """

    @abstractmethod
    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        """The rule's current estimate and uncertainty at period n (progress displays, capped points)."""

    def progress(self, hist: SeriesHistory, n: int) -> tuple[complex, float, float]:
        """:meth:`estimate` and the half-width the rule compares with the tolerance to stop (output units): the
        stated uncertainty, unless the rule stops on another (the ETA follows that one)."""
        value, uncertainty = self.estimate(hist, n)
        return value, uncertainty, uncertainty

    def verdict(self, hist: SeriesHistory, n: int, value: complex, status: str, channel_scale: float) -> Verdict:
        """A verdict on ``value`` with the uncertainty the history supports: |value - E| + U(E).

        E is the settled estimate at n (:func:`settled_estimate`); where its transient is not yet bounded
        the uncertainty is still stated but ``within_eps`` is false.
        """
        settled = settled_estimate(hist, self.skip, n) if n - self.skip >= 2 * _BLOCKS else None
        if settled is None or math.isnan(settled.uncertainty):
            return Verdict(n, value.real, value.imag, math.nan, status, self.name)
        gap = abs(value - settled.value)
        u = gap + settled.uncertainty
        within = settled.bounded and u <= self.tolerance(value, channel_scale)
        return Verdict(n, value.real, value.imag, u, status, self.name, uncertainty_1d=gap + settled.uncertainty_1d,
                       within_eps=within)

    def capped(self, hist: SeriesHistory, n: int, channel_scale: float) -> Verdict:
        """The verdict when max_periods is reached before the rule stopped."""
        return self.verdict(hist, n, self.estimate(hist, n)[0], CAPPED, channel_scale)

