"""Monoharmonic autointegration of one frequency point: samples in, verdicts out.

Joins the per-period integrator (``bodebench.core.fourier``) with a stopping rule
per series (one series = one channel x one harmonic). Pure numerics: the
caller brings timestamped samples from a simulation or a bus.

Gaps in the stream: a period that holds part of an interval between two samples longer than ``max_gap_cycles``
cycles of the highest harmonic integrated is not integrated but discarded (counted in ``discarded``); the rules see
the whole periods only, numbered 1, 2, ... in the order they came. A point of which more than
``max_discarded_percent`` of the periods were discarded fails (``failure`` says why), judged when the rules have
stopped, at every period once the periods spanned reach ``max_periods`` (the period budget), and before that at
every discarded period against the budget: once the discarded periods exceed that share of it
(:func:`discard_limit`), no later period can make the point pass.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bodebench.core.benchgrid import (
    LINE_TURNS,
    alias_fit_order,
    fold_bound,
    line_leak,
    lines_beyond_fit,
    lines_on_fit,
    lines_on_harmonics,
    seen_at,
    turning_amplitude,
)
from bodebench.core.fourier import ExactPeriodIntegrator, GridPeriodIntegrator, line_gains
from bodebench.core.phase_average import PhaseAverage, grid_stands_still, waveform_fold_bound
from bodebench.core.quality import MIN_COHERENCE_PERIODS, coherence, coherence_periods, total_harmonic_distortion
from bodebench.core.response import ResponsePoint
from bodebench.core.rules import MIN_NOISE_EVIDENCE, RESOLUTION, SeriesHistory, StoppingRule, Verdict, make_rule
from bodebench.status import PointStatus


class AnalysisSettings(Protocol):
    """What the sampler needs to know of the analysis (``[analysis]`` of a configuration provides it): the
    harmonics, the stopping rule's name and parameters (tolerance in percent, periods), and the period limit."""

    @property
    def harmonics(self) -> tuple[int, ...]: ...
    @property
    def criterion(self) -> str: ...
    @property
    def tolerance_percent(self) -> float: ...
    @property
    def skip_periods(self) -> int: ...
    @property
    def window(self) -> int: ...
    @property
    def settle_periods(self) -> int: ...
    @property
    def average_periods(self) -> int: ...
    @property
    def max_periods(self) -> int: ...
    @property
    def max_point_s(self) -> float | None: ...
    @property
    def max_gap_cycles(self) -> float: ...
    @property
    def max_discarded_percent(self) -> float: ...
    @property
    def fold_policy(self) -> str: ...
    @property
    def fold_decay(self) -> float: ...

class GapsError(ValueError):
    """A point of which too many periods were discarded for gaps in its samples; the message says how many."""


_FEW_PERIODS = 4  # periods up to which feed() works on Python scalars (cheaper than numpy's per-call cost)

DEFAULT_BENCH_POINT_S = 600.0
"""A bench point's time budget (s of the drive's clock) where ``max_point_s`` is not given: ten minutes."""
MIN_BUDGET_PERIODS = 2 * MIN_NOISE_EVIDENCE
"""Fewest periods a time budget leaves a point: twice the noise evidence the stopping rule judges a hopeless
point on, so a low frequency is still measured, and ended noise-limited early where eps is out of reach."""


def point_seconds(analysis: AnalysisSettings, on_bench: bool) -> float | None:
    """A point's time budget, s: ``max_point_s``, else :data:`DEFAULT_BENCH_POINT_S` on a bench and none offline."""
    if analysis.max_point_s is not None:
        return analysis.max_point_s
    return DEFAULT_BENCH_POINT_S if on_bench else None


def period_budget(analysis: AnalysisSettings, frequency_hz: float, on_bench: bool) -> int:
    """The periods a point at ``frequency_hz`` (Hz) may integrate: ``max_periods``, and at most
    :func:`point_seconds` of them, but never fewer than :data:`MIN_BUDGET_PERIODS`. A series whose noise needs more
    than twice the budget for eps ends ``noise_limited`` as soon as the noise is known (the rule's ``max_periods``
    is this budget)."""
    seconds = point_seconds(analysis, on_bench)
    if seconds is None:
        return analysis.max_periods
    return min(analysis.max_periods, max(MIN_BUDGET_PERIODS, analysis.skip_periods + 1,
                                         math.ceil(seconds * frequency_hz)))


def too_many_discarded(discarded: int, periods: int, max_discarded_percent: float) -> bool:
    """Whether ``discarded`` periods are more than ``max_discarded_percent`` (percent) of ``periods`` periods: the
    share of a point's periods discarded for gaps that fails it."""
    return 100.0 * discarded > max_discarded_percent * periods


def discard_limit(periods: int, max_discarded_percent: float) -> int:
    """The most periods of ``periods`` that may be discarded within ``max_discarded_percent`` (percent): one more is
    :func:`too_many_discarded`."""
    limit = min(periods, math.floor(max_discarded_percent * periods / 100.0))
    while limit > 0 and too_many_discarded(limit, periods, max_discarded_percent):  # the product's round-off
        limit -= 1
    while limit < periods and not too_many_discarded(limit + 1, periods, max_discarded_percent):
        limit += 1
    return limit


MAX_DIVISOR_SCATTER = 0.25
"""Two-channel mode: the most the divisor's fundamental may scatter from period to period, relative to its size
(:meth:`Autointegrator.divisor_scatter`), for the mean of the periods' ratios to be the ratio. The noise of a
period's Fourier coefficient is circular, so its powers average to zero and the mean of 1 / (Z_r + n) is 1 / Z_r
while |n| < |Z_r|; at a relative scatter s a period's noise exceeds the divisor with probability exp(-1 / s^2)
(1e-7 at a quarter), and beyond that the ratios' mean is biased more than their spread shows. Above it the points
end ``divisor_limited``."""

