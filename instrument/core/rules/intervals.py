"""The settled estimate and its intervals: the noise and transient bounds of the first estimator of
:class:`~bodebench.core.rules.adaptive.AdaptiveRule`, and the interval factors every rule states.

The inequalities by which the settled estimate is accepted (the pooled degrees of freedom, the correlation
inflation, the white test, the tail bound of a geometric drift, the noise budget) are named functions and
constants here; the decision (:mod:`.adaptive`) and the screens (:mod:`.screens`) both call them.
Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TypeVar, overload

import numpy as np

from bodebench.core.rules.history import SeriesHistory
from bodebench.core.student_t import t_quantile

CONFIDENCE = 0.95
"""Level of every interval a rule states."""

STOP_CONFIDENCE = 0.98
"""Level of the noise disc that must fit within the tolerance, with the transient bound, for the settled estimate
to converge: a converged point is within eps at this level (at most 2 % of noisy points outside it), while the
interval it states stays the :data:`CONFIDENCE` one."""

_BLOCKS = 4          # quarter-blocks of the analysed record
_SUB_BATCHES = 8     # batches per block for the statistical spread
_MAX_RATIO = 0.5     # a visible drift must shrink at least this fast from block to block
_TAIL = 1.5          # the transient left in the mean of blocks 3-4, per |d3|, of a drift shrinking by _MAX_RATIO
_DRIFT_SIGMAS = 3.72  # |d| / sigma_d of a 2-D normal exceeds this with probability 0.1 %
_ROUND_OFF = 1e-12    # relative size of a change that round-off of the running sums can make
_HOPELESS = 2.0       # a point whose projected periods exceed this many budgets ends noise-limited at once
MIN_NOISE_EVIDENCE = 128  # analysed periods before the noise is judged hopeless
_WHITE_RATIO = 2.0    # batch-mean variance over per-period variance still taken for independent periods
_WHITE_LAG = 0.2      # |lag-1 autocorrelation| still taken for independent periods

_Count = TypeVar("_Count", int, np.ndarray)

_DISC: dict[tuple[int, float], float] = {}


@overload
def _disc_factor_squared(dof: int, confidence: float = CONFIDENCE) -> float: ...
@overload
def _disc_factor_squared(dof: np.ndarray, confidence: float = CONFIDENCE) -> np.ndarray: ...
def _disc_factor_squared(dof: int | np.ndarray, confidence: float = CONFIDENCE) -> float | np.ndarray:
    """The square of :func:`_disc_factor`, for one number of degrees of freedom or an array of them.

    |error|^2 / (2 s^2) follows F(2, dof), whose quantile has the closed form dof/2 ((1 - c)^(-2/dof) - 1).
    """
    return dof * ((1.0 - confidence) ** (-2.0 / dof) - 1.0)


def _disc_factor(dof: int, confidence: float = CONFIDENCE) -> float:
    """Radius, in standard deviations per component, of the confidence disc of a circular 2-D normal mean
    whose variance is estimated with ``dof`` degrees of freedom (:func:`_disc_factor_squared`, kept per dof and
    level)."""
    key = (dof, confidence)
    found = _DISC.get(key)
    if found is not None:
        return found
    factor = math.sqrt(_disc_factor_squared(dof, confidence))
    if len(_DISC) > 4096:
        _DISC.clear()
    _DISC[key] = factor
    return factor


@functools.lru_cache(maxsize=256)
def _line_factor(dof: int, confidence: float = CONFIDENCE) -> float:
    """Two-sided Student t quantile: the 95 % half-width of one component, in standard deviations."""
    return t_quantile(0.5 + confidence / 2.0, dof)


def _pooled_dof(per_block: _Count) -> _Count:
    """Degrees of freedom of a variance per component pooled over blocks 2-4 from ``per_block`` values a block
    (each value's two components about their own block's mean)."""
    return 2 * (_BLOCKS - 1) * (per_block - 1)


def _correlation_inflation(lag: float, length: int) -> float:
    """(1 + r) / (1 - r): how much correlation longer than a batch widens the variance of a mean of AR(1)-like
    periods; r the |lag-1 autocorrelation| ``lag`` beyond what its sampling error over three blocks of ``length``
    periods (about 2 / sqrt(periods)) explains, at most 0.99 (1 where the correlation is unknown)."""
    r = min(max(0.0, lag - 2.0 / math.sqrt(3 * length)), 0.99) if not math.isnan(lag) else 0.0
    return (1.0 + r) / (1.0 - r)


def _white_lag(lag: float) -> bool:
    """Whether neighbouring periods are as unlike as independent ones (a slow transient or coloured noise, e.g. a
    resonance excited by jitter, makes them alike)."""
    return lag <= _WHITE_LAG


def _white(batch_variance: float, period_variance: float, lag: float) -> bool:
    """Whether the periods scatter like independent noise: the batch means no more than independent periods would
    (variances per component, output units squared), and :func:`_white_lag`."""
    return batch_variance <= _WHITE_RATIO * period_variance and _white_lag(lag)


def _noise_budget(max_periods: int) -> float:
    """The periods beyond which a point whose noise alone keeps eps out of reach ends noise-limited at once."""
    return _HOPELESS * max_periods


def _enough_noise_evidence(analysed: int) -> bool:
    """Whether ``analysed`` periods are enough to judge the noise hopeless."""
    return analysed >= MIN_NOISE_EVIDENCE


def _periods_needed(n: int, statistical: float, bias: float, tol: float) -> int:
    """Periods after which the statistical half-width, shrinking as 1/sqrt(n), leaves room for the bias (0 where
    the bias takes half the tolerance or more, or no statistical part is known); output units."""
    if bias >= 0.5 * tol or not statistical > 0.0:
        return 0
    return int(math.ceil(n * (statistical / (tol - bias)) ** 2))


def _hopeless(white: bool, needed: int, max_periods: int, analysed: int) -> bool:
    """Whether a bounded settled estimate ends noise-limited now: white periods, after enough evidence, whose
    noise alone would need more periods than the budget allows."""
    return white and needed > _noise_budget(max_periods) and _enough_noise_evidence(analysed)


@dataclass(frozen=True)
class Estimate:
    """An estimate of a series' limit with its error bound (output units).

    uncertainty: 95 % disc radius, statistical + bias; uncertainty_1d: 95 % half-width along one direction,
    statistical + bias; statistical: the disc radius from noise alone; bounded: whether the history shows
    that the transient left is bounded (False: no error bound exists yet; the uncertainties are then the
    best available but not a guarantee); white: the periods scatter like independent noise; stop_statistical:
    the noise disc radius at :data:`STOP_CONFIDENCE`, which the stop compares with the tolerance.
    """

    value: complex
    uncertainty: float
    uncertainty_1d: float
    statistical: float
    bounded: bool
    white: bool = False
    stop_statistical: float = math.nan

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


_DISC_BATCHES = _disc_factor(_pooled_dof(_SUB_BATCHES), STOP_CONFIDENCE)  # the stop's disc factor, 8 batches a block
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

    value (output units); bias: bound on the transient left (output units); bounded, white: as :class:`Estimate`;
    dof, sigma_mean: degrees of freedom of the noise estimate (the larger of the batch means' and the periods'
    spread) and the standard deviation per component of the estimate from it (output units); period_dof,
    period_sigma: the same from the periods' own spread alone.
    """

    __slots__ = ("value", "bias", "bounded", "white", "dof", "sigma_mean", "period_dof", "period_sigma")

    def __init__(self, value: complex, bias: float, bounded: bool, white: bool, dof: int, sigma_mean: float,
                 period_dof: int, period_sigma: float) -> None:
        self.value, self.bias, self.bounded, self.white = value, bias, bounded, white
        self.dof, self.sigma_mean, self.period_dof, self.period_sigma = dof, sigma_mean, period_dof, period_sigma

    @property
    def stop_statistical(self) -> float:
        """The noise disc radius at :data:`STOP_CONFIDENCE` (output units)."""
        return _disc_factor(self.dof, STOP_CONFIDENCE) * self.sigma_mean

    @property
    def stop_width(self) -> float:
        """What the stop compares with the tolerance: the noise disc at :data:`STOP_CONFIDENCE` plus the transient
        bound (output units)."""
        return self.stop_statistical + self.bias

    def fits(self, tolerance: float) -> bool:
        """Whether the estimate may stop: its :attr:`stop_width` within ``tolerance`` (output units)."""
        return self.stop_width <= tolerance

    def estimate(self, ended_by_budget: bool = False) -> Estimate:
        """The estimate with its stated intervals. A point that stops because its spread is small states the larger
        noise estimate (at the stop, the spread is more often low than high); one that ends for its budget
        (``ended_by_budget``: noise-limited, capped) was not chosen by its spread, and where its periods scatter
        like independent noise states their own spread, which the larger of two estimates overstates."""
        dof, sigma = (self.period_dof, self.period_sigma) if ended_by_budget and self.white else (self.dof,
                                                                                                 self.sigma_mean)
        statistical = _disc_factor(dof) * sigma
        line = _line_factor(dof) * sigma
        return Estimate(self.value, statistical + self.bias, line + self.bias, statistical, self.bounded,
                        self.white, self.stop_statistical)


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
    dof = _pooled_dof(batches)
    var1 = dev / dof
    period_dof = _pooled_dof(length)
    var_periods = within / period_dof
    if lag is None:
        lag = hist.lag_correlation(start + length, n)
    white = _white(var1, var_periods, lag)
    var_periods *= _correlation_inflation(lag, length)
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
        used, bias = 2, _TAIL * d3
        bounded = d3 <= max(_MAX_RATIO * d2, visible) and d2 <= max(_MAX_RATIO * d1, visible)
        value = (block[2] + block[3]) / 2
    sigma_mean = math.sqrt(var1 / (used * length))  # per component
    # with fewer batches than _SUB_BATCHES a smooth drift looks like noise: no bound from so short a record
    bounded = bounded and batches == _SUB_BATCHES
    return _Settled(value, bias, bounded, white, dof, sigma_mean, period_dof, math.sqrt(var_periods / (used * length)))


def settled_estimate(hist: SeriesHistory, skip: int, n: int, ended_by_budget: bool = False) -> Estimate:
    """The mean of the settled part of periods skip+1..n, with its 95 % bounds (output units).

    The analysed record is cut into four equal blocks, each into up to eight batches. Noise: the
    pooled spread of the batch means about their own block's mean in the last three blocks (between-block
    drift excluded), with 3 blocks x (batches - 1) x 2 degrees of freedom, or of the periods themselves where
    larger (``ended_by_budget``: the periods' own where they scatter like independent noise, see
    :meth:`_Settled.estimate`). Drift: the changes d2, d3 between
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
    return _settle(hist, _quarters(hist, skip, n)).estimate(ended_by_budget)
