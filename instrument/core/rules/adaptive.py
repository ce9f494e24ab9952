"""The default stopping rule, :class:`AdaptiveRule`: its decision, and the screens and schedule that spare the
analyses which cannot change it.

The decision is :meth:`AdaptiveRule.check`: the settled estimate's verdict (:meth:`AdaptiveRule._settled_verdict`)
and, failing that, the modal fit's (:func:`_fit_two_windows`, :meth:`AdaptiveRule._fit_verdict`), each from the
named inequalities of :mod:`.intervals`, :mod:`.rule` and :mod:`.modal`. The screens (:mod:`.screens`) are called
only to skip analyses; with ``BODEBENCH_CHECK_SCREENS=1`` in the environment (read once, at import) every analysis
a screen skipped is run as well, and one that would have given a verdict raises AssertionError.
Pure numerics otherwise: no I/O, no threads.
"""

from __future__ import annotations

import math
import os

import numpy as np

from bodebench.core.rules.history import SeriesHistory
from bodebench.core.rules.intervals import (
    _BLOCKS,
    _SUB_BATCHES,
    Estimate,
    _hopeless,
    _noise_budget,
    _periods_needed,
    _quarters,
    _QuarterStats,
    _settle,
    settled_estimate,
)
from bodebench.core.rules.modal import _FIT_WINDOW_SHARE, _MAX_DECAY, _RESIDUALS_IN_BOUND, _confirmed_bound, _modal_fit
from bodebench.core.rules.rule import (
    BELOW_RESOLUTION,
    CAPPED,
    CONVERGED,
    NOISE_LIMITED,
    RESOLUTION,
    StoppingRule,
    Verdict,
)
from bodebench.core.rules.screens import (
    _SCREENS_IN_VAIN,
    _SLACK,
    _TABLE_AFTER,
    _TABLE_AHEAD,
    _TABLE_SPAN,
    _fit_ceiling,
    _ScreenTable,
    _settled_may_stop,
    _two_mode_fit_may_pass,
)

CHECK_SCREENS_VARIABLE = "BODEBENCH_CHECK_SCREENS"
CHECK_SCREENS = os.environ.get(CHECK_SCREENS_VARIABLE, "") == "1"
"""Whether new rules run the full analysis beside every screen that spared one (the variable set to 1)."""

_FIT_SPACING = 32  # once the windows are long, a fit every (n - n_k) // this periods
_RATES_AGREE = 0.1  # how far (relative) the windows two fits in a row find a refused mode needs may differ

# which screen spared an analysis: named in the check mode's AssertionError
_RESIDUAL_SCREEN = "first window's residual against the fit ceiling"
_FORECAST_SCREEN = "first window's forecast error against the fit ceiling"


