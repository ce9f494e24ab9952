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

from bodebench.status import PointStatus

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
CONVERGED = PointStatus.CONVERGED
BELOW_RESOLUTION = PointStatus.BELOW_RESOLUTION
FIXED = PointStatus.FIXED
CAPPED = PointStatus.CAPPED
NOISE_LIMITED = PointStatus.NOISE_LIMITED

CONFIDENCE = 0.95
"""Level of every interval a rule states."""


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


class SeriesHistory:
    """Per-period coefficients Z(i) = P(i) + jQ(i), i = 1..n, of one series, with running sums.

    Running sums of Z and of |Z - Z(1)|^2 (taken about the first value, so that the sums of squares of a
    steady series do not cancel catastrophically) make every window mean and spread O(1).
    """

    def __init__(self) -> None:
        self._z = np.empty(256, dtype=complex)
        self._cum = np.zeros(257, dtype=complex)  # _cum[i] = Z(1) + ... + Z(i)
        self._cum2 = np.zeros(257)  # _cum2[i] = |Z(1) - Z(1)|^2 + ... + |Z(i) - Z(1)|^2
        self._lag = np.zeros(257, dtype=complex)  # _lag[i] = sum over j = 2..i of (Z(j) - Z(1)) conj(Z(j-1) - Z(1))
        self.n = 0

    def extend(self, z: np.ndarray) -> None:
        """Append the coefficients of the next periods (complex array)."""
        z = np.asarray(z, dtype=complex).reshape(-1)
        need = self.n + z.size
        if need > self._z.size:
            size = max(need, 2 * self._z.size)
            self._z = np.resize(self._z, size)
            for name in ("_cum", "_cum2", "_lag"):
                old = getattr(self, name)
                new = np.zeros(size + 1, dtype=old.dtype)
                new[: self.n + 1] = old[: self.n + 1]
                setattr(self, name, new)
        self._z[self.n:need] = z
        self._cum[self.n + 1:need + 1] = self._cum[self.n] + np.cumsum(z)
        centred = self._z[max(self.n - 1, 0):need] - self._z[0]
        self._cum2[self.n + 1:need + 1] = self._cum2[self.n] + np.cumsum(np.abs(centred[-z.size:]) ** 2)
        products = centred[1:] * np.conj(centred[:-1])  # (Z(j) - Z(1)) conj(Z(j-1) - Z(1)), j = max(n, 1)+1..need
        self._lag[need - products.size + 1:need + 1] = self._lag[need - products.size] + np.cumsum(products)
        self.n = need

    @property
    def values(self) -> np.ndarray:
        """Z(1..n) as a read-only view."""
        v = self._z[: self.n]
        v.flags.writeable = False
        return v

    @property
    def cumulative(self) -> np.ndarray:
        """Running sums: ``cumulative[i] = Z(1) + ... + Z(i)``, i = 0..n (read-only view)."""
        c = self._cum[: self.n + 1]
        c.flags.writeable = False
        return c

    def at(self, i: int) -> complex:
        """Z(i), periods counted from 1."""
        return complex(self._z[i - 1])

    def mean(self, a: int, b: int) -> complex:
        """Mean of Z over periods a+1..b."""
        return complex((self._cum[b] - self._cum[a]) / (b - a))

    def lag_correlation(self, a: int, b: int) -> float:
        """|lag-1 autocorrelation| of Z over periods a+1..b (0: independent periods; near 1: a smooth or turning signal)."""
        length = b - a
        if length < 3:
            return math.nan
        shift = (self._cum[b] - self._cum[a]) / length - self._z[0]
        # sum of (Z(j) - m) conj(Z(j-1) - m) over j = a+2..b, expanded about Z(1)
        inner = self._cum[b] - self._cum[a + 1] - self._z[0] * (length - 1)
        outer = self._cum[b - 1] - self._cum[a] - self._z[0] * (length - 1)
        cov = (self._lag[b] - self._lag[a + 1]) - inner * np.conj(shift) - shift * np.conj(outer) \
            + (length - 1) * abs(shift) ** 2
        var = self.scatter(a, b)
        return abs(complex(cov)) / var if var > 0.0 else math.nan

    def scatter(self, a: int, b: int) -> float:
        """Sum of |Z(i) - mean|^2 over periods a+1..b (output units squared)."""
        shift = (self._cum[b] - self._cum[a]) / (b - a) - self._z[0]
        return max(0.0, float(self._cum2[b] - self._cum2[a]) - (b - a) * abs(shift) ** 2)


