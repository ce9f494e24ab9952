"""Stopping rules of monoharmonic autointegration (docs/METHOD.md section 1).

A rule looks at the per-period Fourier coefficients of one series (one
channel, one harmonic), held as complex numbers ``Z(i) = P(i) + j Q(i)``, and
decides after period ``n`` whether the point is measured and what its value
is. The paper's rules are implemented exactly as printed; ``adaptive`` is the
default, built to deliver the requested error (see docs/measurement.md, "Stopping
rules" section for the evidence).

Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import functools
import math
import types
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from bodebench.core.student_t import t_quantile
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


_SMALL_EXTEND = 8  # periods up to which extend() works on Python scalars (cheaper than numpy's per-call cost)


class SeriesHistory:
    """Per-period coefficients Z(i) = P(i) + jQ(i), i = 1..n, of one series, with running sums.

    Running sums of Z, of |Z - Z(1)|^2 and of (Z(j) - Z(1)) conj(Z(j-k) - Z(1)), k = 1, 2 (taken about the first
    value, so that the sums of squares of a steady series do not cancel catastrophically) make every window
    mean, spread and lag correlation O(1). Each is kept as a Python list, for the single entries a rule reads
    every period (a list serves those several times faster), and as a numpy array with the same values, for work
    on many periods at once; periods appended one by one reach the arrays when the arrays are next read
    (:meth:`arrays`), in one slice each.
    """

    def __init__(self) -> None:
        self._z = np.empty(256, dtype=complex)
        self._cum = np.zeros(257, dtype=complex)  # _cum[i] = Z(1) + ... + Z(i)
        self._cum2 = np.zeros(257)  # _cum2[i] = |Z(1) - Z(1)|^2 + ... + |Z(i) - Z(1)|^2
        self._lag = np.zeros(257, dtype=complex)  # _lag[i] = sum over j = 2..i of (Z(j) - Z(1)) conj(Z(j-1) - Z(1))
        self._lag2 = np.zeros(257, dtype=complex)  # _lag2[i] = sum over j = 3..i of (Z(j) - Z(1)) conj(Z(j-2) - Z(1))
        self._first = 0j  # Z(1)
        self._z_list: list[complex] = []
        self._cum_list: list[complex] = [0j]
        self._cum2_list: list[float] = [0.0]
        self._lag_list: list[complex] = [0j]
        self._lag2_list: list[complex] = [0j]
        self.n = 0
        self._synced = 0  # periods whose entries the arrays hold

    def extend(self, z: np.ndarray) -> None:
        """Append the coefficients of the next periods (complex array)."""
        z = np.asarray(z, dtype=complex).reshape(-1)
        if z.size == 0:
            return
        if z.size <= _SMALL_EXTEND:
            for v in z.tolist():
                self.append(v)
            return
        self._sync()
        n, need = self.n, self.n + z.size
        self._reserve(need)
        self._z[n:need] = z
        if n == 0:
            self._first = complex(z[0])
        z0 = self._first
        self._cum[n + 1:need + 1] = self._cum[n] + np.cumsum(z)
        lo = max(n - 2, 0)
        centred = self._z[lo:need] - z0  # Z(lo+1..need) - Z(1)
        self._cum2[n + 1:need + 1] = self._cum2[n] + np.cumsum(np.abs(centred[n - lo:]) ** 2)
        for sums, k in ((self._lag, 1), (self._lag2, 2)):
            # (Z(j) - Z(1)) conj(Z(j-k) - Z(1)) for j = max(n, k)+1..need; the sums up to period k are zero
            count = need - max(n, k)
            if count > 0:
                products = centred[centred.size - count:] * np.conj(centred[centred.size - count - k:-k])
                sums[need - count + 1:need + 1] = sums[need - count] + np.cumsum(products)
        self._z_list.extend(z.tolist())
        self._cum_list.extend(self._cum[n + 1:need + 1].tolist())
        self._cum2_list.extend(self._cum2[n + 1:need + 1].tolist())
        self._lag_list.extend(self._lag[n + 1:need + 1].tolist())
        self._lag2_list.extend(self._lag2[n + 1:need + 1].tolist())
        self.n = self._synced = need

    def append(self, v: complex) -> None:
        """Append the coefficient of the next period (to the lists; the arrays take it when next read)."""
        n = self.n
        v = complex(v)
        if n == 0:
            self._first = v
        z0 = self._first
        d = v - z0
        c = self._cum_list[n] + v
        c2 = self._cum2_list[n] + abs(d) ** 2
        zs = self._z_list
        lag = self._lag_list[n] + d * (zs[n - 1] - z0).conjugate() if n >= 1 else 0j
        lag2 = self._lag2_list[n] + d * (zs[n - 2] - z0).conjugate() if n >= 2 else 0j
        n += 1
        zs.append(v)
        self._cum_list.append(c)
        self._cum2_list.append(c2)
        self._lag_list.append(lag)
        self._lag2_list.append(lag2)
        self.n = n

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The arrays, holding every period appended: Z (from index 0: Z(1)) and the running sums of Z, of
        |Z - Z(1)|^2 and of the lag-1 and lag-2 products (index i: the sum up to period i). Not to be written."""
        self._sync()
        return self._z, self._cum, self._cum2, self._lag, self._lag2

    def _sync(self) -> None:
        """Write the periods appended since the arrays were last read into them, one slice per array."""
        start, n = self._synced, self.n
        if start < n:
            self._reserve(n)
            self._z[start:n] = self._z_list[start:n]
            self._cum[start + 1:n + 1] = self._cum_list[start + 1:n + 1]
            self._cum2[start + 1:n + 1] = self._cum2_list[start + 1:n + 1]
            self._lag[start + 1:n + 1] = self._lag_list[start + 1:n + 1]
            self._lag2[start + 1:n + 1] = self._lag2_list[start + 1:n + 1]
            self._synced = n

    def all_finite(self, a: int, b: int) -> bool:
        """Whether Z(a+1..b) are all finite, from the running sum of squares (O(1)): a value that is not finite
        makes every later sum infinite or NaN. False also where the sum itself overflows (|Z| above ~1e154)."""
        return math.isfinite(self._cum2_list[b] - self._cum2_list[a])

    def _reserve(self, need: int) -> None:
        """Room for ``need`` periods in the arrays (the entries they hold are kept)."""
        if need > self._z.size:
            size = max(need, 2 * self._z.size)
            self._z = np.resize(self._z, size)
            for name in ("_cum", "_cum2", "_lag", "_lag2"):
                old = getattr(self, name)
                new = np.zeros(size + 1, dtype=old.dtype)
                new[: self._synced + 1] = old[: self._synced + 1]
                setattr(self, name, new)

    @property
    def values(self) -> np.ndarray:
        """Z(1..n) as a read-only view."""
        v = self.arrays()[0][: self.n]
        v.flags.writeable = False
        return v

    @property
    def cumulative(self) -> np.ndarray:
        """Running sums: ``cumulative[i] = Z(1) + ... + Z(i)``, i = 0..n (read-only view)."""
        c = self.arrays()[1][: self.n + 1]
        c.flags.writeable = False
        return c

    def at(self, i: int) -> complex:
        """Z(i), periods counted from 1."""
        return self._z_list[i - 1]

    def mean(self, a: int, b: int) -> complex:
        """Mean of Z over periods a+1..b."""
        cum = self._cum_list
        return (cum[b] - cum[a]) / (b - a)

    def lag_correlation(self, a: int, b: int) -> float:
        """|lag-1 autocorrelation| of Z over periods a+1..b (0: independent periods; near 1: smooth or turning)."""
        length = b - a
        if length < 3:
            return math.nan
        cum, z0 = self._cum_list, self._first
        shift = (cum[b] - cum[a]) / length - z0
        # sum of (Z(j) - m) conj(Z(j-1) - m) over j = a+2..b, expanded about Z(1)
        inner = cum[b] - cum[a + 1] - z0 * (length - 1)
        outer = cum[b - 1] - cum[a] - z0 * (length - 1)
        cov = (self._lag_list[b] - self._lag_list[a + 1]) - inner * shift.conjugate() - shift * outer.conjugate() \
            + (length - 1) * abs(shift) ** 2
        var = max(0.0, self._cum2_list[b] - self._cum2_list[a] - length * abs(shift) ** 2)
        return abs(cov) / var if var > 0.0 else math.nan

    def scatter(self, a: int, b: int) -> float:
        """Sum of |Z(i) - mean|^2 over periods a+1..b (output units squared)."""
        cum = self._cum_list
        shift = (cum[b] - cum[a]) / (b - a) - self._first
        return max(0.0, self._cum2_list[b] - self._cum2_list[a] - (b - a) * abs(shift) ** 2)