MIN_SCATTER_PERIODS = 8
"""The fewest settled periods (the later half of those after the skipped ones) the divisor's scatter is taken over;
a shorter point's is taken over every period after the skipped ones, too few to tell a transient from noise."""

MAX_COEFFICIENT = 1e100
"""Largest coefficient a period may have (output units): beyond any sensor's range in any unit, and far enough below
the float range that the rules' squares and sums cannot overflow. A larger one is garbage, discarded as a
non-finite one is."""


@dataclass(frozen=True)
class SeriesState:
    """Where one series stands after the latest period (for progress displays).

    estimate: the rule's current coefficient estimate P + jQ (output units);
    uncertainty: its confidence half-width (NaN until the rule can tell);
    tolerance: the tolerance the rule stops at (output units, NaN until known);
    stop_width: what the rule compares with the tolerance to stop (output units; the uncertainty for most rules, the
    default rule's noise disc at 98 % plus its transient bound; NaN until known).
    """

    channel: str
    harmonic: int
    periods: int
    estimate: complex
    uncertainty: float
    verdict: Verdict | None
    tolerance: float = math.nan
    stop_width: float = math.nan


def _joined(record: list[np.ndarray]) -> np.ndarray:
    """The arrays of ``record`` (period first) joined into one, which then stands for them in ``record``."""
    if len(record) > 1:
        record[:] = [np.concatenate(record)]
    return record[0]