def _disc_factor(dof: int, confidence: float = CONFIDENCE) -> float:
    """Radius, in standard deviations per component, of the confidence disc of a circular 2-D normal mean.

    The variance is estimated with ``dof`` degrees of freedom, so |error|^2 / (2 s^2) follows F(2, dof);
    F(2, d) has the closed-form quantile d/2 ((1 - c)^(-2/d) - 1).
    """
    f = dof / 2.0 * ((1.0 - confidence) ** (-2.0 / dof) - 1.0)
    return math.sqrt(2.0 * f)


@functools.lru_cache(maxsize=256)
def _line_factor(dof: int, confidence: float = CONFIDENCE) -> float:
    """Two-sided Student t quantile: the 95 % half-width of one component, in standard deviations."""
    from scipy import stats  # imported where used: it is slow to import

    return float(stats.t.ppf(0.5 + confidence / 2.0, dof))


_BLOCKS = 4          # quarter-blocks of the analysed record
_SUB_BATCHES = 8     # batches per block for the statistical spread
_MAX_RATIO = 0.5     # a visible drift must shrink at least this fast from block to block
_DRIFT_SIGMAS = 3.72  # |d| / sigma_d of a 2-D normal exceeds this with probability 0.1 %
_ROUND_OFF = 1e-12    # relative size of a change that round-off of the running sums can make
_HOPELESS = 2.0       # a point whose projected periods exceed this many budgets ends noise-limited at once
_MIN_NOISE_EVIDENCE = 128  # analysed periods before the noise is judged hopeless
_WHITE_RATIO = 2.0    # batch-mean variance over per-period variance still taken for independent periods
_WHITE_LAG = 0.2      # |lag-1 autocorrelation| still taken for independent periods


@dataclass(frozen=True)
class Estimate:
    """An estimate of a series' limit with its error bound (output units).

    uncertainty: 95 % disc radius, statistical + bias; uncertainty_1d: 95 % half-width along one direction,
    statistical + bias; statistical: the disc radius from noise alone; bounded: whether the history shows
    that the transient left is bounded (False: no error bound exists yet; the uncertainties are then the
    best available but not a guarantee); white: the periods scatter like independent noise.
    """

    value: complex
    uncertainty: float
    uncertainty_1d: float
    statistical: float
    bounded: bool
    white: bool = False

    @property
    def bias(self) -> float:
        return self.uncertainty - self.statistical