_DISC: dict[int, float] = {}


def _disc_factor(dof: int, confidence: float = CONFIDENCE) -> float:
    """Radius, in standard deviations per component, of the confidence disc of a circular 2-D normal mean.

    The variance is estimated with ``dof`` degrees of freedom, so |error|^2 / (2 s^2) follows F(2, dof);
    F(2, d) has the closed-form quantile d/2 ((1 - c)^(-2/d) - 1).
    """
    if confidence == CONFIDENCE:
        found = _DISC.get(dof)
        if found is not None:
            return found
    f = dof / 2.0 * ((1.0 - confidence) ** (-2.0 / dof) - 1.0)
    factor = math.sqrt(2.0 * f)
    if confidence == CONFIDENCE:
        if len(_DISC) > 4096:
            _DISC.clear()
        _DISC[dof] = factor
    return factor


@functools.lru_cache(maxsize=256)
def _line_factor(dof: int, confidence: float = CONFIDENCE) -> float:
    """Two-sided Student t quantile: the 95 % half-width of one component, in standard deviations."""
    return t_quantile(0.5 + confidence / 2.0, dof)


_BLOCKS = 4          # quarter-blocks of the analysed record
_SUB_BATCHES = 8     # batches per block for the statistical spread
_MAX_RATIO = 0.5     # a visible drift must shrink at least this fast from block to block
_DRIFT_SIGMAS = 3.72  # |d| / sigma_d of a 2-D normal exceeds this with probability 0.1 %
_ROUND_OFF = 1e-12    # relative size of a change that round-off of the running sums can make
_HOPELESS = 2.0       # a point whose projected periods exceed this many budgets ends noise-limited at once
MIN_NOISE_EVIDENCE = 128  # analysed periods before the noise is judged hopeless
_WHITE_RATIO = 2.0    # batch-mean variance over per-period variance still taken for independent periods
_WHITE_LAG = 0.2      # |lag-1 autocorrelation| still taken for independent periods
_SLACK = 1.0 + 1e-9   # margin of a screen's inequalities over the round-off of the bounds they compare
_SLACK2 = _SLACK * _SLACK
_EPS = float(np.finfo(float).eps)


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


_QuarterStats = tuple[int, int, int, complex, complex, complex, float]
"""The analysed periods skip+1..n cut into four equal blocks, what the running sums give in O(1):
(n, length, start, m2, m3, m4, within). length: periods per block; start: the periods before the first block;
m2..m4: the means of blocks 2-4 (output units); within: the scatter of the periods about their own block's
mean, summed over blocks 2-4 (output units squared)."""


def _quarters(hist: SeriesHistory, skip: int, n: int) -> _QuarterStats:
    """The quarter-block statistics of periods skip+1..n (at least one period a block)."""
    length = (n - skip) // _BLOCKS
    start = n - _BLOCKS * length
    cum, cum2, z0 = hist._cum_list, hist._cum2_list, hist._first
    e1 = start + length
    e2 = e1 + length
    e3 = e2 + length
    c2, c3 = cum[e2], cum[e3]
    m2 = (c2 - cum[e1]) / length
    m3 = (c3 - c2) / length
    m4 = (cum[n] - c3) / length
    a = abs(m2 - z0)
    s2 = cum2[e2] - cum2[e1] - length * (a * a)
    a = abs(m3 - z0)
    s3 = cum2[e3] - cum2[e2] - length * (a * a)
    a = abs(m4 - z0)
    s4 = cum2[n] - cum2[e3] - length * (a * a)
    within = (s2 if s2 > 0.0 else 0.0) + (s3 if s3 > 0.0 else 0.0) + (s4 if s4 > 0.0 else 0.0)
    return n, length, start, m2, m3, m4, within


_DISC_BATCHES = _disc_factor(2 * (_BLOCKS - 1) * (_SUB_BATCHES - 1))  # the disc factor of eight batches a block
_OFFSETS: dict[tuple[int, int], tuple[int, ...]] = {}


