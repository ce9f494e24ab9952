"""The paper's stopping rules exactly as printed (NoAveraging, LocalAveraging, FullAveraging, Combined1-3) and the
fixed schemes (FixedScheme: first period, sixth of six, settle N average M).

Each compares two running quantities with the paper's relative test on P and Q; its verdict states the
uncertainty the same history supports (:meth:`~bodebench.core.rules.rule.StoppingRule.verdict`).
Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import math
from abc import abstractmethod

from bodebench.core.rules.history import SeriesHistory
from bodebench.core.rules.rule import CONVERGED, FIXED, StoppingRule, Verdict


def relative_change_percent(current: float, previous: float) -> float:
    """|(|current| - |previous|) / |current|| * 100, the paper's test quantity (inf for x/0, NaN for 0/0)."""
    num = abs(abs(current) - abs(previous))
    den = abs(current)
    if den == 0.0:
        return math.inf if num > 0 else math.nan
    return num / den * 100.0


def _both_within(a: complex, b: complex, eps: float) -> bool:
    """The paper's test on P and Q separately: a is the current/reference value, b the compared one."""
    return (relative_change_percent(a.real, b.real) <= eps
            and relative_change_percent(a.imag, b.imag) <= eps)


class _PrintedRule(StoppingRule):
    """A rule of the paper's family: compares two running quantities with the relative test on P and Q."""

    def __init__(self, tolerance_percent: float, skip_periods: int, window: int = 5) -> None:
        super().__init__(tolerance_percent, skip_periods)
        self.window = window

    def full(self, hist: SeriesHistory, n: int) -> complex:
        """Pc(n): mean over periods n_k+1..n."""
        return hist.mean(self.skip, n)

    def local(self, hist: SeriesHistory, n: int) -> complex:
        """Mean of the last l periods at n."""
        return hist.mean(n - self.window, n)

    @abstractmethod
    def first_period(self) -> int:
        """The first n at which both compared quantities exist."""

    @abstractmethod
    def compare(self, hist: SeriesHistory, n: int) -> tuple[complex, complex]:
        """(reference value, compared value) at n; the reference value is the reported estimate."""

    def check(self, hist: SeriesHistory, n: int, channel_scale: float) -> Verdict | None:
        if n < self.first_period():
            return None
        a, b = self.compare(hist, n)
        if _both_within(a, b, self.eps):
            return self.verdict(hist, n, a, CONVERGED, channel_scale)
        return None

    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        if n < self.first_period():
            return hist.at(n), math.nan
        return self.compare(hist, n)[0], math.nan


class NoAveraging(_PrintedRule):
    """P(n) against P(n-1)."""

    name = "none"

    def first_period(self) -> int:
        return self.skip + 2

    def compare(self, hist: SeriesHistory, n: int) -> tuple[complex, complex]:
        return hist.at(n), hist.at(n - 1)


class LocalAveraging(_PrintedRule):
    """Mean of the last l periods at n against the same at n-1."""

    name = "local"

    def first_period(self) -> int:
        return self.skip + self.window + 1

    def compare(self, hist: SeriesHistory, n: int) -> tuple[complex, complex]:
        return self.local(hist, n), self.local(hist, n - 1)


class FullAveraging(_PrintedRule):
    """Pc(n) against Pc(n-1): the paper's choice."""

    name = "full"

    def first_period(self) -> int:
        return self.skip + 2

    def compare(self, hist: SeriesHistory, n: int) -> tuple[complex, complex]:
        return self.full(hist, n), self.full(hist, n - 1)


class Combined1(_PrintedRule):
    """P(n) against the mean of the last l periods (reported: the mean)."""

    name = "combined1"

    def first_period(self) -> int:
        return self.skip + self.window

    def compare(self, hist: SeriesHistory, n: int) -> tuple[complex, complex]:
        return self.local(hist, n), hist.at(n)


class Combined2(_PrintedRule):
    """P(n) against Pc(n) (reported: Pc)."""

    name = "combined2"

    def first_period(self) -> int:
        return self.skip + 2

    def compare(self, hist: SeriesHistory, n: int) -> tuple[complex, complex]:
        return self.full(hist, n), hist.at(n)


class Combined3(_PrintedRule):
    """Mean of the last l periods against Pc(n) (reported: Pc)."""

    name = "combined3"

    def first_period(self) -> int:
        return self.skip + self.window + 1

    def compare(self, hist: SeriesHistory, n: int) -> tuple[complex, complex]:
        return self.full(hist, n), self.local(hist, n)


class FixedScheme(StoppingRule):
    """Discard ``settle`` periods, average the next ``average``, stop: no test at all.

    The paper's older schemes are special cases: first period (0, 1) and
    sixth of six (5, 1). tolerance_percent is only the eps its ``within_eps`` flag is judged against.
    """

    def __init__(self, settle: int, average: int, name: str = "fixed", tolerance_percent: float = 0.0) -> None:
        super().__init__(tolerance_percent, settle)
        self.average = average
        self.name = name

    def check(self, hist: SeriesHistory, n: int, channel_scale: float) -> Verdict | None:
        if n < self.skip + self.average:
            return None
        return self.verdict(hist, n, self.estimate(hist, n)[0], FIXED, channel_scale)

    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        return hist.mean(min(self.skip, n - 1), n), math.nan