def settled_estimate(hist: SeriesHistory, skip: int, n: int) -> Estimate:
    """The mean of the settled part of periods skip+1..n, with its 95 % bounds (output units).

    The analysed record is cut into four equal blocks, each into up to eight batches. Noise: the
    pooled spread of the batch means about their own block's mean in the last three blocks (between-block
    drift excluded), with 3 blocks x (batches - 1) x 2 degrees of freedom. Drift: the changes d2, d3 between the means of
    blocks 2-3 and 3-4. A drift the noise cannot explain must shrink geometrically, |d3| <= |d2| / 2,
    before the transient is bounded (and so must d2 against d1); the transient left in the mean of
    blocks 3-4 is then at most 1.5 |d3| (the tail of a geometric sequence of ratio <= 1/2). Only where
    the periods scatter like independent noise (``white``: a smooth or turning transient inflates the
    spread and would hide a drift) and no drift is seen over blocks 2-4 is their mean the estimate, the
    bias term zero and the interval purely statistical.
    """
    length = (n - skip) // _BLOCKS
    if length < 2:
        z = hist.at(n)
        return Estimate(z, math.nan, math.nan, math.nan, False, False)
    start = n - _BLOCKS * length
    batches = min(_SUB_BATCHES, length)
    cum = hist.cumulative
    edges = start + (np.arange(_BLOCKS * batches + 1) * length) // batches
    sums = cum[edges[1:]] - cum[edges[:-1]]
    sizes = np.diff(edges)
    means = (sums / sizes).reshape(_BLOCKS, batches)
    block = (cum[start + length * np.arange(1, _BLOCKS + 1)] - cum[start + length * np.arange(_BLOCKS)]) / length
    # per-period variance per component, pooled within blocks 2-4; the first block, where the start-up
    # transient lives, takes part only in the drift test. Two estimates: from the batch means (absorbs
    # correlation between neighbouring periods) and from the periods themselves (many more degrees of
    # freedom, so that stopping on a low spread is rare); the larger one is taken.
    dev = (np.abs(means - block[:, None]) ** 2 * sizes.reshape(_BLOCKS, batches))[1:]
    dof = 2 * (_BLOCKS - 1) * (batches - 1)
    var1 = float(np.sum(dev)) / dof
    period_dof = 2 * (_BLOCKS - 1) * (length - 1)
    var_periods = sum(hist.scatter(start + k * length, start + (k + 1) * length) for k in range(1, _BLOCKS))
    var_periods /= period_dof
    # white: the batch means scatter no more than independent periods would, and neighbouring periods are not
    # alike (a slow transient or coloured noise, e.g. a resonance excited by jitter, makes them so)
    lag = hist.lag_correlation(start + length, n)
    white = bool(var1 <= _WHITE_RATIO * var_periods and lag <= _WHITE_LAG)
    # correlation longer than a batch: the variance of a mean of AR(1)-like periods grows by (1 + r)/(1 - r),
    # r the lag-1 correlation beyond what its own sampling error (about 2/sqrt(periods)) explains
    r = min(max(0.0, lag - 2.0 / math.sqrt(3 * length)), 0.99) if not math.isnan(lag) else 0.0
    var_periods *= (1.0 + r) / (1.0 - r)
    if var_periods >= var1:
        var1, dof = var_periods, period_dof
    sigma_diff = math.sqrt(2.0 * var1 / length)  # per component, difference of two block means
    d1 = float(abs(block[1] - block[0]))
    d2, d3 = float(abs(block[2] - block[1])), float(abs(block[3] - block[2]))
    # a drift is visible above the noise, and above the round-off of the block sums
    visible = max(_DRIFT_SIGMAS * sigma_diff, _ROUND_OFF * float(np.max(np.abs(block))))
    if white and d2 <= visible and d3 <= visible:  # noise and no drift over the last three blocks: average them
        used, bias, bounded = 3, 0.0, True
    else:
        used, bias = 2, 1.5 * d3
        bounded = d3 <= max(_MAX_RATIO * d2, visible) and d2 <= max(_MAX_RATIO * d1, visible)
    value = complex(block[_BLOCKS - used:].mean())
    sigma_mean = math.sqrt(var1 / (used * length))  # per component
    statistical = _disc_factor(dof) * sigma_mean
    line = _line_factor(dof) * sigma_mean
    # with fewer batches than _SUB_BATCHES a smooth drift looks like noise: no bound from so short a record
    bounded = bounded and batches == _SUB_BATCHES
    return Estimate(value, statistical + bias, line + bias, statistical, bounded, white)


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


RESOLUTION = 1e-3
"""Absolute floor of the tolerance, as a fraction of the channel's largest coefficient."""


