"""How long a sweep still takes: the periods each point still needs times the bench's seconds per period.

The current point's periods to go come from its stopping rule's own progress (each open series' width its stop
compares, ``SeriesState.stop_width``, against its tolerance, extrapolated on a power law); a point not yet
started is predicted from the periods the measured points took (this session's and those already on disk
from an interrupted sweep), interpolated in log frequency. Seconds per point are fitted as
``overhead + ratio * (periods + ramp and settle periods) / f`` on the points this session finished, so the
prediction holds for a real-time bench (ratio about 1) as for a simulation running faster than real time.
Time spent paused counts for nothing.

Pure: numbers and caller-supplied monotonic times (s) in, seconds out (no clock, no threads, no I/O).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from bodebench.core.autointegration import SeriesState

FIT_DECADE = 10.0
"""The power law is fitted on the series' last decade of periods (n >= n_last / FIT_DECADE)."""
MAX_LOG_GROWTH = 30.0
"""A power law that reaches the tolerance only beyond e**30 times the periods so far tells nothing."""
NEAREST = 3
"""Measured points whose median predicts a frequency beyond them."""
STEADY_SLOPE = -0.5
"""The slowest a confidence half-width falls with the periods averaged once the periods are steady (noise alone:
n**-1/2); a shallower fitted slope is extrapolated at this one."""
KEEP_VALUES = 256
"""Values a series keeps for the fit; beyond, every other one of the older half is dropped."""


def periods_to_go(periods: Sequence[float], ratio: Sequence[float]) -> float | None:
    """Periods left until ``ratio`` (a series' width its stop compares over its tolerance,
    per period in ``periods``, increasing) falls to 1, from a power law ``ratio = C n**b`` fitted (least squares
    in log-log) to the finite positive values of the last decade of periods and followed from its value at the
    last period, b at most :data:`STEADY_SLOPE`; 0 when already at or below 1; None when unknown (fewer than 4
    values, or not falling)."""
    n = np.asarray(periods, dtype=float)
    r = np.asarray(ratio, dtype=float)
    ok = np.isfinite(n) & np.isfinite(r) & (n > 0) & (r > 0)
    n, r = n[ok], r[ok]
    if n.size == 0:
        return None
    if r[-1] <= 1.0:
        return 0.0
    recent = n >= n[-1] / FIT_DECADE
    n, r = n[recent], r[recent]
    if n.size < 4 or np.ptp(np.log(n)) == 0.0:
        return None
    slope, intercept = np.polyfit(np.log(n), np.log(r), 1)
    if not slope < -1e-3:
        return None
    log_r_last = intercept + slope * math.log(n[-1])
    # an average's half-width falls at least as n**-1/2 once the periods are steady (noise alone); a shallower
    # fall on the last decade is a transient still settling, which would extrapolate to any number of periods
    slope = min(slope, STEADY_SLOPE)
    if log_r_last <= 0.0:
        return 0.0
    growth = -log_r_last / slope  # log of n_reach / n_last
    if not growth < MAX_LOG_GROWTH:  # beyond any cap on periods (or NaN)
        return None
    return max(0.0, float(n[-1]) * math.expm1(growth))


@dataclass
class _Series:
    periods: list[float] = field(default_factory=list)
    ratio: list[float] = field(default_factory=list)
    done: bool = False

    def add(self, state: SeriesState) -> None:
        self.done = state.verdict is not None
        if state.periods <= 0:
            return
        r = state.stop_width / state.tolerance if state.tolerance > 0 else math.nan
        if self.periods and state.periods == self.periods[-1]:
            self.ratio[-1] = r
        else:
            self.periods.append(float(state.periods))
            self.ratio.append(r)
            if len(self.periods) > KEEP_VALUES:
                half = KEEP_VALUES // 2
                self.periods[:half], self.ratio[:half] = self.periods[:half:2], self.ratio[:half:2]

    def to_go(self) -> float | None:
        return 0.0 if self.done else periods_to_go(self.periods, self.ratio)


