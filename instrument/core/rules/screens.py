"""Speed screens of :class:`~bodebench.core.rules.adaptive.AdaptiveRule`: necessary conditions, from the running
sums in O(1), under which the full analysis of a period could give a verdict. Where one fails the rule skips that
analysis; nothing here decides a verdict.

Each screen bounds an inequality of the decision and says which in its docstring; the inequalities themselves
are the named functions and constants of :mod:`.intervals`, :mod:`.rule` and :mod:`.modal` that the decision
calls. ``BODEBENCH_CHECK_SCREENS=1`` makes the rule run the full analysis beside every screen that spared one
(see :mod:`bodebench.core.rules`). Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from bodebench.core.rules.history import _EPS, SeriesHistory
from bodebench.core.rules.intervals import (
    _BLOCKS,
    _DISC_BATCHES,
    _DRIFT_SIGMAS,
    _ROUND_OFF,
    _TAIL,
    _WHITE_LAG,
    _WHITE_RATIO,
    MIN_NOISE_EVIDENCE,
    STOP_CONFIDENCE,
    _correlation_inflation,
    _disc_factor,
    _disc_factor_squared,
    _enough_noise_evidence,
    _noise_budget,
    _pooled_dof,
    _QuarterStats,
    _white_lag,
)
from bodebench.core.rules.modal import _FIT_WINDOW_SHARE, _RESIDUALS_IN_BOUND
from bodebench.core.rules.rule import RESOLUTION, _tolerance

_SLACK = 1.0 + 1e-9   # margin of a screen's inequalities over the round-off of the bounds they compare
_SLACK2 = _SLACK * _SLACK
_SCREENS_IN_VAIN = 8  # screens passed in a row after which fits are made unscreened until one fails on its residual

_TABLE_SPAN = 1024  # periods whose settled screen is worked out at once
_TABLE_AHEAD = 16   # periods the history must hold beyond the one checked for a table to pay
_TABLE_AFTER = 96   # analysed periods before a table pays: building one costs as much as screening ~60 periods
                    # one by one, which a series that stops early never checks
_TABLE_FITS = 16    # scheduled fits in a table's stretch for their screens to be worked out at once


def _fit_ceiling(e: float, first_limit: complex, floor: float) -> float:
    """The most the tolerance of a limit that two windows' fits confirm can be, from the first window's limit
    (output units): the confirmed bound holds the gap between the limits, so a tolerance it meets, e max(|second
    limit|, floor), is at most e max(|first limit| / (1 - e), floor). Both twice the first residual and the first
    fit's forecast error are parts of that bound (:func:`~bodebench.core.rules.modal._confirmed_bound`): where
    either exceeds this, the second window need not be fitted. e = eps / 100; floor: the tolerance's absolute
    floor (output units)."""
    return _tolerance(e, abs(first_limit) / (1.0 - e), floor) * _SLACK


def _settled_may_stop(hist: SeriesHistory, q: _QuarterStats, channel_scale: float, e: float, skip: int,
                      max_periods: int) -> tuple[bool, float | None]:
    """(False, _) where the settled estimate cannot give a verdict at period q[0]; from the running sums, O(1).

    Bounds the settled verdict's two inequalities: converged, the noise disc at STOP_CONFIDENCE plus the bias
    within the tolerance; noise-limited, :func:`~bodebench.core.rules.intervals._hopeless`. Whatever the batch
    means turn out to be, the noise variance is at least the per-period variance within blocks 2-4 times its
    correlation inflation, and its disc factor at least that of their degrees of freedom (no fewer than the batch
    means'), so the statistical half-width is at least what those give; unless all three blocks are averaged, the
    bias is _TAIL |d3|. A noise-limited verdict needs white periods: a lag-1 correlation within the white limit, a
    variance at most _WHITE_RATIO times the per-period one, degrees of freedom at least the batch means'. True
    where either verdict is still possible (or an input is not finite); second, the lag-1 correlation over blocks
    2-4 where it was needed (else None). e = eps / 100; skip: n_k; max_periods: the rule's budget.
    """
    n, length, start, m2, m3, m4, within = q
    floor = RESOLUTION * channel_scale
    tol3 = _tolerance(e, abs((m2 + m3 + m4) / 3), floor)  # the tolerance at each candidate value
    tol2 = _tolerance(e, abs((m3 + m4) / 2), floor)
    dof = _pooled_dof(length)
    var = within / dof
    d3 = abs(m4 - m3)
    if not math.isfinite(tol3 + tol2 + var + d3) or tol3 <= 0.0 or tol2 <= 0.0:
        return True, None
    # squared half-widths per averaged block, compared with squared tolerances
    low = _disc_factor(dof, STOP_CONFIDENCE) ** 2 * var / length
    room = tol2 * _SLACK - _TAIL * d3  # what the bias of the last two blocks leaves of their tolerance
    lag = math.nan
    if low <= 3.0 * tol3 * tol3 * _SLACK2 or (room >= 0.0 and low <= 2.0 * room * room):
        lag = hist.lag_correlation(start + length, n)
        low *= _correlation_inflation(lag, length)
        if low <= 3.0 * tol3 * tol3 * _SLACK2 or (room >= 0.0 and low <= 2.0 * room * room):
            return True, lag
    if not _enough_noise_evidence(n - skip):
        return False, None
    white_var = _WHITE_RATIO * var  # the largest noise variance white periods allow
    high = _DISC_BATCHES ** 2 * white_var / length
    budget = _noise_budget(max_periods) / _SLACK
    # the last two blocks: a bias below half the tolerance (else no periods are projected) leaves half of it to
    # the noise
    possible = 2.0 * _TAIL * d3 < tol2 * _SLACK and 2.0 * n * high > budget * tol2 * tol2
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
    return _white_lag(lag), lag


def _two_mode_fit_may_pass(hist: SeriesHistory, s: int, w: int, e: float, floor: float) -> bool:
    """False where no two-mode fit of periods s+1..s+w can explain them well enough for the modal check; O(1).

    Bounds the fit verdict's inequality, the confirmed bound within the tolerance at the second window's limit,
    through the bound's term twice the first window's residual (:func:`~bodebench.core.rules.modal._confirmed_bound`).

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
    limit = _tolerance(e, level / (1.0 - e), 4.0 * floor) / _RESIDUALS_IN_BOUND
    return lowest <= 2 * rows * limit * limit * _SLACK


class _ScreenTable:
    """The settled screen of periods first..last of one history, worked out at once with numpy.

    Per period: the channel scale (the magnitude of the channel's largest coefficient, output units) at and above
    which a converged verdict is possible (conv), the open interval (low, high) and the bound below which (below) a
    noise-limited one is; and the quarter-block statistics and lag-1 correlation the settled estimate then takes.
    The same necessary conditions as :func:`_settled_may_stop`, solved for the channel scale. fit: for the
    periods ``fits`` lists (the modal fit's schedule), the channel scale at and above which the two-mode fit's
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
            # r of _correlation_inflation, per period
            r = np.clip(np.nan_to_num(lag - 2.0 / np.sqrt(3 * size), nan=0.0), 0.0, 0.99)
            dof = _pooled_dof(length)
            disc2 = _disc_factor_squared(dof, STOP_CONFIDENCE)
            var = within / dof
            low = disc2 * var / size * (1.0 + r) / (1.0 - r)
            a3 = np.abs(means[1:].sum(axis=0) / 3)
            a2 = np.abs(means[2:].sum(axis=0) / 2)
            d3 = np.abs(means[3] - means[2])
            scale = e * RESOLUTION  # the tolerance floor per unit of channel scale
            # converged: the tolerance at the value of the last three (two) blocks must reach the half-width
            # (plus _TAIL |d3|); the tolerance is e max(|value|, RESOLUTION channel_scale)
            need3 = np.sqrt(low / 3.0)
            need2 = _TAIL * d3 + np.sqrt(low / 2.0)
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
    """For each period n, the least channel scale at which :func:`_two_mode_fit_may_pass` holds for the first window
    of the fit made at n (-inf: at any), worked out for all n at once (the same bound solved for the channel scale:
    the floor term of its tolerance, 4 floor e / 2, is 2 e RESOLUTION channel_scale)."""
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