class StoppingRule(ABC):
    """Decides, period after period, when a series is measured.

    tolerance_percent: eps (%); skip_periods: n_k, periods never analysed. Whatever the rule, a verdict
    states the honest uncertainty of its value from the same history (:meth:`verdict`).
    """

    name: str = ""

    def __init__(self, tolerance_percent: float, skip_periods: int) -> None:
        self.eps = tolerance_percent
        self.skip = skip_periods

    def tolerance(self, z: complex, reference: float) -> float:
        """eps/100 * max(|z|, RESOLUTION * reference), output units."""
        return self.eps / 100.0 * max(abs(z), RESOLUTION * reference)

    @abstractmethod
    def check(self, hist: SeriesHistory, n: int, reference: float) -> Verdict | None:
        """Verdict at period n (n <= hist.n), or None to go on integrating.

        reference: magnitude of the channel's largest coefficient (output units),
        the scale against which a coefficient near zero is judged.
        """

    @abstractmethod
    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        """The rule's current estimate and uncertainty at period n (progress displays, capped points)."""

    def verdict(self, hist: SeriesHistory, n: int, value: complex, status: str, reference: float) -> Verdict:
        """A verdict on ``value`` with the uncertainty the history supports: |value - E| + U(E).

        E is the settled estimate at n (:func:`settled_estimate`); where its transient is not yet bounded
        the uncertainty is still stated but ``within_eps`` is false.
        """
        settled = settled_estimate(hist, self.skip, n) if n - self.skip >= 2 * _BLOCKS else None
        if settled is None or math.isnan(settled.uncertainty):
            return Verdict(n, value.real, value.imag, math.nan, status, self.name)
        gap = abs(value - settled.value)
        u = gap + settled.uncertainty
        within = settled.bounded and u <= self.tolerance(value, reference)
        return Verdict(n, value.real, value.imag, u, status, self.name, uncertainty_1d=gap + settled.uncertainty_1d,
                       within_eps=within)

    def capped(self, hist: SeriesHistory, n: int, reference: float) -> Verdict:
        """The verdict when max_periods is reached before the rule stopped."""
        return self.verdict(hist, n, self.estimate(hist, n)[0], CAPPED, reference)


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
            return self.verdict(hist, n, a, CONVERGED, reference)
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

    def check(self, hist: SeriesHistory, n: int, reference: float) -> Verdict | None:
        if n < self.skip + self.average:
            return None
        return self.verdict(hist, n, self.estimate(hist, n)[0], FIXED, reference)

    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        return hist.mean(min(self.skip, n - 1), n), math.nan


_MIN_TURN = 0.5  # |1 - lambda| of a slowly decaying mode that the fit may extrapolate through


@dataclass(frozen=True)
class ModalFit:
    """A modal fit of a window: its limit, rms residual (both output units) and its forecast of what follows."""

    limit: complex
    residual: float
    prediction: np.ndarray


def extrapolate_modes(z: np.ndarray, modes: int, max_decay: float = 0.5, predict: int = 0) -> ModalFit | None:
    """Limit of a sequence ``Z(i) = Z_inf + sum_r a_r lambda_r**i`` from a least-squares linear-prediction fit.

    The real recurrence ``Z(i) = c + sum_r alpha_r Z(i-r)`` is fitted to P and Q
    jointly; ``Z_inf = c / (1 - sum alpha)``. The fit is only trusted where the
    data show the transient dying: every mode must shrink to at most
    ``max_decay`` of itself over the fitted stretch (a mode on or outside the
    unit circle, a beat of a conservative link or a growing response, has no
    limit). ``predict``: how many values after the window the recurrence
    forecasts. None when the sequence is too short or no limit is shown.
    """
    n = z.size
    rows = n - modes
    if rows < modes + 3:
        return None
    mean = complex(np.mean(z))
    if float(np.max(np.abs(z - mean))) <= _ROUND_OFF * abs(mean):  # settled to round-off: no mode to fit
        return ModalFit(mean, 0.0, np.full(predict, mean))
    x = np.zeros((2 * rows, modes + 2))
    for r in range(1, modes + 1):
        col = z[modes - r:n - r]
        x[:rows, r - 1] = col.real
        x[rows:, r - 1] = col.imag
    x[:rows, modes] = 1.0
    x[rows:, modes + 1] = 1.0
    y = np.concatenate([z[modes:].real, z[modes:].imag])
    sol, *_ = np.linalg.lstsq(x, y, rcond=None)
    alpha = sol[:modes]
    lambdas = np.roots(np.concatenate([[1.0], -alpha]))
    # a mode must have decayed over the window, unless it is damped and turns far enough from 1 that the
    # limit does not hang on its decay rate (a rotating mode's mean is its limit)
    slow = np.abs(lambdas) ** n > max_decay
    if np.any(slow & ((np.abs(lambdas) >= 1.0) | (np.abs(1.0 - lambdas) < _MIN_TURN))):
        return None
    den = 1.0 - float(np.sum(alpha))
    resid = y - x @ sol
    limit = complex(sol[modes], sol[modes + 1]) / den
    return ModalFit(limit, float(np.sqrt(np.mean(resid ** 2))) / abs(den), _forecast(z[n - modes:], alpha, limit, predict))