def _batch_offsets(length: int, batches: int) -> tuple[int, ...]:
    """Batch edges in a block of ``length`` periods cut into ``batches``: (j * length) // batches, j = 0..batches."""
    key = (length, batches)
    found = _OFFSETS.get(key)
    if found is None:
        if len(_OFFSETS) > 4096:
            _OFFSETS.clear()
        found = _OFFSETS[key] = tuple((j * length) // batches for j in range(batches + 1))
    return found


class _Settled:
    """The settled estimate before its one-direction half-width, which costs a quantile, is worked out.

    value (output units); statistical: 95 % disc radius from the noise; bias: bound on the transient left
    (both output units); bounded, white: as :class:`Estimate`; dof: degrees of freedom of the noise estimate;
    sigma_mean: standard deviation per component of the estimate (output units).
    """

    __slots__ = ("value", "statistical", "bias", "bounded", "white", "dof", "sigma_mean")

    def __init__(self, value: complex, statistical: float, bias: float, bounded: bool, white: bool, dof: int,
                 sigma_mean: float) -> None:
        self.value, self.statistical, self.bias = value, statistical, bias
        self.bounded, self.white, self.dof, self.sigma_mean = bounded, white, dof, sigma_mean

    @property
    def uncertainty(self) -> float:
        return self.statistical + self.bias

    def estimate(self) -> Estimate:
        line = _line_factor(self.dof) * self.sigma_mean
        return Estimate(self.value, self.statistical + self.bias, line + self.bias, self.statistical, self.bounded,
                        self.white)


def _settle(hist: SeriesHistory, q: _QuarterStats, lag: float | None = None) -> _Settled:
    """The settled estimate of :func:`settled_estimate` from its quarter-blocks (at least two periods each).

    lag: the |lag-1 autocorrelation| over blocks 2-4 where already worked out (None: worked out here).
    """
    n, length, start, m2, m3, m4, within = q
    block = ((hist._cum_list[start + length] - hist._cum_list[start]) / length, m2, m3, m4)
    batches = min(_SUB_BATCHES, length)
    offsets = _batch_offsets(length, batches)
    cum = hist._cum_list
    # per-period variance per component, pooled within blocks 2-4; the first block, where the start-up
    # transient lives, takes part only in the drift test. Two estimates: from the batch means (absorbs
    # correlation between neighbouring periods) and from the periods themselves (many more degrees of
    # freedom, so that stopping on a low spread is rare); the larger one is taken.
    dev = 0.0
    for k in range(1, _BLOCKS):
        base = start + k * length
        mean = block[k]
        lo = cum[base]
        for j in range(1, batches + 1):
            size = offsets[j] - offsets[j - 1]
            hi = cum[base + offsets[j]]
            dev += abs((hi - lo) / size - mean) ** 2 * size
            lo = hi
    dof = 2 * (_BLOCKS - 1) * (batches - 1)
    var1 = dev / dof
    period_dof = 2 * (_BLOCKS - 1) * (length - 1)
    var_periods = within / period_dof
    # white: the batch means scatter no more than independent periods would, and neighbouring periods are not
    # alike (a slow transient or coloured noise, e.g. a resonance excited by jitter, makes them so)
    if lag is None:
        lag = hist.lag_correlation(start + length, n)
    white = var1 <= _WHITE_RATIO * var_periods and lag <= _WHITE_LAG
    # correlation longer than a batch: the variance of a mean of AR(1)-like periods grows by (1 + r)/(1 - r),
    # r the lag-1 correlation beyond what its own sampling error (about 2/sqrt(periods)) explains
    r = min(max(0.0, lag - 2.0 / math.sqrt(3 * length)), 0.99) if not math.isnan(lag) else 0.0
    var_periods *= (1.0 + r) / (1.0 - r)
    if var_periods >= var1:
        var1, dof = var_periods, period_dof
    sigma_diff = math.sqrt(2.0 * var1 / length)  # per component, difference of two block means
    d1, d2, d3 = abs(block[1] - block[0]), abs(block[2] - block[1]), abs(block[3] - block[2])
    # a drift is visible above the noise, and above the round-off of the block sums
    visible = max(_DRIFT_SIGMAS * sigma_diff, _ROUND_OFF * max(abs(b) for b in block))
    if white and d2 <= visible and d3 <= visible:  # noise and no drift over the last three blocks: average them
        used, bias, bounded = 3, 0.0, True
        value = (block[1] + block[2] + block[3]) / 3
    else:
        used, bias = 2, 1.5 * d3
        bounded = d3 <= max(_MAX_RATIO * d2, visible) and d2 <= max(_MAX_RATIO * d1, visible)
        value = (block[2] + block[3]) / 2
    sigma_mean = math.sqrt(var1 / (used * length))  # per component
    statistical = _disc_factor(dof) * sigma_mean
    # with fewer batches than _SUB_BATCHES a smooth drift looks like noise: no bound from so short a record
    bounded = bounded and batches == _SUB_BATCHES
    return _Settled(value, statistical, bias, bounded, white, dof, sigma_mean)


def settled_estimate(hist: SeriesHistory, skip: int, n: int) -> Estimate:
    """The mean of the settled part of periods skip+1..n, with its 95 % bounds (output units).

    The analysed record is cut into four equal blocks, each into up to eight batches. Noise: the
    pooled spread of the batch means about their own block's mean in the last three blocks (between-block
    drift excluded), with 3 blocks x (batches - 1) x 2 degrees of freedom. Drift: the changes d2, d3 between
    the means of blocks 2-3 and 3-4. A drift the noise cannot explain must shrink geometrically, |d3| <= |d2| / 2,
    before the transient is bounded (and so must d2 against d1); the transient left in the mean of
    blocks 3-4 is then at most 1.5 |d3| (the tail of a geometric sequence of ratio <= 1/2). Only where
    the periods scatter like independent noise (``white``: a smooth or turning transient inflates the
    spread and would hide a drift) and no drift is seen over blocks 2-4 is their mean the estimate, the
    bias term zero and the interval purely statistical. Block means and spreads come from the running sums,
    the batch means from eight lookups a block: the cost does not grow with n.
    """
    if (n - skip) // _BLOCKS < 2:
        z = hist.at(n)
        return Estimate(z, math.nan, math.nan, math.nan, False, False)
    return _settle(hist, _quarters(hist, skip, n)).estimate()


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
_MAX_DECAY = 0.5  # the most a fitted mode may keep of itself over its window
_FIT_WINDOW_SHARE = 4  # each of the modal fit's two windows holds 1/this of the analysed periods (min_window at least)


class ModalFit(NamedTuple):
    """A modal fit of a window: its limit and rms residual (both output units); ``alpha`` the recurrence's
    coefficients (none for a window settled to round-off) and ``tail`` the window's last values (oldest first),
    from which it forecasts what follows. A named tuple: made at every fit, it costs half a frozen dataclass."""

    limit: complex
    residual: float
    alpha: tuple[float, ...] = ()
    tail: tuple[complex, ...] = ()

    def forecast(self, steps: int) -> np.ndarray:
        """The ``steps`` values the recurrence forecasts after the window (output units)."""
        return _forecast(self.tail, self.alpha, self.limit, steps)

    def forecast_error(self, following: np.ndarray) -> float:
        """The largest |forecast - value| over the values that followed the window (output units; NaN where a
        forecast is not a number; 0 where none followed): ``max(abs(forecast - following))`` without making the
        forecast an array."""
        values = following.tolist()
        limit = self.limit
        if len(self.alpha) == 2:  # the two-mode fit's recurrence (as _recurrence runs it), unrolled in locals
            c0, c1 = self.alpha
            p1, p0 = self.tail[0] - limit, self.tail[1] - limit
            s0, s1 = c0 * p0 + c1 * p1, c1 * p0
            worst = total = 0.0
            for v in values:
                y = s0
                s0, s1 = s1 + y * c0, y * c1
                error = abs(limit + y - v)
                total += error
                if error > worst:
                    worst = error
            return worst if total == total else math.nan  # a NaN anywhere makes the sum NaN
        forecast = _recurrence(self.tail, self.alpha, limit, len(values)) if self.alpha else [limit] * len(values)
        errors = [abs(f - v) for f, v in zip(forecast, values, strict=True)]
        total = sum(errors)
        return max(errors, default=0.0) if total == total else math.nan


def extrapolate_modes(z: np.ndarray, modes: int, max_decay: float = _MAX_DECAY) -> ModalFit | None:
    """Limit of a sequence ``Z(i) = Z_inf + sum_r a_r lambda_r**i`` from a least-squares linear-prediction fit.

    The real recurrence ``Z(i) = c + sum_r alpha_r Z(i-r)`` is fitted to P and Q
    jointly; ``Z_inf = c / (1 - sum alpha)``. The fit is only trusted where the
    data show the transient dying: every mode must shrink to at most
    ``max_decay`` of itself over the fitted stretch (a mode on or outside the
    unit circle, a beat of a conservative link or a growing response, has no
    limit). None when the sequence is too short, holds a value that is not
    finite, or no limit is shown.
    """
    return _modal_fit(z, modes, max_decay)[0]


def _modal_fit(z: np.ndarray, modes: int, max_decay: float, finite: bool = False) -> tuple[ModalFit | None, float]:
    """:func:`extrapolate_modes`, and the window (periods) over which the slowest mode it refused for not having
    decayed would decay to ``max_decay`` at its fitted rate (inf for a mode on or outside the unit circle; 0 where
    no mode was refused). finite: the caller knows every value of z to be finite (else it is checked here)."""
    n = z.size
    if n - modes < modes + 3:
        return None, 0.0
    z = np.ascontiguousarray(z, dtype=complex)
    values = np.empty(2 * n + 2)  # (P(1), Q(1), ..., P(n), Q(n), 1, 0): the intercepts' entries last
    values[:-2] = z.view(np.float64)
    values[-2] = 1.0
    values[-1] = 0.0
    if not (finite or np.isfinite(values).all()):  # LAPACK, handed one, may print a complaint or return zeros
        return None, 0.0
    if _may_be_settled(z):
        mean = complex(z.sum() / n)
        if float(np.abs(z - mean).max()) <= _ROUND_OFF * abs(mean):  # settled to round-off: no mode to fit
            return ModalFit(mean, 0.0), 0.0
    design = _DESIGNS.get((n, modes)) or _design(n, modes)
    columns = modes + 2
    # the design matrix's columns (Z lagged by 1..modes, the two intercepts) and Z itself over the rows (P then Q
    # of Z(modes+1..n)), gathered at once; the transpose is a column-major view, the layout LAPACK works in
    xy = values[design.gather]
    sol = _least_squares(xy, design)
    found = sol[:columns].tolist()
    alpha = found[:modes]
    # a mode must have decayed over the window, unless it is damped and turns far enough from 1 that the
    # limit does not hang on its decay rate (a rotating mode's mean is its limit); size ** n is taken only
    # below 1, where it cannot overflow
    needed = 0.0
    for lam in _mode_roots(alpha):
        size = abs(lam)
        if size >= 1.0:
            if max_decay < 1.0 or n * math.log(size) > math.log(max_decay):
                return None, math.inf
        elif size ** n > max_decay and abs(1.0 - lam) < _MIN_TURN:
            needed = max(needed, math.log(max_decay) / math.log(size))
    if needed:
        return None, needed
    den = 1.0 - (sum(alpha) if modes < 8 else float(sol[:modes].sum()))  # numpy's sum is Python's below 8 terms
    # the residual of the solution returned (LAPACK's own sum of squares is that of the exact least-squares
    # solution, which a badly scaled design can put orders of magnitude lower): with -1 after the solution, the
    # product with the gathered columns and values is (design @ solution - values), row by row
    sol[columns] = -1.0
    resid = sol[:columns + 1].dot(xy)  # the method: numpy's function adds a dispatch to the same product
    limit = complex(found[modes], found[modes + 1]) / den
    residual = math.sqrt(float(resid.dot(resid)) / resid.size) / abs(den)
    return ModalFit(limit, residual, tuple(alpha), tuple(z[n - modes:].tolist())), 0.0


def _may_be_settled(z: np.ndarray) -> bool:
    """False where the window's first and last values differ by more than a window settled to round-off
    (every value within _ROUND_OFF |mean| of its mean) allows: 2 _ROUND_OFF |mean| <= 2 _ROUND_OFF |Z(1)| (1 + 2
    _ROUND_OFF), with a margin for the round-off of the comparison. True also where the first or last value is
    not a number, and where |Z(1)| is so small that the bound itself rounds (below 1e-280)."""
    first, last = z.item(0), z.item(-1)  # Python complex numbers
    size = abs(first)
    return not (abs(first - last) > 2.0 * _ROUND_OFF * (1.0 + 1e-6) * size and size > 1e-280)


class _Design(NamedTuple):
    """A window shape's least-squares problem: ``gather`` indexes (P(1), Q(1), ..., P(n), Q(n), 1, 0) to make,
    one row each, the design matrix's columns (Z lagged by 1..modes, the P and Q intercepts) and then the fitted
    values Z(t), over the fit's rows (P then Q of Z(modes+1..n)); ``lwork`` is LAPACK's workspace for it (0:
    its query failed) and ``cond`` the condition at which dgelsy cuts the rank."""

    gather: np.ndarray
    lwork: int
    cond: float


_DESIGNS: dict[tuple[int, int], _Design] = {}


def _design(n: int, modes: int) -> _Design:
    """The least-squares problem of a window of n values fitted with ``modes`` modes, made and kept in _DESIGNS
    for the next fit of that shape (the fit looks there first)."""
    t = np.arange(modes, n)  # 0-based index of Z(t) for the rows
    one, zero = 2 * n, 2 * n + 1
    p_rows = [2 * (t - r) for r in range(1, modes + 1)] + [np.full(t.size, one), np.full(t.size, zero), 2 * t]
    q_rows = [2 * (t - r) + 1 for r in range(1, modes + 1)] + [np.full(t.size, zero), np.full(t.size, one),
                                                               2 * t + 1]
    gather = np.concatenate((np.stack(p_rows), np.stack(q_rows)), axis=1)
    m, k = gather.shape[1], modes + 2
    cond = _EPS * max(m, k)
    work, info = _lapack().dgelsy_lwork(m, k, 1, cond)
    if len(_DESIGNS) > 1024:
        _DESIGNS.clear()
    design = _DESIGNS[(n, modes)] = _Design(gather, int(work) if info == 0 else 0, cond)
    return design


def _least_squares(xy: np.ndarray, design: _Design) -> np.ndarray:
    """The least-squares solution of x @ sol = y, x the first ``modes + 2`` rows of xy transposed and y its last
    row, by LAPACK's dgelsy: QR with column pivoting, the rank cut where the triangle's condition estimate passes
    1 / (eps max(m, k)). Returned with the m - k entries LAPACK leaves after it (an array of xy's row length; the
    caller may write there); xy is left as it was.

    The design's columns differ in scale by orders of magnitude (the lagged values against the unit intercepts,
    the transient against the limit); an SVD cut-off relative to the largest singular value there drops a
    direction the limit hangs on and leaves errors of 1e-7 of it, where the pivoted QR keeps it and solves to
    round-off. Called directly: numpy's and scipy's wrappers cost several times the solve of a small system.
    Where LAPACK reports a failure numpy's lstsq is called instead, so that it fails the way numpy does.
    """
    k = xy.shape[0] - 1
    x, y = xy[:k].T, xy[k]
    if design.lwork:
        # the pivot order is read and written: a fresh one (all free columns) each call; LAPACK works on copies
        out = _lapack().dgelsy(x, y, np.zeros(k, dtype=np.intc), design.cond, design.lwork)
        if out[4] == 0:  # else an argument refused, before any work
            return out[1]
    sol = np.zeros(y.size)
    sol[:k] = np.linalg.lstsq(x, y, rcond=None)[0]
    return sol


@functools.cache
def _lapack() -> types.ModuleType:
    """scipy's LAPACK wrappers, imported on first use (the import is slow)."""
    from scipy.linalg import lapack

    return lapack


def _mode_roots(alpha: Sequence[float]) -> list[complex]:
    """The modes lambda_r of the recurrence: roots of z^m - alpha_1 z^(m-1) - ... - alpha_m (closed form to m = 2)."""
    if len(alpha) == 1:
        return [complex(alpha[0])]
    if len(alpha) == 2:
        a1, a2 = float(alpha[0]), float(alpha[1])
        disc = a1 * a1 + 4.0 * a2
        if disc < 0.0:
            half = 0.5 * math.sqrt(-disc)
            return [complex(0.5 * a1, half), complex(0.5 * a1, -half)]
        q = 0.5 * (a1 + math.copysign(math.sqrt(disc), a1))  # the larger root; the other from the product -a2
        return [complex(q), complex(-a2 / q)] if q != 0.0 else [0j, 0j]
    return [complex(v) for v in np.roots(np.concatenate([[1.0], -np.asarray(alpha, dtype=float)]))]


def _forecast(last: Sequence[complex], alpha: Sequence[float], limit: complex, steps: int) -> np.ndarray:
    """The next ``steps`` values of the recurrence Z(i) - Z_inf = sum_r alpha_r (Z(i-r) - Z_inf) from its last ones
    (``last``, oldest first), as an array."""
    if steps == 0 or len(alpha) == 0:
        return np.full(steps, limit, dtype=complex)
    return np.array(_recurrence(last, alpha, limit, steps), dtype=complex)


def _recurrence(last: Sequence[complex], alpha: Sequence[float], limit: complex, steps: int) -> list[complex]:
    """The next ``steps`` values of the recurrence from its last ones (oldest first), as a list.

    Run as a direct-form-II-transposed filter on Python scalars: state[m] = sum over r > m of alpha_r times the
    deviation r - m periods back, the next deviation is state[0] (the same arithmetic as scipy.signal.lfilter,
    without the import of scipy.signal in every process that fits a mode).
    """
    coef = [float(v) for v in alpha]
    order = len(coef)
    past = [complex(v) - limit for v in last[::-1]]  # the most recent deviation first
    state = [sum(coef[m + k] * past[k] for k in range(order - m)) for m in range(order)]
    out = []
    for _ in range(steps):
        y = state[0]
        for m in range(order - 1):
            state[m] = state[m + 1] + y * coef[m]
        state[order - 1] = y * coef[order - 1]
        out.append(limit + y)
    return out


def _two_mode_fit_may_pass(hist: SeriesHistory, s: int, w: int, e: float, floor: float) -> bool:
    """False where no two-mode fit of periods s+1..s+w can explain them well enough for the modal check; O(1).

    The fit's rows are the periods t = s+3..s+w, fitted by Z(t) = c + alpha_1 Z(t-1) + alpha_2 Z(t-2) with real
    alpha. Its least-squares residual is the Schur complement of the Gram matrix of the centred columns, which
    the running sums give; the error of those sums (at most a few n x machine-epsilon of their totals) and of
    the complement are subtracted. A fit the modal check accepts has both modes inside the unit circle, so
    |alpha_1| < 2, |alpha_2| < 1, |1 - alpha_1 - alpha_2| < 4 and |c| <= |m0| + 2 |m1| + |m2| (m_r the row
    means of Z(t-r)); with eps = e, twice its rms residual within a tolerance met at the second window's limit
    needs rms <= e/2 max((|m0| + 2 |m1| + |m2|) / (1 - e), 4 floor). True where that is still possible, or where
    the sums cannot tell. floor: the tolerance's absolute floor (output units).
    """
    rows = w - 2
    if rows < 5:  # too short for the fit itself
        return True
    cum, cum2, z0 = hist._cum_list, hist._cum2_list, hist._first
    lag, lag2 = hist._lag_list, hist._lag2_list
    end = s + w
    d0 = cum[end] - cum[s + 2] - rows * z0  # sums over the rows of Z(t - r) - Z(1)
    d1 = cum[end - 1] - cum[s + 1] - rows * z0
    d2 = cum[end - 2] - cum[s] - rows * z0
    g00 = cum2[end] - cum2[s + 2] - abs(d0) ** 2 / rows
    g11 = cum2[end - 1] - cum2[s + 1] - abs(d1) ** 2 / rows
    g22 = cum2[end - 2] - cum2[s] - abs(d2) ** 2 / rows
    g01 = (lag[end] - lag[s + 2]).real - (d0 * d1.conjugate()).real / rows
    g12 = (lag[end - 1] - lag[s + 1]).real - (d1 * d2.conjugate()).real / rows
    g02 = (lag2[end] - lag2[s + 2]).real - (d0 * d2.conjugate()).real / rows
    # round-off of the running sums: sequential sums of end terms, each no larger than the sum of squares
    total = cum2[end]
    err_d = 4.0 * end * _EPS * (end * abs(z0) + math.sqrt(end * total))
    err = 2.0 * (8.0 * end * _EPS * total + (2.0 * math.sqrt(rows * total) * err_d + err_d * err_d) / rows)
    m0, m1, m2 = d0 / rows + z0, d1 / rows + z0, d2 / rows + z0
    level = abs(m0) + 2.0 * abs(m1) + abs(m2)
    if not math.isfinite(g00 + g11 + g22 + g01 + g12 + g02 + err + level):
        return True
    if g00 <= w * (2.0 * _ROUND_OFF * level) ** 2 + 16.0 * err:  # settled to round-off: the fit needs no modes
        return True
    det = g11 * g22 - g12 * g12
    if not (g11 > 0.0 and g22 > 0.0 and det > 1e-6 * g11 * g22):  # the lagged columns all but collinear
        return True
    explained = (g22 * g01 * g01 - 2.0 * g12 * g01 * g02 + g11 * g02 * g02) / det
    # residual over alpha in the box |alpha_1| <= 2, |alpha_2| <= 1: a perturbation of the Gram matrix by err
    # per entry moves the quadratic form by at most (1 + 2 + 1)^2 err
    lowest = g00 - explained - 16.0 * err - 1e-7 * (abs(g00) + abs(explained))
    limit = 0.5 * e * max(level / (1.0 - e), 4.0 * floor)
    return lowest <= 2 * rows * limit * limit * _SLACK


_RATES_AGREE = 0.1  # how far (relative) the windows two fits in a row find a refused mode needs may differ
_SCREENS_IN_VAIN = 8  # screens passed in a row after which fits are made unscreened until one fails on its residual

_TABLE_SPAN = 1024  # periods whose settled screen is worked out at once
_TABLE_AHEAD = 16   # periods the history must hold beyond the one checked for a table to pay
_TABLE_AFTER = 96   # analysed periods before a table pays: building one costs as much as screening ~60 periods
                    # one by one, which a series that stops early never checks
_TABLE_FITS = 16    # scheduled fits in a table's stretch for their screens to be worked out at once


class _ScreenTable:
    """The settled screen of periods first..last of one history, worked out at once with numpy.

    Per period: the reference (the channel's scale, output units) at and above which a converged verdict is
    possible (conv), the open interval (low, high) and the bound below which (below) a noise-limited one is;
    and the quarter-block statistics and lag-1 correlation the settled estimate then takes. The same
    necessary conditions as :meth:`AdaptiveRule._settled_may_stop`, solved for the reference. fit: for the
    periods ``fits`` lists (the modal fit's schedule), the reference at and above which the two-mode fit's
    screen passes (None where the schedule has too few in the stretch to pay).
    """

    __slots__ = ("hist", "first", "last", "conv", "low", "high", "below", "m2", "m3", "m4", "within", "lag", "fit")

    def __init__(self, hist: SeriesHistory, skip: int, first: int, last: int, e: float, budget: float,
                 fits: Sequence[int] = (), fit_window: int = 0) -> None:
        self.hist, self.first, self.last = hist, first, last
        n = np.arange(first, last + 1)
        length = (n - skip) // _BLOCKS
        edges = n - _BLOCKS * length + length * np.arange(_BLOCKS + 1)[:, None]  # block edges, one row each
        size = length.astype(float)
        _, cum, cum2, lag_sums, _ = hist.arrays()
        z0 = hist._first
        c = cum[edges]
        means = _divide(c[1:] - c[:-1], size)  # the four block means
        sq = cum2[edges[1:]]
        within = np.maximum((sq[1:] - sq[:-1]) - size * np.abs(means[1:] - z0) ** 2, 0.0).sum(axis=0)
        # |lag-1 autocorrelation| over blocks 2-4, as SeriesHistory.lag_correlation
        e1 = edges[1]
        span = 3 * length
        shift = _divide(c[4] - c[1], span.astype(float)) - z0
        inner = c[4] - cum[e1 + 1] - z0 * (span - 1)
        outer = cum[n - 1] - c[1] - z0 * (span - 1)
        cov = (lag_sums[n] - lag_sums[e1 + 1]) - inner * np.conj(shift) - shift * np.conj(outer) \
            + (span - 1) * np.abs(shift) ** 2
        spread = np.maximum(sq[3] - sq[0] - span * np.abs(shift) ** 2, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            lag = np.where(spread > 0.0, np.abs(cov) / spread, np.nan)
            r = np.clip(np.nan_to_num(lag - 2.0 / np.sqrt(3 * size), nan=0.0), 0.0, 0.99)
            dof = 2 * (_BLOCKS - 1) * (length - 1)
            disc2 = dof * ((1.0 - CONFIDENCE) ** (-2.0 / dof) - 1.0)  # the disc factor squared
            var = within / dof
            low = disc2 * var / size * (1.0 + r) / (1.0 - r)
            a3 = np.abs(means[1:].sum(axis=0) / 3)
            a2 = np.abs(means[2:].sum(axis=0) / 2)
            d3 = np.abs(means[3] - means[2])
            scale = e * RESOLUTION  # the tolerance floor per unit reference
            # converged: the tolerance at the value of the last three (two) blocks must reach the half-width
            # (plus 1.5 |d3|); the tolerance is e max(|value|, RESOLUTION reference)
            need3 = np.sqrt(low / 3.0)
            need2 = 1.5 * d3 + np.sqrt(low / 2.0)
            conv = np.minimum(np.where(e * a3 * _SLACK2 >= need3, -np.inf, need3 / (scale * _SLACK2)),
                              np.where(e * a2 * _SLACK2 >= need2, -np.inf, need2 / (scale * _SLACK2)))
            conv[~np.isfinite(a3 + a2 + var + d3 + low)] = -np.inf
            # noise-limited, the last two blocks: the tolerance in (3 |d3|, sqrt(2 n high / budget)); all three:
            # below sqrt(n high / (3 budget)), with no drift visible
            high = _DISC_BATCHES ** 2 * _WHITE_RATIO * var / size
            top2 = np.sqrt(2.0 * n * high / budget) * _SLACK2
            bottom2 = 3.0 * d3 / _SLACK2
            empty = e * a2 >= top2
            low2 = np.where(empty, np.inf, np.where(e * a2 > bottom2, -np.inf, bottom2 / scale))
            high2 = np.where(empty, -np.inf, top2 / scale)
            top3 = np.sqrt(n * high / (3.0 * budget)) * _SLACK2
            still = (d3 * d3 <= _DRIFT_SIGMAS ** 2 * 2.0 * _WHITE_RATIO * var / size * _SLACK2) \
                | (d3 <= _ROUND_OFF * np.abs(means).max(axis=0) * _SLACK)
            below = np.where(still & (e * a3 < top3), top3 / scale, -np.inf)
        white = (n - skip >= MIN_NOISE_EVIDENCE) & (lag <= _WHITE_LAG)
        low2[~white] = np.inf
        high2[~white] = -np.inf
        below[~white] = -np.inf
        self.conv, self.low, self.high, self.below = conv.tolist(), low2.tolist(), high2.tolist(), below.tolist()
        self.m2, self.m3, self.m4 = means[1].tolist(), means[2].tolist(), means[3].tolist()
        self.within, self.lag = within.tolist(), lag.tolist()
        self.fit: dict[int, float] | None = None
        if len(fits) >= _TABLE_FITS:
            periods = np.array(fits)
            self.fit = dict(zip(fits, _two_mode_fit_floors(hist, skip, periods, fit_window, e).tolist(), strict=True))


def _two_mode_fit_floors(hist: SeriesHistory, skip: int, n: np.ndarray, min_window: int, e: float) -> np.ndarray:
    """For each period n, the least reference at which :func:`_two_mode_fit_may_pass` holds for the first window
    of the fit made at n (-inf: at any), worked out for all n at once."""
    w = np.maximum(min_window, (n - skip) // _FIT_WINDOW_SHARE)
    s = np.maximum(n - 2 * w, 0)
    rows = w - 2
    end = s + w
    _, cum, cum2, lag, lag2 = hist.arrays()
    z0 = hist._first
    d0 = cum[end] - cum[s + 2] - rows * z0
    d1 = cum[end - 1] - cum[s + 1] - rows * z0
    d2 = cum[end - 2] - cum[s] - rows * z0
    g00 = cum2[end] - cum2[s + 2] - np.abs(d0) ** 2 / rows
    g11 = cum2[end - 1] - cum2[s + 1] - np.abs(d1) ** 2 / rows
    g22 = cum2[end - 2] - cum2[s] - np.abs(d2) ** 2 / rows
    g01 = (lag[end] - lag[s + 2]).real - (d0 * np.conj(d1)).real / rows
    g12 = (lag[end - 1] - lag[s + 1]).real - (d1 * np.conj(d2)).real / rows
    g02 = (lag2[end] - lag2[s + 2]).real - (d0 * np.conj(d2)).real / rows
    total = cum2[end]
    err_d = 4.0 * end * _EPS * (end * abs(z0) + np.sqrt(end * total))
    err = 2.0 * (8.0 * end * _EPS * total + (2.0 * np.sqrt(rows * total) * err_d + err_d * err_d) / rows)
    level = np.abs(d0 / rows + z0) + 2.0 * np.abs(d1 / rows + z0) + np.abs(d2 / rows + z0)
    det = g11 * g22 - g12 * g12
    with np.errstate(divide="ignore", invalid="ignore"):
        explained = (g22 * g01 * g01 - 2.0 * g12 * g01 * g02 + g11 * g02 * g02) / det
        lowest = g00 - explained - 16.0 * err - 1e-7 * (np.abs(g00) + np.abs(explained))
        need = np.sqrt(np.maximum(lowest, 0.0) / (2 * rows)) / _SLACK  # the limit the residual needs, less a margin
        always = (rows < 5) | ~np.isfinite(g00 + g11 + g22 + g01 + g12 + g02 + err + level + lowest) \
            | (g00 <= w * (2.0 * _ROUND_OFF * level) ** 2 + 16.0 * err) \
            | ~((g11 > 0.0) & (g22 > 0.0) & (det > 1e-6 * g11 * g22)) \
            | (lowest <= 0.0) | (0.5 * e * level / (1.0 - e) >= need)
        return np.where(always, -np.inf, need / (2.0 * e * RESOLUTION))


def _divide(z: np.ndarray, d: np.ndarray) -> np.ndarray:
    """z / d for complex z and real d (broadcast), part by part (as Python divides a complex by a real)."""
    out = np.empty(z.shape, dtype=complex)
    out.real = z.real / d
    out.imag = z.imag / d
    return out


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

    Cost per period O(1): the settled estimate is checked at every period, but worked out in full only where
    necessary conditions from the running sums (:meth:`_settled_may_stop`, or :class:`_ScreenTable` for many
    periods at once) leave a verdict possible; the fit is tried every period up to 64 analysed periods, then
    every (n - n_k) // 32, and skipped where the running sums bound its residual above what the check accepts.
    A fit refused, twice running, for a mode that has not decayed over its window, at rates that agree within
    10 %, puts the next off until the windows are long enough for that mode to decay at that rate, by
    ``fit_delay`` periods at most (far above resonance a slow mode is refused for dozens of periods in a row;
    a fitted rate that wanders, or a mode on the unit circle, puts nothing off: a fit may pass at isolated
    periods there).
    Fits are made unscreened until one fails on its residual, then screened until eight screens in a row have
    spared none (a clean series, whose fits all explain their windows, is not screened in vain at every period).
    A screen only skips analyses that cannot give a verdict, so with ``fit_delay=0`` (no fit put off) the stop is
    the one the full analysis at every period of the schedule gives (``screened=False, fit_delay=0`` runs that, for
    comparison).
    """

    name = "adaptive"

    def __init__(self, tolerance_percent: float, skip_periods: int, *, max_periods: int = 20000, modes: int = 2,
                 min_window: int = 8, min_periods: int = 8, screened: bool = True, fit_delay: int = 2) -> None:
        super().__init__(tolerance_percent, skip_periods)
        if fit_delay < 0:
            raise ValueError(f"fit_delay must be >= 0, got {fit_delay}")
        self.fit_delay = fit_delay
        self.max_periods = max_periods
        self.modes = modes
        self.min_window = min_window
        self.min_periods = min_periods
        self.screened = screened
        self._next_fit = skip_periods + 2 * min_window  # the fit's schedule: its next period (first with two windows)
        self._fit_put_off = 0  # no fit before this period (a mode refused for its slow decay)
        self._refused_needs = 0.0  # the window a mode refused at the last fit made would decay over (0: none)
        self._table: _ScreenTable | None = None
        self._screening = False  # whether the next fit is screened first
        self._screens_passed = 0  # screens passed in a row since the last that spared a fit

    def _extrapolated(self, hist: SeriesHistory, n: int, reference: float) -> tuple[complex, float] | None:
        """(limit, error bound) of the modal fit confirmed on two windows, or None where it is not confirmed.

        Screened, None also where the bound cannot come within the tolerance: where the running sums show that
        no two-mode fit explains the first window well enough (no fit is made; screened while screens spare
        fits), or where the first window's fit already shows it (the second is not made).
        """
        w = max(self.min_window, (n - self.skip) // _FIT_WINDOW_SHARE)
        if n - 2 * w < self.skip:
            return None
        e = self.eps / 100.0
        screened = self.screened and e < 1.0
        if screened and self.modes == 2:
            table = self._table
            floor = table.fit.get(n) if table is not None and table.fit is not None and table.hist is hist else None
            if floor is not None:
                if reference < floor:
                    return None
            elif self._screening:
                if not _two_mode_fit_may_pass(hist, n - 2 * w, w, e, RESOLUTION * reference):
                    self._screens_passed = 0
                    return None
                self._screens_passed += 1
                self._screening = self._screens_passed < _SCREENS_IN_VAIN
        confirmed, needed = self._fit_windows(hist.arrays()[0], n, w, e, reference, screened,
                                              hist.all_finite(n - 2 * w, n))
        # a mode refused for its slow decay twice running at rates that agree: no fit before the windows are long
        # enough for it to decay (the first period whose w reaches needed), nor later than fit_delay periods after
        # the next one due
        last, self._refused_needs = self._refused_needs, needed
        if w < needed < math.inf and abs(needed - last) <= _RATES_AGREE * needed:
            self._fit_put_off = min(n + 1 + self.fit_delay, self.skip + _FIT_WINDOW_SHARE * math.ceil(needed))
        return confirmed

    def _fit_windows(self, z: np.ndarray, n: int, w: int, e: float, reference: float, screened: bool,
                     finite: bool) -> tuple[tuple[complex, float] | None, float]:
        """:meth:`_extrapolated`'s fits of the windows of w periods before n: (limit, bound) or None, and the
        window over which a mode refused for its slow decay would decay (0: none refused). finite: every value in
        the windows is known to be finite."""
        first, needed = _modal_fit(z[n - 2 * w:n - w], self.modes, _MAX_DECAY, finite)
        if first is None:
            return None, needed
        # screened: the bound holds the prediction error, twice the first residual and the gap between the limits,
        # so a tolerance it meets, e max(|limit|, floor) at the second limit, is at most e max(|first limit| /
        # (1 - e), floor); the residual is known already, the forecast is made only where it passes
        ceiling = e * max(abs(first.limit) / (1.0 - e), RESOLUTION * reference) * _SLACK if screened else math.inf
        if 2.0 * first.residual > ceiling:
            self._screening, self._screens_passed = True, 0  # a screen might have spared this fit
            return None, 0.0
        prediction_error = first.forecast_error(z[n - w:n])
        if prediction_error > ceiling:
            return None, 0.0
        second, needed = _modal_fit(z[n - w:n], self.modes, _MAX_DECAY, finite)
        if second is None:
            return None, needed
        bound = abs(first.limit - second.limit) + 2.0 * max(first.residual, second.residual)
        return (second.limit, max(bound, prediction_error)), 0.0

    def check(self, hist: SeriesHistory, n: int, reference: float) -> Verdict | None:
        analysed = n - self.skip
        if analysed < self.min_periods:
            return None
        # a settled estimate is bounded only with eight batches in each quarter-block
        if analysed >= _BLOCKS * _SUB_BATCHES:
            verdict = self._settled_check(hist, n, reference)
            if verdict is not None:
                return verdict
        # the fit costs more than the mean: once windows are long, try it on a sparser schedule
        if self.modes > 0 and n >= self._next_fit:
            self._next_fit = n + max(1, analysed // 32)
            if n < self._fit_put_off:  # skipped, the schedule kept: a put-off never moves the fits after it
                return None
            fit = self._extrapolated(hist, n, reference)
            if fit is not None:
                limit, bound = fit
                if bound <= self.tolerance(limit, reference):
                    return self._finish(n, Estimate(limit, bound, bound, 0.0, True), self.tolerance(0.0, reference),
                                        "extrapolated")
        return None

    def _settled_check(self, hist: SeriesHistory, n: int, reference: float) -> Verdict | None:
        """The settled estimate's verdict at n where the screen leaves one possible; None to go on."""
        if not self.screened:
            return self._settled_verdict(hist, _quarters(hist, self.skip, n), reference)
        table = self._table
        if table is None or table.hist is not hist or not table.first <= n <= table.last:
            table = None
            if hist.n - n >= _TABLE_AHEAD and n - self.skip >= _TABLE_AFTER:
                e = self.eps / 100.0
                last = min(hist.n, n + _TABLE_SPAN - 1)
                fits = []
                if self.modes == 2 and e < 1.0:  # the periods the fit's schedule reaches in the stretch
                    period = max(self._next_fit, n)
                    while period <= last:
                        fits.append(period)
                        period += max(1, (period - self.skip) // 32)
                table = self._table = _ScreenTable(hist, self.skip, n, last, e, _HOPELESS * self.max_periods / _SLACK,
                                                   fits, self.min_window)
        if table is None:
            q = _quarters(hist, self.skip, n)
            possible, lag = self._settled_may_stop(hist, q, reference)
            return self._settled_verdict(hist, q, reference, lag) if possible else None
        i = n - table.first
        if (reference >= table.conv[i] or table.low[i] < reference < table.high[i] or reference < table.below[i]
                or reference != reference):
            length = (n - self.skip) // _BLOCKS
            q = (n, length, n - _BLOCKS * length, table.m2[i], table.m3[i], table.m4[i], table.within[i])
            return self._settled_verdict(hist, q, reference, table.lag[i])
        return None

    def _settled_verdict(self, hist: SeriesHistory, q: _QuarterStats, reference: float,
                         lag: float | None = None) -> Verdict | None:
        """A verdict from the settled estimate at period q[0]: converged, or noise-limited already; None to go on."""
        settled = _settle(hist, q, lag)
        if not settled.bounded:
            return None
        n = q[0]
        tol = self.tolerance(settled.value, reference)
        if settled.uncertainty <= tol:
            return self._finish(n, settled.estimate(), self.tolerance(0.0, reference), "settled mean")
        needed = self._periods_needed(n, settled.statistical, settled.uncertainty - settled.statistical, tol)
        if settled.white and needed > _HOPELESS * self.max_periods and n - self.skip >= MIN_NOISE_EVIDENCE:
            # the noise alone keeps eps out of reach within the budget: say so now, not at max_periods
            return self._noise_limited(n, settled.estimate(), needed)
        return None

    def _settled_may_stop(self, hist: SeriesHistory, q: _QuarterStats,
                          reference: float) -> tuple[bool, float | None]:
        """(False, _) where the settled estimate cannot give a verdict at period q[0]; from the running sums, O(1).

        Whatever the batch means turn out to be, the noise variance is at least the per-period variance within
        blocks 2-4 times its correlation factor (1 + r)/(1 - r), and its disc factor at least that of their
        degrees of freedom (no fewer than the batch means'), so the statistical half-width is at least what
        those give; unless all three blocks are averaged, the bias is 1.5 |d3|. A noise-limited verdict needs
        white periods: a lag-1 correlation within the white limit, a variance at most twice the per-period
        one, degrees of freedom at least the batch means'. True where either verdict is still possible (or an
        input is not finite); second, the lag-1 correlation over blocks 2-4 where it was needed (else None).
        """
        n, length, start, m2, m3, m4, within = q
        e = self.eps / 100.0
        floor = RESOLUTION * reference
        size = abs((m2 + m3 + m4) / 3)
        tol3 = e * (size if size > floor else floor)  # the tolerance at each candidate value
        size = abs((m3 + m4) / 2)
        tol2 = e * (size if size > floor else floor)
        var = within / (2 * (_BLOCKS - 1) * (length - 1))
        d3 = abs(m4 - m3)
        if not math.isfinite(tol3 + tol2 + var + d3) or tol3 <= 0.0 or tol2 <= 0.0:
            return True, None
        # squared half-widths per averaged block, compared with squared tolerances
        low = _disc_factor(2 * (_BLOCKS - 1) * (length - 1)) ** 2 * var / length
        room = tol2 * _SLACK - 1.5 * d3  # what the bias of the last two blocks leaves of their tolerance
        lag = math.nan
        if low <= 3.0 * tol3 * tol3 * _SLACK2 or (room >= 0.0 and low <= 2.0 * room * room):
            lag = hist.lag_correlation(start + length, n)
            if not math.isnan(lag):
                r = min(max(0.0, lag - 2.0 / math.sqrt(3 * length)), 0.99)
                low *= (1.0 + r) / (1.0 - r)
            if low <= 3.0 * tol3 * tol3 * _SLACK2 or (room >= 0.0 and low <= 2.0 * room * room):
                return True, lag
        if n - self.skip < MIN_NOISE_EVIDENCE:
            return False, None
        white_var = _WHITE_RATIO * var  # the largest noise variance white periods allow
        high = _DISC_BATCHES ** 2 * white_var / length
        budget = _HOPELESS * self.max_periods / _SLACK
        # the last two blocks: a bias up to half the tolerance leaves at least half of it to the noise
        possible = 3.0 * d3 < tol2 * _SLACK and 2.0 * n * high > budget * tol2 * tol2
        # all three averaged: no drift visible, so |d3| within the drift threshold
        if not possible and n * high > 3.0 * budget * tol3 * tol3:
            possible = d3 * d3 <= _DRIFT_SIGMAS ** 2 * 2.0 * white_var / length * _SLACK2
            if not possible:
                m1 = abs(hist.mean(start, start + length))
                possible = d3 <= _ROUND_OFF * max(abs(m2), abs(m3), abs(m4), m1) * _SLACK
        if not possible:
            return False, None
        if math.isnan(lag):
            lag = hist.lag_correlation(start + length, n)
        return lag <= _WHITE_LAG, lag

    def _finish(self, n: int, est: Estimate, floor: float, method: str) -> Verdict:
        """A coefficient within its own uncertainty or the absolute floor of zero has no phase."""
        status = BELOW_RESOLUTION if abs(est.value) <= max(est.uncertainty, floor) else CONVERGED
        return Verdict(n, est.value.real, est.value.imag, est.uncertainty, status, method,
                       uncertainty_1d=est.uncertainty_1d, within_eps=True)

    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        if (n - self.skip) // _BLOCKS < 2:
            return hist.at(n), math.nan
        settled = _settle(hist, _quarters(hist, self.skip, n))
        return settled.value, settled.uncertainty

    @staticmethod
    def _periods_needed(n: int, statistical: float, bias: float, tol: float) -> int:
        """Periods after which the statistical half-width, shrinking as 1/sqrt(n), leaves room for the bias."""
        if bias >= 0.5 * tol or not statistical > 0.0:
            return 0
        return int(math.ceil(n * (statistical / (tol - bias)) ** 2))

    def _noise_limited(self, n: int, est: Estimate, needed: int) -> Verdict:
        return Verdict(n, est.value.real, est.value.imag, est.uncertainty, NOISE_LIMITED, "settled mean",
                       uncertainty_1d=est.uncertainty_1d, within_eps=False, periods_needed=needed)

    def capped(self, hist: SeriesHistory, n: int, reference: float) -> Verdict:
        """At max_periods: noise-limited (with the periods eps would need) when only the statistics are too wide."""
        est = settled_estimate(hist, self.skip, n)
        tol = self.tolerance(est.value, reference)
        needed = self._periods_needed(n, est.statistical, est.bias, tol) if est.bounded and est.white else 0
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
