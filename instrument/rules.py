"""Stopping rules of monoharmonic autointegration (METHOD.md section 1).

A rule looks at the per-period Fourier coefficients of one series (one
channel, one harmonic), held as complex numbers ``Z(i) = P(i) + j Q(i)``, and
decides after period ``n`` whether the point is measured and what its value
is. The paper's rules are implemented exactly as printed; ``adaptive`` is the
default, built to deliver the requested error (see the README's "Stopping
rules" section for the evidence).

Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
from scipy import stats

CRITERIA: tuple[str, ...] = (
    "adaptive",
    "full",
    "none",
    "local",
    "combined1",
    "combined2",
    "combined3",
    "first_period",
    "sixth_of_six",
    "fixed",
)

# statuses a finished series can carry
CONVERGED = "converged"
BELOW_RESOLUTION = "below_resolution"
FIXED = "fixed"
CAPPED = "capped"


@dataclass(frozen=True)
class Verdict:
    """What a rule decided about a series at period ``period``.

    p, q: the coefficient estimate (output units); uncertainty: half-width of
    the ~95 % confidence region of (p, q) in output units (NaN where the rule
    has no basis for one); status: one of converged, below_resolution, fixed,
    capped; method: how the estimate was formed.
    """

    period: int
    p: float
    q: float
    uncertainty: float
    status: str
    method: str

    @property
    def converged(self) -> bool:
        return self.status in (CONVERGED, BELOW_RESOLUTION, FIXED)


class SeriesHistory:
    """Per-period coefficients Z(i) = P(i) + jQ(i), i = 1..n, of one series, with running sums."""

    def __init__(self) -> None:
        self._z = np.empty(256, dtype=complex)
        self._cum = np.zeros(257, dtype=complex)  # _cum[i] = Z(1) + ... + Z(i)
        self.n = 0

    def extend(self, z: np.ndarray) -> None:
        """Append the coefficients of the next periods (complex array)."""
        z = np.asarray(z, dtype=complex).reshape(-1)
        need = self.n + z.size
        if need > self._z.size:
            size = max(need, 2 * self._z.size)
            self._z = np.resize(self._z, size)
            cum = np.zeros(size + 1, dtype=complex)
            cum[: self.n + 1] = self._cum[: self.n + 1]
            self._cum = cum
        self._z[self.n:need] = z
        self._cum[self.n + 1:need + 1] = self._cum[self.n] + np.cumsum(z)
        self.n = need

    @property
    def values(self) -> np.ndarray:
        """Z(1..n) as a read-only view."""
        v = self._z[: self.n]
        v.flags.writeable = False
        return v

    def at(self, i: int) -> complex:
        """Z(i), periods counted from 1."""
        return complex(self._z[i - 1])

    def mean(self, a: int, b: int) -> complex:
        """Mean of Z over periods a+1..b."""
        return complex((self._cum[b] - self._cum[a]) / (b - a))

    def batch_uncertainty(self, a: int, b: int, batches: int = 8, confidence: float = 0.95) -> float:
        """Half-width of the confidence region of the mean over periods a+1..b, from batch means (output units).

        Batches absorb correlation between neighbouring periods; NaN with fewer than two periods a batch.
        """
        length = b - a
        nb = min(batches, length // 2)
        if nb < 2:
            return math.nan
        edges = a + (np.arange(nb + 1) * length) // nb
        sums = self._cum[edges[1:]] - self._cum[edges[:-1]]
        means = sums / np.diff(edges)
        spread = np.sqrt(np.sum(np.abs(means - means.mean()) ** 2) / (nb * (nb - 1)))
        return float(_student_t(confidence, nb - 1) * spread)


@functools.lru_cache(maxsize=64)
def _student_t(confidence: float, dof: int) -> float:
    """Two-sided Student t quantile (computed once per confidence and degrees of freedom)."""
    return float(stats.t.ppf(0.5 + confidence / 2, dof))


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


class StoppingRule(ABC):
    """Decides, period after period, when a series is measured.

    tolerance_percent: eps (%); skip_periods: n_k, periods never analysed.
    """

    name: str = ""

    def __init__(self, tolerance_percent: float, skip_periods: int) -> None:
        self.eps = tolerance_percent
        self.skip = skip_periods

    @abstractmethod
    def check(self, hist: SeriesHistory, n: int, reference: float) -> Verdict | None:
        """Verdict at period n (n <= hist.n), or None to go on integrating.

        reference: magnitude of the channel's largest coefficient (output units),
        the scale against which a coefficient near zero is judged.
        """

    @abstractmethod
    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        """The rule's current estimate and uncertainty at period n, for a point ended by the period cap."""

    def capped(self, hist: SeriesHistory, n: int) -> Verdict:
        """The verdict when max_periods is reached before the rule stopped."""
        z, u = self.estimate(hist, n)
        return Verdict(n, z.real, z.imag, u, CAPPED, self.name)


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

    def check(self, hist: SeriesHistory, n: int, reference: float) -> Verdict | None:
        if n < self.first_period():
            return None
        a, b = self.compare(hist, n)
        if _both_within(a, b, self.eps):
            return Verdict(n, a.real, a.imag, self._uncertainty(hist, n), CONVERGED, self.name)
        return None

    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        if n < self.first_period():
            return hist.at(n), math.nan
        return self.compare(hist, n)[0], self._uncertainty(hist, n)

    def _uncertainty(self, hist: SeriesHistory, n: int) -> float:
        return hist.batch_uncertainty(self.averaged_from(n), n)

    def averaged_from(self, n: int) -> int:
        """Periods after this one make up the reported average."""
        return self.skip