class SweepTimer:
    """The time a sweep of ``frequencies_hz`` (Hz) still takes.

    extra_periods: periods each point spends besides those integrated (ramp in, settle, ramp out), aligned with
    ``frequencies_hz``; max_periods: the cap on integrated periods, one for all or one per frequency (a point's
    budget, :func:`~bodebench.core.autointegration.period_budget`); seconds_per_period: the bench's wall seconds
    per nominal period before any is measured (1 for a real-time clock, None: unknown until measured).
    """

    def __init__(self, frequencies_hz: Sequence[float], extra_periods: Sequence[float] | float = 0.0,
                 max_periods: int | Sequence[int] | None = None, seconds_per_period: float | None = None) -> None:
        self.frequencies_hz = tuple(float(f) for f in frequencies_hz)
        extra = [float(extra_periods)] * len(self.frequencies_hz) if isinstance(extra_periods, (int, float)) \
            else [float(e) for e in extra_periods]
        if len(extra) != len(self.frequencies_hz):
            raise ValueError("extra_periods must give one value per frequency")
        self._extra = dict(zip(self.frequencies_hz, extra, strict=True))
        caps: list[int | None] = ([max_periods] * len(self.frequencies_hz)
                                  if max_periods is None or isinstance(max_periods, int) else list(max_periods))
        if len(caps) != len(self.frequencies_hz):
            raise ValueError("max_periods must give one value, or one per frequency")
        self._caps = dict(zip(self.frequencies_hz, caps, strict=True))
        self.prior_ratio = seconds_per_period
        self.finished: set[float] = set()
        self._periods: dict[float, float] = {}      # periods integrated at a measured frequency (its slowest series)
        self._timed: list[tuple[float, float]] = []  # (nominal s, wall s) of the points this session measured
        self._current: float | None = None
        self._point_wall = 0.0       # wall seconds the current point has run, pauses excluded, at _mark
        self._mark: float | None = None
        self._first: tuple[float, int] | None = None  # (point wall s, periods) at the first progress with periods
        self._last: tuple[float, int] | None = None
        self._series: dict[tuple[str, int], _Series] = {}
        self.paused = False

    # --- what is known before
    def already_measured(self, points: Mapping[float, int]) -> None:
        """Frequencies on disk from an interrupted sweep, with the periods their slowest series took: done."""
        for f, periods in points.items():
            f = self._own(f)
            self.finished.add(f)
            self._periods[f] = float(periods)

    def extend(self, frequencies_hz: Sequence[float], extra_periods: Sequence[float],
               max_periods: Sequence[int]) -> None:
        """Frequencies (Hz) an adaptive plan adds, each with its extra periods and its cap on integrated periods."""
        for f, extra, cap in zip(frequencies_hz, extra_periods, max_periods, strict=True):
            f = float(f)
            if f not in self._extra:
                self.frequencies_hz += (f,)
                self._extra[f], self._caps[f] = float(extra), int(cap)

    # --- events (now: monotonic seconds)
    def point_started(self, frequency_hz: float, now: float) -> None:
        f = self._own(frequency_hz)
        self.finished.discard(f)  # measured again
        self._current, self._point_wall, self._mark = f, 0.0, None if self.paused else now
        self._first = self._last = None
        self._series = {}

    def progress(self, periods: int, states: Iterable[SeriesState], now: float) -> None:
        """The current point after ``periods`` integrated periods, its series' ``states``."""
        if self._current is None:
            return
        for s in states:
            self._series.setdefault((s.channel, s.harmonic), _Series()).add(s)
        wall = self._wall(now)
        if periods > 0:
            if self._first is None:
                self._first = (wall, periods)
            self._last = (wall, periods)

    def point_finished(self, frequency_hz: float, periods: int | None, now: float) -> None:
        """The point is done: ``periods`` its slowest series took (None: skipped or refused, not timed)."""
        f = self._own(frequency_hz)
        wall = self._wall(now)
        self.finished.add(f)
        if periods is not None and f == self._current:
            self._periods[f] = float(periods)
            self._timed.append(((periods + self._extra.get(f, 0.0)) / f, wall))
        self._current = self._mark = None
        self._first = self._last = None
        self._series = {}

    def pause(self, now: float) -> None:
        if not self.paused:
            self._wall(now)
            self.paused, self._mark = True, None

    def unpause(self, now: float) -> None:
        if self.paused:
            self.paused = False
            self._mark = now if self._current is not None else None

    # --- figures
    @property
    def total(self) -> int:
        return len(self.frequencies_hz)

    @property
    def done(self) -> int:
        return len(self.finished)

    def series_to_go(self) -> dict[tuple[str, int], float | None]:
        """The current point's periods to go per series (channel, harmonic)."""
        return {key: s.to_go() for key, s in self._series.items()}

    def current_periods_to_go(self) -> float | None:
        """Periods the current point still integrates: its slowest open series by its rule's progress, else the
        prediction from the measured points; capped by max_periods; None when unknown."""
        if self._current is None:
            return None
        done = self._periods_done
        to_go = list(self.series_to_go().values())
        known = [v for v in to_go if v is not None]
        predicted = self.predicted_periods(self._current)
        if known and (len(known) == len(to_go) or predicted is None):
            left = max(known)
        elif predicted is not None:
            left = max([predicted - done, *known])
        else:
            return None
        cap = self._caps.get(self._current)
        if cap is not None:
            left = min(left, cap - done)
        return max(0.0, left)

    def predicted_periods(self, frequency_hz: float) -> float | None:
        """Periods a point at ``frequency_hz`` is expected to integrate: interpolated in log frequency between the
        measured points; beyond them, the median of the NEAREST measured ones (so that one slow point, a
        resonance, does not stand for all that follow); None before any point is measured."""
        if not self._periods:
            return None
        fs = sorted(self._periods)
        x = math.log(frequency_hz)
        if fs[0] <= frequency_hz <= fs[-1]:
            value = float(np.interp(x, [math.log(f) for f in fs], [self._periods[f] for f in fs]))
        else:
            nearest = sorted(fs, key=lambda f: abs(math.log(f) - x))[:NEAREST]
            value = float(np.median([self._periods[f] for f in nearest]))
        cap = self._caps.get(frequency_hz)
        return min(value, cap) if cap is not None else value

    def seconds_model(self) -> tuple[float, float] | None:
        """(overhead s per point, wall s per nominal s) fitted on this session's points and the current one's
        integration so far; None before anything is measured and with no prior."""
        nominal = [n for n, _ in self._timed]
        wall = [w for _, w in self._timed]
        if self._first is not None and self._last is not None and self._last[1] > self._first[1]:
            assert self._current is not None
            span_nominal = (self._last[1] - self._first[1]) / self._current
            span_wall = self._last[0] - self._first[0]
        else:
            span_nominal = span_wall = 0.0
        if len(nominal) >= 3 and np.ptp(nominal) > 0:
            ratio, overhead = np.polyfit(nominal, wall, 1)
            if ratio > 0 and overhead >= 0:
                return float(overhead), float(ratio)
        total_nominal = sum(nominal) + span_nominal
        if total_nominal > 0:
            return 0.0, (sum(wall) + span_wall) / total_nominal
        return (0.0, self.prior_ratio) if self.prior_ratio is not None else None

    def remaining(self, now: float) -> float | None:
        """Seconds until the sweep is done (frozen while paused); None when unknown, 0 when nothing is left."""
        left = [f for f in self.frequencies_hz if f not in self.finished and f != self._current]
        if not left and self._current is None:
            return 0.0
        model = self.seconds_model()
        if model is None:
            return None
        overhead, ratio = model
        done = self._periods_done
        to_go = self.current_periods_to_go()  # None without a current point
        current_total = None if to_go is None else done + to_go  # what points measured by none are expected to take
        total = 0.0
        for f in left:
            periods = self.predicted_periods(f)
            if periods is None:
                periods = current_total
            if periods is None:
                return None
            total += overhead + ratio * (periods + self._extra.get(f, 0.0)) / f
        if self._current is not None:
            if to_go is None:
                return None
            f = self._current
            predicted = overhead + ratio * (done + to_go + self._extra.get(f, 0.0)) / f
            total += max(predicted - self._wall(now), ratio * to_go / f)
        return total

    # --- internals
    @property
    def _periods_done(self) -> int:
        """Periods the current point has integrated (0 before its first)."""
        return self._last[1] if self._last else 0

    def _wall(self, now: float) -> float:
        """The current point's wall seconds so far, pauses excluded."""
        if self._mark is not None:
            self._point_wall += max(0.0, now - self._mark)
            self._mark = now
        return self._point_wall

    def _own(self, frequency_hz: float) -> float:
        for f in self.frequencies_hz:
            if math.isclose(f, frequency_hz, rel_tol=1e-9, abs_tol=1e-12):
                return f
        raise ValueError(f"frequency {frequency_hz:g} Hz is not in this sweep")