def _forecast(last: np.ndarray, alpha: np.ndarray, limit: complex, steps: int) -> np.ndarray:
    """The next ``steps`` values of the recurrence Z(i) - Z_inf = sum_r alpha_r (Z(i-r) - Z_inf), from its last values."""
    if steps == 0 or alpha.size == 0:
        return np.full(steps, limit, dtype=complex)
    from scipy.signal import lfilter, lfiltic  # imported where used: it is slow to import

    a = np.concatenate([[1.0], -alpha])
    zi = lfiltic([1.0], a, (last[::-1] - limit))
    return limit + lfilter([1.0], a, np.zeros(steps, dtype=complex), zi=zi.astype(complex))[0]


class AdaptiveRule(StoppingRule):
    """The default: stops when an error bound on the estimate, earned from the history itself, is within eps.

    Two estimators, each accepted only with its own evidence:

    1. The settled estimate (:func:`settled_estimate`): the mean of the last half of the analysed periods,
       with a statistical 95 % half-width and a bound on the transient left in it. A drift that the
       quarter-blocks show must have been seen to shrink geometrically (each block's change at most half
       the previous one) before any bound exists, so a slow transient cannot pass for a plateau. This is
       the path of noisy bench data.
    2. Modal extrapolation: Z(i) = Z_inf + sum a_r lambda_r**i fitted on two independent windows, accepted
       when both limits agree within the tolerance, each fit explains its window (residual within it),
       every fitted mode has visibly decayed over its window, and the fit made on the older window
       predicts the newer window's data (the model is confirmed on data it has not seen).

    Tolerance: ``eps/100 * max(|Z|, RESOLUTION * reference)``: a coefficient far below the channel's largest
    one is measured to an absolute floor and reported as below resolution when its confidence region
    contains zero. Points that reach ``max_periods`` end ``noise_limited`` when only the statistical part is
    too wide (with the periods the requested eps would need), else ``capped``.
    """

    name = "adaptive"

    def __init__(self, tolerance_percent: float, skip_periods: int, *, max_periods: int = 20000, modes: int = 2,
                 min_window: int = 8, min_periods: int = 8) -> None:
        super().__init__(tolerance_percent, skip_periods)
        self.max_periods = max_periods
        self.modes = modes
        self.min_window = min_window
        self.min_periods = min_periods
        self._next_extrapolation = 0

    def _extrapolated(self, hist: SeriesHistory, n: int) -> tuple[complex, float] | None:
        """(limit, error bound) of the modal fit confirmed on two windows, or None where it is not confirmed."""
        w = max(self.min_window, (n - self.skip) // 4)
        if n - 2 * w < self.skip:
            return None
        z = hist.values
        first = extrapolate_modes(z[n - 2 * w:n - w], self.modes, predict=w)
        second = extrapolate_modes(z[n - w:n], self.modes)
        if first is None or second is None:
            return None
        prediction_error = float(np.max(np.abs(first.prediction - z[n - w:n])))
        bound = abs(first.limit - second.limit) + 2.0 * max(first.residual, second.residual)
        return second.limit, max(bound, prediction_error)

    def check(self, hist: SeriesHistory, n: int, reference: float) -> Verdict | None:
        if n - self.skip < self.min_periods:
            return None
        settled = settled_estimate(hist, self.skip, n)
        floor = self.tolerance(0.0, reference)
        if settled.bounded:
            tol = self.tolerance(settled.value, reference)
            if settled.uncertainty <= tol:
                return self._finish(n, settled, floor, "settled mean")
            needed = self._periods_needed(n, settled, tol)
            if settled.white and needed > _HOPELESS * self.max_periods and n - self.skip >= _MIN_NOISE_EVIDENCE:
                # the noise alone keeps eps out of reach within the budget: say so now, not at max_periods
                return self._noise_limited(n, settled, needed)
        # the fit costs more than the mean: once windows are long, try it on a sparser schedule
        if self.modes > 0 and n >= self._next_extrapolation:
            self._next_extrapolation = n + max(1, (n - self.skip) // 32)
            fit = self._extrapolated(hist, n)
            if fit is not None:
                limit, bound = fit
                if bound <= self.tolerance(limit, reference):
                    return self._finish(n, Estimate(limit, bound, bound, 0.0, True), floor, "extrapolated")
        return None

    def _finish(self, n: int, est: Estimate, floor: float, method: str) -> Verdict:
        """A coefficient within its own uncertainty or the absolute floor of zero has no phase."""
        status = BELOW_RESOLUTION if abs(est.value) <= max(est.uncertainty, floor) else CONVERGED
        return Verdict(n, est.value.real, est.value.imag, est.uncertainty, status, method,
                       uncertainty_1d=est.uncertainty_1d, within_eps=True)

    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        if n - self.skip < 2:
            return hist.at(n), math.nan
        est = settled_estimate(hist, self.skip, n)
        return est.value, est.uncertainty

    @staticmethod
    def _periods_needed(n: int, est: Estimate, tol: float) -> int:
        """Periods after which the statistical half-width, shrinking as 1/sqrt(n), leaves room for the bias."""
        if est.bias >= 0.5 * tol or not est.statistical > 0.0:
            return 0
        return int(math.ceil(n * (est.statistical / (tol - est.bias)) ** 2))

    def _noise_limited(self, n: int, est: Estimate, needed: int) -> Verdict:
        return Verdict(n, est.value.real, est.value.imag, est.uncertainty, NOISE_LIMITED, "settled mean",
                       uncertainty_1d=est.uncertainty_1d, within_eps=False, periods_needed=needed)

    def capped(self, hist: SeriesHistory, n: int, reference: float) -> Verdict:
        """At max_periods: noise-limited (with the periods eps would need) when only the statistics are too wide."""
        est = settled_estimate(hist, self.skip, n)
        needed = self._periods_needed(n, est, self.tolerance(est.value, reference)) if est.bounded and est.white else 0
        if needed:
            return self._noise_limited(n, est, needed)
        return Verdict(n, est.value.real, est.value.imag, est.uncertainty, CAPPED, self.name,
                       uncertainty_1d=est.uncertainty_1d)


def make_rule(criterion: str, *, tolerance_percent: float, skip_periods: int, window: int,
              settle_periods: int = 50, average_periods: int = 50, max_periods: int = 20000) -> StoppingRule:
    """The rule a config's ``analysis.criterion`` names (a fresh object per series: rules keep state)."""
    if criterion == "adaptive":
        return AdaptiveRule(tolerance_percent, skip_periods, max_periods=max_periods)
    if criterion == "first_period":
        return FixedScheme(0, 1, "first_period", tolerance_percent)
    if criterion == "sixth_of_six":
        return FixedScheme(5, 1, "sixth_of_six", tolerance_percent)
    if criterion == "fixed":
        return FixedScheme(settle_periods, average_periods, "fixed", tolerance_percent)
    printed: dict[str, type[_PrintedRule]] = {
        "none": NoAveraging, "local": LocalAveraging, "full": FullAveraging,
        "combined1": Combined1, "combined2": Combined2, "combined3": Combined3,
    }
    try:
        return printed[criterion](tolerance_percent, skip_periods, window)
    except KeyError:
        raise ValueError(f"unknown criterion {criterion!r}; one of {', '.join(CRITERIA)}") from None