def _next_fit_after(period: int, skip: int) -> int:
    """The fit's schedule: the period after ``period`` at which the next fit is due (n_k = skip)."""
    return period + max(1, (period - skip) // _FIT_SPACING)


def _fit_two_windows(z: np.ndarray, n: int, w: int, modes: int, e: float, floor: float, screened: bool,
                     finite: bool) -> tuple[tuple[complex, float] | None, float, str]:
    """The modal fits of the two windows of w periods before n: the limit they confirm with its error bound
    (:func:`~bodebench.core.rules.modal._confirmed_bound`, output units) or None; the window over which a mode
    refused for its slow decay would decay (0: none refused); and the screen that spared the second fit ("":
    none). z: the history's values; e = eps / 100; floor: the tolerance's absolute floor (output units);
    screened: stop after the first window where :func:`~bodebench.core.rules.screens._fit_ceiling` shows the
    bound out of reach; finite: every value in the windows is known to be finite."""
    first, needed = _modal_fit(z[n - 2 * w:n - w], modes, _MAX_DECAY, finite)
    if first is None:
        return None, needed, ""
    ceiling = _fit_ceiling(e, first.limit, floor) if screened else math.inf
    if _RESIDUALS_IN_BOUND * first.residual > ceiling:
        return None, 0.0, _RESIDUAL_SCREEN
    prediction_error = first.forecast_error(z[n - w:n])
    if prediction_error > ceiling:
        return None, 0.0, _FORECAST_SCREEN
    second, needed = _modal_fit(z[n - w:n], modes, _MAX_DECAY, finite)
    if second is None:
        return None, needed, ""
    return (second.limit, _confirmed_bound(first, second, prediction_error)), 0.0, ""


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

    Tolerance: ``eps/100 * max(|Z|, RESOLUTION * channel_scale)``: a coefficient far below the channel's largest
    one is measured to an absolute floor and reported as below resolution when its confidence region
    contains zero. Points that reach ``max_periods`` end ``noise_limited`` when only the statistical part is
    too wide (with the periods the requested eps would need), else ``capped``.

    Cost per period O(1): the settled estimate is checked at every period, but worked out in full only where
    necessary conditions from the running sums (:func:`~bodebench.core.rules.screens._settled_may_stop`, or
    :class:`~bodebench.core.rules.screens._ScreenTable` for many periods at once) leave a verdict possible; the
    fit is tried every period up to 64 analysed periods, then every (n - n_k) // 32, and skipped where the
    running sums bound its residual above what the check accepts.
    A fit refused, twice running, for a mode that has not decayed over its window, at rates that agree within
    10 %, puts the next off until the windows are long enough for that mode to decay at that rate, by
    ``fit_delay`` periods at most (far above resonance a slow mode is refused for dozens of periods in a row;
    a fitted rate that wanders, or a mode on the unit circle, puts nothing off: a fit may pass at isolated
    periods there).
    Fits are made unscreened until one fails on its residual, then screened until eight screens in a row have
    spared none (a clean series, whose fits all explain their windows, is not screened in vain at every period).
    A screen only skips analyses that cannot give a verdict, so with ``fit_delay=0`` (no fit put off) the stop is
    the one the full analysis at every period of the schedule gives (``screened=False, fit_delay=0`` runs that, for
    comparison). check_screens: run the full analysis beside every screen that spared one and raise AssertionError
    where it gives a verdict (default: :data:`CHECK_SCREENS`, from the environment).
    """

    name = "adaptive"

    def __init__(self, tolerance_percent: float, skip_periods: int, *, max_periods: int = 20000, modes: int = 2,
                 min_window: int = 8, min_periods: int = 8, screened: bool = True, fit_delay: int = 2,
                 check_screens: bool = CHECK_SCREENS) -> None:
        super().__init__(tolerance_percent, skip_periods)
        if fit_delay < 0:
            raise ValueError(f"fit_delay must be >= 0, got {fit_delay}")
        self.fit_delay = fit_delay
        self.max_periods = max_periods
        self.modes = modes
        self.min_window = min_window
        self.min_periods = min_periods
        self.screened = screened
        self.check_screens = check_screens  # run the full analysis beside every screen that spared one
        self._next_fit = skip_periods + 2 * min_window  # the fit's schedule: its next period (first with two windows)
        self._fit_put_off = 0  # no fit before this period (a mode refused for its slow decay)
        self._refused_needs = 0.0  # the window a mode refused at the last fit made would decay over (0: none)
        self._table: _ScreenTable | None = None
        self._screening = False  # whether the next fit is screened first
        self._screens_passed = 0  # screens passed in a row since the last that spared a fit

    def check(self, hist: SeriesHistory, n: int, channel_scale: float) -> Verdict | None:
        analysed = n - self.skip
        if analysed < self.min_periods:
            return None
        # a settled estimate is bounded only with eight batches in each quarter-block
        if analysed >= _BLOCKS * _SUB_BATCHES:
            verdict = self._settled_check(hist, n, channel_scale)
            if verdict is not None:
                return verdict
        # the fit costs more than the mean: once windows are long, try it on a sparser schedule
        if self.modes > 0 and n >= self._next_fit:
            self._next_fit = _next_fit_after(n, self.skip)
            if n < self._fit_put_off:  # skipped, the schedule kept: a put-off never moves the fits after it
                return None
            return self._fit_verdict(n, self._extrapolated(hist, n, channel_scale), channel_scale)
        return None

    def _settled_verdict(self, hist: SeriesHistory, q: _QuarterStats, channel_scale: float,
                         lag: float | None = None) -> Verdict | None:
        """A verdict from the settled estimate at period q[0]: converged, or noise-limited already; None to go on."""
        settled = _settle(hist, q, lag)
        if not settled.bounded:
            return None
        n = q[0]
        tol = self.tolerance(settled.value, channel_scale)
        if settled.fits(tol):
            return self._finish(n, settled.estimate(), self.tolerance(0.0, channel_scale), "settled mean")
        needed = _periods_needed(n, settled.stop_statistical, settled.bias, tol)
        if _hopeless(settled.white, needed, self.max_periods, n - self.skip):
            # the noise alone keeps eps out of reach within the budget: say so now, not at max_periods
            return self._noise_limited(n, settled.estimate(ended_by_budget=True), needed)
        return None

    def _fit_verdict(self, n: int, fit: tuple[complex, float] | None, channel_scale: float) -> Verdict | None:
        """A verdict from the limit two windows' fits confirm (with its bound, output units) where the bound is
        within the tolerance at that limit; None to go on."""
        if fit is None:
            return None
        limit, bound = fit
        if bound <= self.tolerance(limit, channel_scale):
            return self._finish(n, Estimate(limit, bound, bound, 0.0, True), self.tolerance(0.0, channel_scale),
                                "extrapolated")
        return None

    def _settled_check(self, hist: SeriesHistory, n: int, channel_scale: float) -> Verdict | None:
        """The settled estimate's verdict at n where the screen leaves one possible; None to go on."""
        if not self.screened:
            return self._settled_verdict(hist, _quarters(hist, self.skip, n), channel_scale)
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
                        period = _next_fit_after(period, self.skip)
                table = self._table = _ScreenTable(hist, self.skip, n, last, e,
                                                   _noise_budget(self.max_periods) / _SLACK, fits, self.min_window)
        if table is None:
            q = _quarters(hist, self.skip, n)
            possible, lag = _settled_may_stop(hist, q, channel_scale, self.eps / 100.0, self.skip, self.max_periods)
            if possible:
                return self._settled_verdict(hist, q, channel_scale, lag)
            screen = "settled screen"
        else:
            i = n - table.first
            scale = channel_scale
            if (scale >= table.conv[i] or table.low[i] < scale < table.high[i] or scale < table.below[i]
                    or scale != scale):
                length = (n - self.skip) // _BLOCKS
                q = (n, length, n - _BLOCKS * length, table.m2[i], table.m3[i], table.m4[i], table.within[i])
                return self._settled_verdict(hist, q, channel_scale, table.lag[i])
            screen = "settled screen table"
        if self.check_screens:
            self._spared(n, screen, self._settled_verdict(hist, _quarters(hist, self.skip, n), channel_scale))
        return None

    def _extrapolated(self, hist: SeriesHistory, n: int, channel_scale: float) -> tuple[complex, float] | None:
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
            fits = table.fit if table is not None and table.hist is hist else None
            least_scale = fits.get(n) if fits is not None else None
            if least_scale is not None:
                if channel_scale < least_scale:
                    self._check_fit_spared(hist, n, w, e, channel_scale, "two-mode fit screen table")
                    return None
            elif self._screening:
                if not _two_mode_fit_may_pass(hist, n - 2 * w, w, e, RESOLUTION * channel_scale):
                    self._screens_passed = 0
                    self._check_fit_spared(hist, n, w, e, channel_scale, "two-mode fit screen")
                    return None
                self._screens_passed += 1
                self._screening = self._screens_passed < _SCREENS_IN_VAIN
        confirmed, needed, screen = _fit_two_windows(hist.arrays()[0], n, w, self.modes, e, RESOLUTION * channel_scale,
                                                     screened, hist.all_finite(n - 2 * w, n))
        if screen == _RESIDUAL_SCREEN:
            self._screening, self._screens_passed = True, 0  # a screen might have spared this fit
        if screen:
            self._check_fit_spared(hist, n, w, e, channel_scale, screen)
        # a mode refused for its slow decay twice running at rates that agree: no fit before the windows are long
        # enough for it to decay (the first period whose w reaches needed), nor later than fit_delay periods after
        # the next one due
        last, self._refused_needs = self._refused_needs, needed
        if w < needed < math.inf and abs(needed - last) <= _RATES_AGREE * needed:
            self._fit_put_off = min(n + 1 + self.fit_delay, self.skip + _FIT_WINDOW_SHARE * math.ceil(needed))
        return confirmed

    def _check_fit_spared(self, hist: SeriesHistory, n: int, w: int, e: float, channel_scale: float,
                          screen: str) -> None:
        """In the check mode, the fit verdict the unscreened fits of the windows at n would give, for
        :meth:`_spared`; nothing otherwise."""
        if self.check_screens:
            fit = _fit_two_windows(hist.arrays()[0], n, w, self.modes, e, RESOLUTION * channel_scale, False,
                                   hist.all_finite(n - 2 * w, n))[0]
            self._spared(n, screen, self._fit_verdict(n, fit, channel_scale))

    @staticmethod
    def _spared(n: int, screen: str, verdict: Verdict | None) -> None:
        """The check mode's test: a screen that spared the analysis at period n spared no verdict."""
        if verdict is not None:
            raise AssertionError(f"period {n}: the {screen} spared an analysis that gives a verdict "
                                 f"({verdict.status}, {verdict.method}, value {complex(verdict.p, verdict.q)})")

    def _finish(self, n: int, est: Estimate, floor: float, method: str) -> Verdict:
        """A coefficient within its own uncertainty or the absolute floor of zero has no phase."""
        status = BELOW_RESOLUTION if abs(est.value) <= max(est.uncertainty, floor) else CONVERGED
        return Verdict(n, est.value.real, est.value.imag, est.uncertainty, status, method,
                       uncertainty_1d=est.uncertainty_1d, within_eps=True)

    def estimate(self, hist: SeriesHistory, n: int) -> tuple[complex, float]:
        return self.progress(hist, n)[:2]

    def progress(self, hist: SeriesHistory, n: int) -> tuple[complex, float, float]:
        """The settled estimate, its stated (95 %) uncertainty and the width its stop compares: the noise disc at
        :data:`STOP_CONFIDENCE` plus the transient bound."""
        if (n - self.skip) // _BLOCKS < 2:
            return hist.at(n), math.nan, math.nan
        settled = _settle(hist, _quarters(hist, self.skip, n))
        return settled.value, settled.estimate().uncertainty, settled.stop_width

    def _noise_limited(self, n: int, est: Estimate, needed: int) -> Verdict:
        return Verdict(n, est.value.real, est.value.imag, est.uncertainty, NOISE_LIMITED, "settled mean",
                       uncertainty_1d=est.uncertainty_1d, within_eps=False, periods_needed=needed)

    def capped(self, hist: SeriesHistory, n: int, channel_scale: float) -> Verdict:
        """At max_periods: noise-limited (with the periods eps would need) when only the statistics are too wide."""
        est = settled_estimate(hist, self.skip, n, ended_by_budget=True)
        tol = self.tolerance(est.value, channel_scale)
        needed = _periods_needed(n, est.stop_statistical, est.bias, tol) if est.bounded and est.white else 0
        if needed:
            return self._noise_limited(n, est, needed)
        return Verdict(n, est.value.real, est.value.imag, est.uncertainty, CAPPED, self.name,
                       uncertainty_1d=est.uncertainty_1d)