def _later_half(rows: np.ndarray, periods: int) -> np.ndarray:
    """The later half of the first ``periods`` of ``rows`` (period first; of all of them where it holds fewer)."""
    kept = min(periods, rows.shape[0])
    return rows[kept // 2: kept]


class Autointegrator:
    """Integrates period after period until every series' rule stops or ``max_periods`` is reached.

    frequency_hz: excitation frequency f (Hz); amplitude: input amplitude A_i
    (input units), for gains; channels: names of the measured columns fed;
    t0: instant (s) at which the excitation sine has phase zero.

    reference: two-channel mode. One more column (fed last) carries the input
    as the drive saw it (e.g. the echoed setpoint). Every period, each output
    coefficient is taken relative to that period's reference fundamental
    ``Z_r``: ``Z_k * A_i * (conj(Z_r)/|Z_r|)**k / |Z_r|``, so gain and phase
    are output over input whatever delay or amplitude error the path to the
    drive added, and the rules judge that ratio. reference_phase (rad): the phase the reference's fundamental has
    on an ideal bench, put back on every coefficient (harmonic k turned by k times it); the drive's echo of the
    setpoint of control period c - 1, dated c h, has -2 pi f h, and with it the ratio reads as a single-channel
    measurement dated on the drive's own clock (drivers/PROTOCOL.md section 7).

    check_gaps: discard the periods gaps in the samples touch (False takes every period whose samples resolve the
    harmonics, gaps bridged by straight lines).
    grid_steps_per_period: the samples of a computation, on a uniform grid of this many steps per period that t0
    lies on (:class:`~bodebench.core.fourier.GridPeriodIntegrator`: the same coefficients as a matrix product per
    chunk; a grid has no gaps); 0: samples at any times, as a bench delivers them
    (:class:`~bodebench.core.fourier.ExactPeriodIntegrator`: exact for a constant plus the harmonics up to the
    highest integrated, whatever the grid).

    samples_per_period: the bench's sample rate over f (0: unknown). With it, the integrator also solves the
    harmonics above the measured ones up to :func:`~bodebench.core.benchgrid.alias_fit_order` (so they leak into
    none of the measured ones on any grid), and with ``fold_policy == "bound"`` each point's interval carries the
    bound :func:`~bodebench.core.benchgrid.fold_bound` puts on what the rate folds onto it from higher up: a series
    the bound pushes past its tolerance goes on while more periods can make room for it, and ends ``alias_limited``
    where they cannot.

    disturbance_lines: on a bench, the frequencies of the disturbance lines (Hz; mains and its harmonics). A line
    nearest a whole harmonic j of f above the measured ones leaks into each measured harmonic k about
    ``h sin(pi delta) / (pi |d/f - k|)`` a period (h its amplitude, delta = d/f - j), turning delta cycles a period:
    until it has turned a couple of times over the n periods averaged (n |delta| small) that leak is nearly the same
    every period and no spread shows it. Its amplitude is read from the record: beyond the solved harmonics, from
    what each period's solved harmonics leave at d (:class:`~bodebench.core.fourier.ExactPeriodIntegrator`); nearest
    a solved harmonic j, measured or not, from how j's coefficient turns
    (:func:`~bodebench.core.benchgrid.turning_amplitude`; a measured j's own point is ``flag_disturbed``'s). The leak
    is bounded by :func:`~bodebench.core.benchgrid.line_leak` and added to the interval like the fold bound; a series
    whose verdict it pushes past its tolerance is judged again with each period while the line turns, and ends
    ``disturbed`` where the periods run out first. In two-channel mode the lines on the reference column are read the
    same way, and what they leak into its fundamental, the divisor, moves every ratio by its share of it; unless
    ``reference_lines`` is False: a reference that carries no line (the drive's echo of its setpoint, a number) would
    only have its noise read as one, near the fundamental at a cost of many periods.

    periods: whole periods integrated; discarded: periods a gap in the samples touched, up to the period at which
    the rules stopped (see the module docstring); discard_limit: the most of them the point may discard before it
    fails whatever comes; failure: why the point is not a measurement ("" while it is).
    """

    def __init__(self, frequency_hz: float, amplitude: float, channels: Sequence[str],
                 analysis: AnalysisSettings, t0: float = 0.0, reference: str | None = None,
                 check_gaps: bool = True, grid_steps_per_period: int = 0, reference_phase: float = 0.0,
                 samples_per_period: float = 0.0, disturbance_lines: Sequence[float] = (),
                 reference_lines: bool = True) -> None:
        self.frequency_hz = frequency_hz
        self.amplitude = amplitude
        self.channels = tuple(channels)
        self.harmonics = tuple(analysis.harmonics)
        self.max_periods = period_budget(analysis, frequency_hz, on_bench=not grid_steps_per_period)
        """The periods this point may integrate (:func:`period_budget`)."""
        self.skip_periods = analysis.skip_periods
        self.tolerance_percent = analysis.tolerance_percent
        """The tolerance every point of this frequency is measured to, percent."""
        self.reference = reference
        self.reference_phase = reference_phase
        harmonics = self.harmonics if reference is None or 1 in self.harmonics else (*self.harmonics, 1)
        self._ref_index = harmonics.index(1) if reference is not None else -1
        self.max_gap_periods = analysis.max_gap_cycles / max(harmonics)
        """Longest interval between two samples a whole period may contain, in periods of f."""
        self.max_discarded_percent = analysis.max_discarded_percent
        self.discard_limit = discard_limit(self.max_periods, self.max_discarded_percent)
        """The most periods this point may discard for gaps before it fails whatever comes (:func:`discard_limit` of
        the period budget): one more fails it at once."""
        columns = len(self.channels) + (reference is not None)
        fit_order = alias_fit_order(samples_per_period, max(harmonics))
        self.standing_lines: tuple[float, ...] = () if grid_steps_per_period else \
            lines_beyond_fit(disturbance_lines, frequency_hz, samples_per_period, max(max(harmonics), fit_order))
        """The disturbance lines (Hz, as the samples see them) nearest a whole harmonic above the solved ones, whose
        leak :func:`~bodebench.core.benchgrid.line_leak` bounds."""
        self.turning_lines: tuple[float, ...] = () if grid_steps_per_period else \
            lines_on_fit(disturbance_lines, frequency_hz, samples_per_period, self.harmonics, fit_order)
        """The disturbance lines (Hz, as the samples see them) nearest a whole harmonic each period is solved for but
        not measured (in two-channel mode the fundamental, solved for the divisor, where it is not measured), whose
        leak :func:`~bodebench.core.benchgrid.line_leak` bounds with the amplitude
        :func:`~bodebench.core.benchgrid.turning_amplitude` reads from that harmonic's coefficients."""
        self.measured_lines: tuple[float, ...] = () if grid_steps_per_period else \
            lines_on_harmonics(disturbance_lines, frequency_hz, samples_per_period, self.harmonics)
        """The disturbance lines (Hz, as the samples see them) nearest a measured harmonic, whose leak into the other
        measured harmonics :func:`~bodebench.core.benchgrid.line_leak` bounds with the amplitude
        :func:`~bodebench.core.benchgrid.turning_amplitude` reads from that harmonic's own coefficients."""
        self._integrator = (
            GridPeriodIntegrator(frequency_hz, harmonics, columns, grid_steps_per_period, t0)
            if grid_steps_per_period else
            ExactPeriodIntegrator(frequency_hz, harmonics, columns, t0,
                                  max_gap=self.max_gap_periods if check_gaps else math.inf,
                                  fit_order=fit_order, lines_hz=self.standing_lines))
        self.samples_per_period = samples_per_period
        # what each period's solve on the bench's grid lets through of a unit standing line into each solved harmonic
        # (harmonic -> (line,)): more than the continuous-time leak on a coarse grid
        gains = line_gains(frequency_hz, harmonics, fit_order, samples_per_period, self.standing_lines)
        self._line_gains = {k: gains[i] for i, k in enumerate(harmonics)}
        # the standing lines the sample rate folds (Hz, as the samples see them): above half the rate, a line's
        # turning against the period and the grid's own slip combine, and the folded view's turns say nothing of
        # whether the spread shows its leak
        rate = samples_per_period * frequency_hz
        self._folded_lines = {seen_at(d, rate) for d in disturbance_lines if 0 < rate < 2.0 * d}
        self.fold_decay = analysis.fold_decay
        """The power j**-d the output's harmonics are taken to fall at least as fast as in the tail the averaged
        waveform shows (harmonics N/4 to N/2 on a whole grid); the bound from the solved harmonics, up to 8, which
        need not be in the tail yet, extends them as j**-2."""
        # each whole period's coefficients of the harmonics solved but not measured (_unmeasured_orders: in
        # two-channel mode the fundamental where it is solved only for the divisor, then the integrator's
        # unmeasured_harmonics), (channel, harmonic), while a rule is open
        self._unmeasured: list[np.ndarray] = []
        unmeasured: tuple[int, ...] = getattr(self._integrator, "unmeasured_harmonics", ())
        self._divisor_only = reference is not None and 1 not in self.harmonics
        self._unmeasured_orders: tuple[int, ...] = (1,) * self._divisor_only + unmeasured
        # two-channel mode: each whole period's reference coefficients at the harmonic nearest each turning and
        # measured line, then its residual at each standing line, then its fundamental (input units), while a rule
        # is open: a line on the reference moves the divisor of every ratio
        self._reference_rows: list[np.ndarray] = []
        self._reference_leak_at = (-1, 0.0)  # (periods, _reference_leak of them) last computed
        self._reference_lines = reference is not None and reference_lines and not grid_steps_per_period and bool(
            self.turning_lines or self.measured_lines or self.standing_lines)
        solved = (*harmonics, *unmeasured)
        self._reference_columns = [solved.index(round(d / frequency_hz))
                                   for d in (*self.turning_lines, *self.measured_lines)]
        # each whole period's residual at each standing line, (channel, line), while a rule is open
        self._lines: list[np.ndarray] = []
        self._high_count = len(getattr(self._integrator, "high_harmonics", ())) \
            if analysis.fold_policy == "bound" else 0
        self._keep_unmeasured = bool(self._high_count or self.turning_lines)
        # whether a converged series can carry a systematic bound (a fold, a line's leak) to be checked against
        self._systematic = bool(self._high_count or self.standing_lines or self.turning_lines or self.measured_lines)
        # on a grid of a whole number of samples a period, the waveform averaged phase by phase, for a closer bound
        self._phase = PhaseAverage(frequency_hz, t0, samples_per_period, columns, self.max_periods) \
            if self._high_count and grid_stands_still(samples_per_period, max(harmonics)) else None
        self._histories = [[SeriesHistory() for _ in self.harmonics] for _ in self.channels]
        self._series = [hist for row in self._histories for hist in row]  # channel by channel, harmonic by harmonic
        self._rules: list[list[StoppingRule]] = [
            [make_rule(analysis.criterion, tolerance_percent=analysis.tolerance_percent,
                       skip_periods=analysis.skip_periods, window=analysis.window,
                       settle_periods=analysis.settle_periods, average_periods=analysis.average_periods,
                       max_periods=self.max_periods)
             for _ in self.harmonics] for _ in self.channels]
        self._verdicts: list[list[Verdict | None]] = [[None] * len(self.harmonics) for _ in self.channels]
        self._pending = len(self.channels) * len(self.harmonics)  # series still without a verdict
        self.periods = 0
        self.discarded = 0
        self.failure = ""
        # the first harmonic (else the first listed) leads: the others are judged only once it has settled,
        # so a small harmonic cannot stop on the calm before the transient of its channel has died out
        self._primary = self.harmonics.index(1) if 1 in self.harmonics else 0
        self._order = [self._primary] + [k for k in range(len(self.harmonics)) if k != self._primary]
        self._led = [False] * len(self.channels)  # each channel's leading series has had a verdict (it settled)
        self._last_scales: list[float] = [math.nan] * len(self.channels)
        # the drift the bench's integrator took off, summed (channel units per period) over the whole periods it
        # returned while a rule was still open, and their count
        self._drift_sum = np.zeros(len(self.channels))
        self._drift_periods = 0
        # two-channel mode: the reference fundamental of each period integrated, for the divisor's scatter
        self._divisors: list[np.ndarray] = []

    @property
    def done(self) -> bool:
        """True once every series has a verdict, or the point has failed."""
        return self._pending == 0 or bool(self.failure)

    def _judge_gaps(self, whole: int) -> None:
        """Fail the point when more than ``max_discarded_percent`` of the periods it spans were discarded: of the
        periods spanned after ``whole`` whole ones once the rules have stopped, else of the most it may span before
        that is judged (``max_periods``, or the periods spanned once they reach it)."""
        spanned = whole + self.discarded
        of = spanned if self._pending == 0 else max(spanned, self.max_periods)
        if spanned and too_many_discarded(self.discarded, of, self.max_discarded_percent):
            budget = f" of the {of} periods the point may span" if of != spanned else ""
            self.failure = (
                f"{self.frequency_hz:g} Hz: {self.discarded} of {spanned} periods discarded for gaps in the samples "
                f"longer than {self.max_gap_periods / self.frequency_hz * 1e3:.3g} ms ({self.max_gap_periods:.3g} "
                f"of a period), more than max_discarded_percent = {self.max_discarded_percent:g} %{budget}")

    def feed(self, t: np.ndarray, y: np.ndarray) -> int:
        """Take samples (t in s, increasing; y shaped (n, channels)); returns the whole periods completed."""
        if self._phase is not None and not self.done:
            sane = (np.abs(y) <= MAX_COEFFICIENT).all(axis=1)  # False for inf and NaN too
            if sane.all():
                self._phase.add(t, y)
            else:
                self._phase.add(t[sane], y[sane])
        p, q, whole = self._integrator.feed_marked(t, y)
        m = p.shape[0]
        if m == 0:
            return 0
        usable = None  # the periods the histories take, where already known
        if isinstance(self._integrator, ExactPeriodIntegrator) and not self.done:
            drift = self._integrator.drift[whole, : len(self.channels)]
            self._drift_sum += drift.sum(axis=0)
            self._drift_periods += drift.shape[0]
            if self._keep_unmeasured or self.standing_lines or self._reference_lines:
                usable = self._usable(p, q)
                kept = whole & usable  # the periods the histories take, so that the records align
                if self._keep_unmeasured:
                    self._take_unmeasured(self._integrator.unmeasured, p, q, kept)
                if self.standing_lines:
                    self._take_lines(self._integrator.lines, p, q, kept)
                if self._reference_lines:
                    self._take_reference(self._integrator, p, q, kept)
        if m <= _FEW_PERIODS and self.reference is None and all(whole.tolist()):
            values = list(map(complex, p.ravel().tolist(), q.ravel().tolist()))
            sizes = list(map(abs, values))
            if max(sizes) <= MAX_COEFFICIENT:  # False for inf and NaN too
                if self.done:
                    self.periods += m
                else:
                    self._take(values, sizes)
                return m
        whole &= self._usable(p, q) if usable is None else usable
        if not whole.all():
            if self.done:
                p, q = p[whole], q[whole]
            else:
                return self._feed_with_gaps(p, q, whole)
        m = p.shape[0]
        if m == 0 or self.done:
            self.periods += m
            return m
        self._integrate(p, q)
        return m

    def _take_unmeasured(self, unmeasured: np.ndarray, p: np.ndarray, q: np.ndarray, whole: np.ndarray) -> None:
        """Keep the whole periods' coefficients of the harmonics solved but not measured (unmeasured: (m, columns,
        n)); in two-channel mode relative to each period's reference fundamental, as the measured ones, after the
        outputs' fundamental where it is solved only for the divisor (``_unmeasured_orders``)."""
        z = unmeasured[:, : len(self.channels)]
        if self.reference is not None:
            if self._divisor_only:
                z = np.concatenate((p[:, : len(self.channels), self._ref_index, None]
                                    + 1j * q[:, : len(self.channels), self._ref_index, None], z), axis=2)
            with np.errstate(all="ignore"):
                z = self._relative_to_reference(z, p[:, -1, self._ref_index] + 1j * q[:, -1, self._ref_index],
                                                self._unmeasured_orders)
        keep = whole & np.isfinite(z).all(axis=(1, 2)) & (np.abs(z) <= MAX_COEFFICIENT).all(axis=(1, 2))
        if keep.any():
            self._unmeasured.append(z[keep])

    def _take_lines(self, lines: np.ndarray, p: np.ndarray, q: np.ndarray, whole: np.ndarray) -> None:
        """Keep the whole periods' residuals at the standing lines (lines: (m, columns, line)); in two-channel mode
        scaled by each period's reference fundamental, as the measured coefficients."""
        z = lines[:, : len(self.channels)]
        if self.reference is not None:
            with np.errstate(all="ignore"):
                z = z * (self.amplitude / np.abs(p[:, -1, self._ref_index] + 1j * q[:, -1, self._ref_index]))[
                    :, None, None]
        keep = whole & np.isfinite(z).all(axis=(1, 2))
        if keep.any():
            self._lines.append(z[keep])

    def _take_reference(self, integrator: ExactPeriodIntegrator, p: np.ndarray, q: np.ndarray, whole: np.ndarray
                        ) -> None:
        """Keep the whole periods' reference coefficients (input units) at the harmonic nearest each turning and
        measured line, its residuals at the standing lines and its fundamental (``_reference_rows``)."""
        solved = np.concatenate((p[:, -1] + 1j * q[:, -1], integrator.unmeasured[:, -1]), axis=1)
        rows = np.concatenate((solved[:, self._reference_columns], integrator.lines[:, -1],
                               solved[:, self._ref_index, None]), axis=1)
        keep = whole & np.isfinite(rows).all(axis=1)
        if keep.any():
            self._reference_rows.append(rows[keep])

    def _reference_leak(self, periods: int) -> float:
        """Two-channel mode: the bound :func:`~bodebench.core.benchgrid.line_leak` puts on what the lines on the
        reference column leak into its fundamental over the fewest periods a rule averages, relative to that
        fundamental (0 without a line or a reference). Each line's amplitude is read as on an output: from how the
        reference's solved harmonic nearest it turns, or from its residual at a standing line."""
        if not self._reference_lines or not self._reference_rows:
            return 0.0
        if self._reference_leak_at[0] == periods:  # the same for every series judged at this period
            return self._reference_leak_at[1]
        rows = _later_half(_joined(self._reference_rows), periods)
        if rows.shape[0] < 2:
            return 0.0
        averaged = max(1, (periods - self.skip_periods) // 2)
        f = self.frequency_hz
        turning = (*self.turning_lines, *self.measured_lines)
        leak = sum(line_leak(turning_amplitude(rows[:, i], d / f), d / f, 1, averaged)
                   for i, d in enumerate(turning))
        residuals = rows[:, len(turning): len(turning) + len(self.standing_lines)]
        leak += self._standing_leak(self._line_amplitudes(residuals), 1, averaged)
        divisor = abs(complex(rows[:, -1].mean()))
        self._reference_leak_at = (periods, leak / divisor if divisor else math.inf)
        return self._reference_leak_at[1]

    def _line_amplitudes(self, residuals: np.ndarray) -> list[float]:
        """Each standing line's amplitude from W periods' residuals at it ((period, line), units times seconds):
        ``2 f |sum| / W``."""
        return (2.0 * self.frequency_hz * np.abs(residuals.sum(axis=0)) / residuals.shape[0]).tolist()

    def _standing_leak(self, amplitudes: Sequence[float], harmonic: int, averaged: int) -> float:
        """What the standing lines of ``amplitudes`` leak into the mean of ``averaged`` periods of ``harmonic``: the
        larger of :func:`~bodebench.core.benchgrid.line_leak` and, until the line has turned
        :data:`~bodebench.core.benchgrid.LINE_TURNS` times (for a line the rate folds, always), its amplitude times
        the most one period's solve on the bench's grid lets through (``line_gains``; standing still, such a leak is
        the same every period)."""
        leak = 0.0
        gains = self._line_gains[harmonic]
        for h, d, gain in zip(amplitudes, self.standing_lines, gains.tolist(), strict=True):
            x = d / self.frequency_hz
            grid = h * gain if averaged * abs(x - round(x)) < LINE_TURNS or d in self._folded_lines else 0.0
            leak += max(line_leak(h, x, harmonic, averaged), grid)
        return leak

    def line_leaks(self) -> np.ndarray:
        """(channels, harmonics) the bound :func:`~bodebench.core.benchgrid.line_leak` puts on what the disturbance
        lines leak into each series over the periods it keeps (output units; 0 where no line stands)."""
        out = np.zeros((len(self.channels), len(self.harmonics)))
        for c, verdicts in enumerate(self._verdicts):
            for k, verdict in enumerate(verdicts):
                out[c, k] = self._line_leak(c, k, verdict.period if verdict is not None else self.periods)
        return out

    def _line_leak(self, c: int, k: int, periods: int) -> float:
        """The leak bound on series (channel c, harmonic index k) after ``periods`` periods, each line's amplitude
        read over the later half of them: a standing line's from its residual, a turning line's from how the
        solved harmonic nearest it turns. The bound is the one on a mean of the fewest periods a rule's value
        averages: the later half of those after the skipped ones (the default rule's settled mean takes the last
        half or three quarters)."""
        leak = 0.0
        averaged = max(1, (periods - self.skip_periods) // 2)
        if self._lines:
            rows = _joined(self._lines)
            if min(periods, rows.shape[0]) >= 2:
                amplitudes = self._line_amplitudes(_later_half(rows, periods)[:, c])
                leak += self._standing_leak(amplitudes, self.harmonics[k], averaged)
        for x, coefficients in self._turning(c, k, periods):
            leak += line_leak(turning_amplitude(coefficients, x), x, self.harmonics[k], averaged)
        relative = self._reference_leak(periods)
        if relative:  # the divisor Z_r off by a fraction r moves |Z_k| by r and its phase by k r (rad): sqrt(1 + k^2) r
            ratio = abs(complex(_later_half(self._histories[c][k].values, periods).mean()))
            leak += ratio * math.hypot(1.0, self.harmonics[k]) * relative
        return leak

    def _turning(self, c: int, k: int, periods: int) -> Iterator[tuple[float, np.ndarray]]:
        """Each line a solved harmonic of channel c takes in (x: its frequency in harmonics of f), with that
        harmonic's coefficients over the later half of ``periods`` periods: the unmeasured one's nearest each turning
        line, the measured one's nearest each measured line other than series k's own (there the line is
        ``flag_disturbed``'s)."""
        if self.turning_lines and self._unmeasured:
            window = _later_half(_joined(self._unmeasured), periods)[:, c]
            orders = self._unmeasured_orders
            for d in self.turning_lines:
                x = d / self.frequency_hz
                yield x, window[:, orders.index(round(x))]
        for d in self.measured_lines:
            x = d / self.frequency_hz
            on = self.harmonics.index(round(x))
            if on != k:
                yield x, _later_half(self._histories[c][on].values, periods)

    def fold_bounds(self) -> np.ndarray:
        """(channels, harmonics) the bound :func:`~bodebench.core.benchgrid.fold_bound` puts on what the sample rate
        folds onto each series and its periods keep (output units; 0 where the record gives none)."""
        out = np.zeros((len(self.channels), len(self.harmonics)))
        for c, verdicts in enumerate(self._verdicts):
            for k, verdict in enumerate(verdicts):
                out[c, k] = self._fold(c, k, verdict.period if verdict is not None else self.periods)[0]
        return out

    def _fold(self, c: int, k: int, periods: int) -> tuple[float, bool]:
        """The fold bound on series (channel c, harmonic index k) after ``periods`` periods, and whether the content
        above the measured harmonics it is read from has settled. That content is the mean of the last quarter of
        the periods, after most of a transient (what is left of one counts as content); it has settled when that
        mean differs from the previous quarter's by less than half its size. On a whole grid, where the waveform
        averaged phase by phase shows the spectrum up to half the sample rate, its
        :func:`~bodebench.core.phase_average.waveform_fold_bound` instead: the solved harmonics alone cannot tell
        an output whose spectrum falls as 1/j (a relay, a quantiser's steps) from one that falls as 1/j^2."""
        if not self._high_count or not self._unmeasured:
            return 0.0, True
        unmeasured = _joined(self._unmeasured)
        high = unmeasured[:, :, unmeasured.shape[2] - self._high_count:]  # (period, channel, harmonic above)
        periods = min(periods, high.shape[0])
        quarter = periods // 4
        if quarter < 2:
            return 0.0, True
        last = high[periods - quarter: periods, c].mean(axis=0)
        before = high[periods - 2 * quarter: periods - quarter, c].mean(axis=0)
        settled = bool(np.max(np.abs(last - before)) <= 0.5 * np.max(np.abs(last)))
        waveform = self._phase.recent(periods) if self._phase is not None else None
        if waveform is not None:
            scale = 1.0
            if self.reference is not None:  # relative to the reference fundamental, as the measured coefficients
                scale = self.amplitude / abs(2.0 * np.fft.rfft(waveform[:, -1])[1] / waveform.shape[0])
            bound = scale * waveform_fold_bound(waveform[:, c], self.harmonics, self.samples_per_period,
                                                self.harmonics[k], periods, self.fold_decay)
            if math.isfinite(bound):
                return bound, settled
        orders = self._integrator.high_harmonics  # type: ignore[union-attr]
        return fold_bound(last, orders, self.samples_per_period, self.harmonics[k], periods), settled  # 1/j^2

    def _reopen_for_folds(self, n: int, scales: list[float]) -> None:
        """Every series converged at period n whose fold bound and line leak push it past its tolerance, where more
        periods can help: the bounds alone are within the tolerance (the interval has to shrink to make room for
        them), the content above the measured harmonics is still fading (a transient, not a fold), or a line leaks
        and the fold bound alone leaves room (the leak falls as the line turns). Reopened, to be judged again with
        the next period, until it fits, the fold bound alone exceeds the tolerance with that content settled (it ends
        ``alias_limited``), or the period budget ends."""
        if n >= self.max_periods:
            return
        for c, verdicts in enumerate(self._verdicts):
            for k, v in enumerate(verdicts):
                if v is None or not v.converged or v.period != n:
                    continue
                bound, settled = self._fold(c, k, n)
                leak = self._line_leak(c, k, n)
                if not bound and not leak:
                    continue
                tolerance = self._rules[c][k].tolerance(complex(v.p, v.q), scales[c])
                # a line's leak fades as it turns with more periods, unless the fold alone already leaves no room
                fading = leak and bound < tolerance
                if not self._fits(v, bound + leak, tolerance) and (bound + leak < tolerance or not settled or fading):
                    verdicts[k] = None
                    self._pending += 1

    @staticmethod
    def _fits(verdict: Verdict, fold: float, tolerance: float) -> bool:
        """Whether a converged verdict's interval with the fold bound added still fits its tolerance."""
        return verdict.uncertainty + fold <= tolerance

    def _usable(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(m,) periods with coefficients within MAX_COEFFICIENT whose reference fundamental, in two-channel mode,
        shows the sine (at least RESOLUTION of the amplitude: the others would divide by nothing); the rest are
        discarded."""
        with np.errstate(invalid="ignore"):
            ok = (np.abs(p) <= MAX_COEFFICIENT).all(axis=(1, 2)) & (np.abs(q) <= MAX_COEFFICIENT).all(axis=(1, 2))
        if self.reference is not None:
            ok &= np.hypot(p[:, -1, self._ref_index], q[:, -1, self._ref_index]) >= RESOLUTION * self.amplitude
        return ok

    def _feed_with_gaps(self, p: np.ndarray, q: np.ndarray, whole: np.ndarray) -> int:
        """Periods some of which a gap touched: each run of whole periods integrated, each discarded one counted
        (until the rules stop) and judged (``_judge_gaps``: against the period budget until the periods spanned
        reach it)."""
        m = int(whole.sum())
        edges = np.flatnonzero(np.diff(whole.astype(np.int8))) + 1
        for run in np.split(np.arange(whole.size), edges):
            if self.done:
                if whole[run[0]]:
                    self.periods += run.size
                continue
            if whole[run[0]]:
                self._integrate(p[run], q[run])
            else:
                for _ in run:
                    self.discarded += 1
                    self._judge_gaps(self.periods)
                    if self.failure:
                        break
        return m

    def _integrate(self, p: np.ndarray, q: np.ndarray) -> None:
        """Whole periods' coefficients (m, channel, harmonic) into the histories and the rules."""
        m = p.shape[0]
        z = p + 1j * q  # (m, channel, harmonic)
        if self.reference is not None:
            divisor = z[:, -1, self._ref_index]
            self._divisors.append(divisor)
            z = self._relative_to_reference(z[:, :-1, : len(self.harmonics)], divisor, self.harmonics)
        if m <= _FEW_PERIODS:
            values = z.ravel().tolist()
            self._take(values, list(map(abs, values)))
            return
        for c, row in enumerate(self._histories):
            for k, hist in enumerate(row):
                hist.extend(z[:, c, k])
        # each channel's scale: its largest coefficient of the period (output units)
        self._judge(m, np.max(np.abs(z), axis=2).tolist())

    def _relative_to_reference(self, z: np.ndarray, z_ref: np.ndarray, harmonics: Sequence[int]) -> np.ndarray:
        """Output coefficients z (m, channel, harmonic) of ``harmonics`` relative to each period's reference
        fundamental z_ref (m,): ``Z_k * A_i * (conj(Z_r)/|Z_r|)**k / |Z_r|``, turned by k times ``reference_phase``
        (see the class docstring)."""
        powers = np.asarray(harmonics)
        z = z * (self.amplitude / np.abs(z_ref))[:, None, None] \
            * (np.conj(z_ref) / np.abs(z_ref))[:, None, None] ** powers[None, None, :]
        if self.reference_phase:
            z = z * np.exp(1j * self.reference_phase * powers)[None, None, :]
        return z

    def _take(self, values: list[complex], sizes: list[float]) -> None:
        """A few whole periods' coefficients (output units), period by period, channel by channel, harmonic by
        harmonic, and their sizes |Z|, into the histories and the rules, on Python scalars (numpy's cost per call
        exceeds the arithmetic)."""
        series = self._series
        count, harmonics = len(series), len(self.harmonics)
        scales = []
        for start in range(0, len(values), count):
            for hist, v in zip(series, values[start:start + count], strict=True):
                hist.append(v)
            # each channel's scale: its largest coefficient of the period
            scales.append([max(sizes[first:first + harmonics]) for first in range(start, start + count, harmonics)])
        self._judge(len(scales), scales)

    def _judge(self, m: int, scales: list[list[float]]) -> None:
        """The rules' verdicts on the m periods just appended to the histories; scales: each period's scale of each
        channel, its largest coefficient (output units)."""
        self._last_scales = scales[-1]
        primary, order, max_periods = self._primary, self._order, self.max_periods
        led = self._led
        for i in range(m):
            n = self.periods + i + 1
            converged = False
            for c, verdicts in enumerate(self._verdicts):
                channel_scale = scales[i][c]
                rules, histories = self._rules[c], self._histories[c]
                for k in order:
                    if verdicts[k] is not None or (k != primary and not led[c]):
                        continue
                    verdict = rules[k].check(histories[k], n, channel_scale)
                    if verdict is None and n >= max_periods:
                        verdict = rules[k].capped(histories[k], n, channel_scale)
                    if verdict is not None:
                        verdicts[k] = verdict
                        self._pending -= 1
                        led[c] = True
                        converged = converged or verdict.converged
            if converged and self._systematic:
                self._reopen_for_folds(n, scales[i])
            if self.discarded and (self._pending == 0 or n + self.discarded >= max_periods):
                self._judge_gaps(n)
            if self.done:
                break
        self.periods += m

    def end_of_record(self) -> None:
        """The samples ended before every series had a verdict (a record analysed again with a rule that wants more
        periods): each series still open is capped at the last whole period, as at ``max_periods``."""
        for c, verdicts in enumerate(self._verdicts):
            for k in self._order:
                if verdicts[k] is None:
                    hist = self._histories[c][k]
                    if hist.n == 0:
                        raise ValueError(f"the record of {self.frequency_hz:g} Hz holds no whole period")
                    verdicts[k] = self._rules[c][k].capped(hist, hist.n, self._last_scales[c])
                    self._pending -= 1

    def states(self) -> list[SeriesState]:
        """Progress of every series at the latest period."""
        out = []
        for c, name in enumerate(self.channels):
            for k, harmonic in enumerate(self.harmonics):
                verdict = self._verdicts[c][k]
                hist = self._histories[c][k]
                if verdict is not None:
                    est, unc, n = complex(verdict.p, verdict.q), verdict.uncertainty, verdict.period
                    width = unc
                elif hist.n:
                    est, unc, width = self._rules[c][k].progress(hist, hist.n)
                    n = hist.n
                else:
                    est, unc, width, n = complex("nan"), math.nan, math.nan, 0
                scale = self._last_scales[c]
                tol = self._rules[c][k].tolerance(est, scale) if n and math.isfinite(scale) else math.nan
                out.append(SeriesState(name, harmonic, n, est, unc, verdict, tol, width))
        return out

    def history(self, channel: str, harmonic: int) -> np.ndarray:
        """Per-period coefficients P(i) + jQ(i) of one series so far."""
        return self._histories[self.channels.index(channel)][self.harmonics.index(harmonic)].values

    def divisor_scatter(self) -> float:
        """Two-channel mode: the spread of the reference fundamental from period to period relative to its mean (the
        standard deviation of the complex coefficient over its size), over the periods a coherence is taken over
        (:func:`~bodebench.core.quality.coherence_periods`: the later half of those after the skipped ones, where
        a transient has gone), or over every period after the skipped ones where that half holds fewer than
        :data:`MIN_SCATTER_PERIODS` (every period where fewer than two are left after the skip);
        inf where the divisor's mean is zero and it is not; NaN without a reference or a period."""
        if len(self._divisors) > 1:
            self._divisors = [np.concatenate(self._divisors)]
        if not self._divisors or not self._divisors[0].size:
            return math.nan
        divisors = self._divisors[0]
        start, stop = coherence_periods(self.skip_periods, len(divisors))
        if stop - start < MIN_SCATTER_PERIODS:
            start = self.skip_periods if stop - self.skip_periods >= MIN_COHERENCE_PERIODS else 0
        settled = divisors[start:stop]
        mean = complex(settled.mean())
        spread = float(np.sqrt(np.mean(np.abs(settled - mean) ** 2)))
        if not mean:
            return math.inf if spread else math.nan
        return spread / abs(mean)

    def points(self) -> list[ResponsePoint]:
        """The measured points, one per series (requires ``done``); ValueError saying why for a failed point."""
        if not self.done:
            raise RuntimeError("Autointegrator.points() before every series has a verdict")
        if self.failure:
            raise GapsError(self.failure)
        pts = []
        folds = self.fold_bounds()
        leaks = self.line_leaks()
        drift = self._drift_sum / self._drift_periods * self.frequency_hz if self._drift_periods else \
            np.full(len(self.channels), math.nan)
        noisy_divisor = self.divisor_scatter() > MAX_DIVISOR_SCATTER
        for c, name in enumerate(self.channels):
            verdicts = self._verdicts[c]
            thd = math.nan
            if 1 in self.harmonics:
                fundamental = verdicts[self.harmonics.index(1)]
                assert fundamental is not None
                thd = total_harmonic_distortion(complex(fundamental.p, fundamental.q),
                                                [complex(v.p, v.q) for k, v in zip(self.harmonics, verdicts,
                                                                                   strict=True)
                                                 if k != 1 and v is not None])
            for k, harmonic in enumerate(self.harmonics):
                v = verdicts[k]
                assert v is not None
                start, stop = coherence_periods(self.skip_periods, v.period)
                converged, status, within_eps = v.converged, v.status, v.within_eps
                fold, leak = float(folds[c, k]), float(leaks[c, k])
                systematic = fold + leak
                if systematic and converged and not self._fits(
                        v, systematic, self._rules[c][k].tolerance(complex(v.p, v.q), self._last_scales[c])):
                    converged, within_eps = False, False
                    status = PointStatus.DISTURBED if leak > fold else PointStatus.ALIAS_LIMITED
                if noisy_divisor:
                    converged, status, within_eps = False, PointStatus.DIVISOR_LIMITED, False
                pts.append(ResponsePoint(frequency_hz=self.frequency_hz, harmonic=harmonic, channel=name,
                                         amplitude=self.amplitude, p=v.p, q=v.q, periods=v.period,
                                         converged=converged, status=status, uncertainty=v.uncertainty + systematic,
                                         uncertainty_1d=v.uncertainty_1d + systematic, within_eps=within_eps,
                                         periods_needed=v.periods_needed, periods_discarded=self.discarded,
                                         thd=thd if harmonic == 1 else math.nan,
                                         coherence=coherence(self._histories[c][k].values[start:stop]),
                                         drift_per_s=float(drift[c]), tolerance_percent=self.tolerance_percent))
        return pts