class NoAveraging(_PrintedRule):
    """P(n) against P(n-1)."""

    name = "none"

    def first_period(self) -> int:
        return self.skip + 2

    def compare(self, hist: SeriesHistory, n: int) -> tuple[complex, complex]:
        return hist.at(n), hist.at(n - 1)

    def averaged_from(self, n: int) -> int:
        return n - 1


class LocalAveraging(_PrintedRule):
    """Mean of the last l periods at n against the same at n-1."""

    name = "local"

    def first_period(self) -> int:
        return self.skip + self.window + 1

    def compare(self, hist: SeriesHistory, n: int) -> tuple[complex, complex]:
        return self.local(hist, n), self.local(hist, n - 1)

    def averaged_from(self, n: int) -> int:
        return n - self.window


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

    def averaged_from(self, n: int) -> int:
        return n - self.window


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
    sixth of six (5, 1).
    """

    def __init__(self, settle: int, average: int, name: str = "fixed") -> None:
        super().__init__(0.0, settle)
        self.average = average
        self.name = name

    def check(self, hist: SeriesHistory, n: int, reference: float) -> Verdict | None:
        if n < self.skip + self.average:
            return None
        z, u = self.estimate(hist, n)
        return Verdict(n, z.real, z.imag, u, FIXED, self.name)

    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        start = min(self.skip, n - 1)
        return hist.mean(start, n), hist.batch_uncertainty(start, n)


def extrapolate_modes(z: np.ndarray, modes: int, max_decay: float = 0.5) -> tuple[complex, float] | None:
    """Limit of a sequence ``Z(i) = Z_inf + sum_r a_r lambda_r**i`` from a least-squares linear-prediction fit.

    The real recurrence ``Z(i) = c + sum_r alpha_r Z(i-r)`` is fitted to P and Q
    jointly; ``Z_inf = c / (1 - sum alpha)``. The fit is only trusted where the
    data show the transient dying: every mode must shrink to at most
    ``max_decay`` of itself over the fitted stretch (a mode on or outside the
    unit circle, a beat of a conservative link or a growing response, has no
    limit). Returns (Z_inf, rms residual of the fit scaled like Z_inf), or
    None when the sequence is too short or no limit is shown.
    """
    n = z.size
    rows = n - modes
    if rows < modes + 3:
        return None
    x = np.zeros((2 * rows, modes + 2))
    for r in range(1, modes + 1):
        col = z[modes - r:n - r]
        x[:rows, r - 1] = col.real
        x[rows:, r - 1] = col.imag
    x[:rows, modes] = 1.0
    x[rows:, modes + 1] = 1.0
    y = np.concatenate([z[modes:].real, z[modes:].imag])
    sol, *_ = np.linalg.lstsq(x, y, rcond=None)
    lambdas = np.roots(np.concatenate([[1.0], -sol[:modes]]))
    if np.any(np.abs(lambdas) ** n > max_decay):
        return None
    den = 1.0 - float(np.sum(sol[:modes]))
    resid = y - x @ sol
    return complex(sol[modes], sol[modes + 1]) / den, float(np.sqrt(np.mean(resid ** 2))) / abs(den)


class AdaptiveRule(StoppingRule):
    """The default: stops when the estimate's own error bound is within eps, with two estimators.

    1. Modal extrapolation. A transient that decays through a few modes makes
       Z(i) - Z_inf a sum of geometric sequences (linear plants exactly, a
       stable limit cycle asymptotically). The limit is fitted on the last
       ``2*w`` periods as two independent windows of ``w`` periods; it is
       accepted when both windows agree and each fit's residual is within
       the tolerance, i.e. when the model demonstrably explains the data.
    2. Settled-window mean. The first half of the periods is discarded (the
       window forgets the start-up transient, unlike the full average), the
       rest is averaged; accepted when the means of the window's two halves
       agree and the batch-means confidence half-width is within the tolerance.

    Tolerance: ``eps/100 * max(|Z|, resolution * reference)``: a coefficient
    far below the channel's largest one is measured to an absolute floor and
    reported as below resolution when its confidence region contains zero.
    """

    name = "adaptive"

    def __init__(self, tolerance_percent: float, skip_periods: int, *, modes: int = 2, min_window: int = 8,
                 resolution: float = 1e-3, min_periods: int = 4) -> None:
        super().__init__(tolerance_percent, skip_periods)
        self.modes = modes
        self.min_window = min_window
        self.resolution = resolution
        self.min_periods = min_periods
        self._next_extrapolation = 0

    def _tolerance(self, z: complex, reference: float) -> float:
        return self.eps / 100.0 * max(abs(z), self.resolution * reference)

    def _window(self, n: int) -> int:
        return max(self.skip, n // 2)

    def _mean_estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float, float]:
        """(window mean, drift between its halves, batch-means half-width) over the settled window."""
        s = self._window(n)
        mid = s + (n - s) // 2
        mean = hist.mean(s, n)
        drift = abs(hist.mean(mid, n) - hist.mean(s, mid))
        return mean, drift, hist.batch_uncertainty(s, n)

    def _extrapolated(self, hist: SeriesHistory, n: int) -> tuple[complex, float, float] | None:
        """(limit, disagreement of the two windows, worst fit residual) or None."""
        w = max(self.min_window, (n - self.skip) // 4)
        if n - 2 * w < self.skip:
            return None
        z = hist.values
        first = extrapolate_modes(z[n - 2 * w:n - w], self.modes)
        second = extrapolate_modes(z[n - w:n], self.modes)
        if first is None or second is None:
            return None
        return second[0], abs(first[0] - second[0]), max(first[1], second[1])

    def check(self, hist: SeriesHistory, n: int, reference: float) -> Verdict | None:
        if n - self.skip < self.min_periods:
            return None
        mean, drift, spread = self._mean_estimate(hist, n)
        tol = self._tolerance(mean, reference)
        floor = self._tolerance(0.0, reference)
        if drift <= tol and spread <= tol:
            return self._finish(n, mean, drift + spread, floor, "window mean")
        # the fit costs more than the mean: once windows are long, try it on a sparser schedule
        if self.modes > 0 and n >= self._next_extrapolation:
            self._next_extrapolation = n + max(1, (n - self.skip) // 32)
            fit = self._extrapolated(hist, n)
            if fit is not None:
                limit, disagreement, residual = fit
                tol = self._tolerance(limit, reference)
                if disagreement <= tol and residual <= tol:
                    return self._finish(n, limit, disagreement + 2.0 * residual, floor, "extrapolated")
        return None

    def _finish(self, n: int, z: complex, uncertainty: float, floor: float, method: str) -> Verdict:
        """A coefficient within its own uncertainty or the absolute floor of zero has no phase."""
        status = BELOW_RESOLUTION if abs(z) <= max(uncertainty, floor) else CONVERGED
        return Verdict(n, z.real, z.imag, uncertainty, status, method)

    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        if n - self._window(n) < 2:
            return hist.at(n), math.nan
        mean, drift, spread = self._mean_estimate(hist, n)
        return mean, drift + spread if not math.isnan(spread) else math.nan


def make_rule(criterion: str, *, tolerance_percent: float, skip_periods: int, window: int,
              settle_periods: int = 50, average_periods: int = 50) -> StoppingRule:
    """The rule a config's ``analysis.criterion`` names (a fresh object per series: rules keep state)."""
    if criterion == "adaptive":
        return AdaptiveRule(tolerance_percent, skip_periods)
    if criterion == "first_period":
        return FixedScheme(0, 1, "first_period")
    if criterion == "sixth_of_six":
        return FixedScheme(5, 1, "sixth_of_six")
    if criterion == "fixed":
        return FixedScheme(settle_periods, average_periods, "fixed")
    printed: dict[str, type[_PrintedRule]] = {
        "none": NoAveraging, "local": LocalAveraging, "full": FullAveraging,
        "combined1": Combined1, "combined2": Combined2, "combined3": Combined3,
    }
    try:
        return printed[criterion](tolerance_percent, skip_periods, window)
    except KeyError:
        raise ValueError(f"unknown criterion {criterion!r}; one of {', '.join(CRITERIA)}") from None
