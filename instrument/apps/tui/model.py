"""What the terminal UI shows, kept apart from the widgets: sweep rows, convergence history, bus rates, ETA.

Pure: session events and numbers in, plain values out (no Textual, no threads, no I/O).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from bodebench.core.autointegration import SeriesState
from bodebench.core.eta import SweepTimer
from bodebench.core.response import ResponsePoint
from bodebench.status import PointStatus

#: states of a row in the sweep table
PENDING, SETTLING, INTEGRATING, CONVERGED, CAPPED, NOISE_LIMITED, DISTURBED, ALIASED, DIVISOR_NOISY, UNTIED = (
    "pending", "settling", "integrating", "converged", "capped", "noise-limited", "disturbed", "aliased",
    "divisor-noisy", "untied")
FAILED, SKIPPED = "failed", "skipped"
ROW_STATES = (PENDING, SETTLING, INTEGRATING, CONVERGED, CAPPED, NOISE_LIMITED, DISTURBED, ALIASED, DIVISOR_NOISY,
              UNTIED, FAILED, SKIPPED)
ACTIVE_STATES = (SETTLING, INTEGRATING)


def relative_error_percent(estimate: complex, uncertainty: float) -> float:
    """100 * uncertainty / |estimate| (%); NaN when either is unknown or the estimate is zero."""
    magnitude = abs(estimate)
    if not (math.isfinite(magnitude) and math.isfinite(uncertainty)) or magnitude == 0.0:
        return math.nan
    return 100.0 * uncertainty / magnitude


def format_duration(seconds: float | None) -> str:
    """``m:ss`` (``h:mm:ss`` past an hour); ``--`` when unknown."""
    if seconds is None or not math.isfinite(seconds) or seconds < 0:
        return "--"
    s = int(round(seconds))
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def row_key(position: int, harmonic: int, channel: str) -> str:
    """Key of a sweep table row (frequency position in the sweep, harmonic, channel)."""
    return f"{position}:{harmonic}:{channel}"


_UNCONVERGED_STATES: dict[str, str] = {PointStatus.CAPPED: CAPPED, PointStatus.NOISE_LIMITED: NOISE_LIMITED,
                                       PointStatus.DISTURBED: DISTURBED, PointStatus.ALIAS_LIMITED: ALIASED,
                                       PointStatus.DIVISOR_LIMITED: DIVISOR_NOISY, PointStatus.UNTIED: UNTIED}


def finished_state(converged: bool, status: str) -> str:
    """The row state of a finished point or series: converged, or why not (capped, noise-limited, disturbed: a
    disturbance line on its harmonic, aliased: the rate folds more onto it than its tolerance, divisor-noisy: a
    two-channel ratio whose divisor is too noisy a period to divide by, untied: its phase has
    the host's latency in it), failed otherwise."""
    if converged:
        return CONVERGED
    return _UNCONVERGED_STATES.get(status, FAILED)  # a status is its own string


def point_state(point: ResponsePoint) -> str:
    """:func:`finished_state` of a finished point."""
    return finished_state(point.converged, point.status)


@dataclass
class Row:
    """One line of the sweep table: a series (harmonic x channel) at one frequency."""

    frequency_hz: float
    harmonic: int
    channel: str
    state: str = PENDING
    gain_db: float = math.nan
    phase_deg: float = math.nan
    periods: int = 0
    thd: float = math.nan
    coherence: float = math.nan


@dataclass
class SeriesTrace:
    """Relative error (%) per update of one series of the current point."""

    channel: str
    harmonic: int
    periods: list[int] = field(default_factory=list)
    rel_error: list[float] = field(default_factory=list)
    uncertainty: float = math.nan
    estimate: complex = complex(math.nan, math.nan)
    done: bool = False

    def add(self, state: SeriesState) -> None:
        self.uncertainty, self.estimate = state.uncertainty, state.estimate
        self.done = state.verdict is not None
        e = relative_error_percent(state.estimate, state.uncertainty)
        if self.periods and state.periods == self.periods[-1]:
            self.rel_error[-1] = e
        elif state.periods > 0:
            self.periods.append(state.periods)
            self.rel_error.append(e)


class SweepModel:
    """Rows for every (frequency, harmonic, channel) of a sweep, the current point's convergence, and timing.

    Points are found by frequency (a re-measured frequency comes back with a new event index).
    Times are monotonic seconds supplied by the caller.
    """

    def __init__(self, frequencies_hz: Sequence[float], harmonics: Sequence[int], channels: Sequence[str]) -> None:
        if not frequencies_hz:
            raise ValueError("a sweep needs at least one frequency")
        self.frequencies_hz = tuple(float(f) for f in frequencies_hz)
        self.harmonics = tuple(harmonics)
        self.channels = tuple(channels)
        self.rows: dict[str, Row] = {
            row_key(i, k, c): Row(f, k, c) for i, f in enumerate(self.frequencies_hz)
            for k in self.harmonics for c in self.channels}
        self.current: int | None = None        # position of the point being measured
        self.current_index: int | None = None  # its session event index
        self.traces: list[SeriesTrace] = []
        self.tolerance_percent = math.nan
        self.criterion = ""
        self.periods = 0
        self.started_at: float | None = None
        self.ended_at: float | None = None
        self.timer = SweepTimer(self.frequencies_hz)
        self.finished: set[int] = set()
        self.changed: set[str] = set(self.rows)
        self.state_changed = True  # a row changed more than its period count since take_changed

    def extend(self, frequencies_hz: Sequence[float], extra_periods: Sequence[float],
               max_periods: Sequence[int]) -> None:
        """Frequencies (Hz) an adaptive plan adds: rows of their own, every row in ascending frequency (positions
        keep their keys), timed like the others (their extra periods and caps)."""
        new = [float(f) for f in frequencies_hz if not any(math.isclose(f, g, rel_tol=1e-9)
                                                           for g in self.frequencies_hz)]
        start = len(self.frequencies_hz)
        self.frequencies_hz += tuple(new)
        for i, f in enumerate(new, start):
            for k in self.harmonics:
                for c in self.channels:
                    self.rows[row_key(i, k, c)] = Row(f, k, c)
                    self.changed.add(row_key(i, k, c))
        order = sorted(range(len(self.frequencies_hz)), key=lambda i: self.frequencies_hz[i])
        self.rows = {key: self.rows[key] for i in order for key in self.keys_at(i)}
        self.timer.extend(frequencies_hz, extra_periods, max_periods)
        self.state_changed = True

    # --- lookups
    def position(self, frequency_hz: float) -> int:
        """Position of ``frequency_hz`` in the sweep; ValueError when it is not one of its frequencies."""
        for i, f in enumerate(self.frequencies_hz):
            if math.isclose(f, frequency_hz, rel_tol=1e-9, abs_tol=1e-12):
                return i
        raise ValueError(f"frequency {frequency_hz:g} Hz is not in this sweep")

    def keys_at(self, position: int) -> list[str]:
        return [row_key(position, k, c) for k in self.harmonics for c in self.channels]

    def _set(self, key: str, **values: object) -> None:
        row = self.rows.get(key)
        if row is None:
            return
        for name, value in values.items():
            if name != "periods" and getattr(row, name) != value:
                self.state_changed = True
            setattr(row, name, value)
        self.changed.add(key)

    # --- events
    def session_started(self, now: float, timer: SweepTimer | None = None) -> None:
        """A session starts; ``timer`` times it (from its SessionStarted: what is already measured, ramp and
        settle periods, the clock), else a timer knowing only the frequencies."""
        self.started_at, self.ended_at = now, None
        paused = self.timer.paused
        self.timer = timer or SweepTimer(self.frequencies_hz)
        if paused:
            self.timer.pause(now)

    def pause(self, now: float) -> None:
        """The sweep is paused: the ETA stands still."""
        self.timer.pause(now)

    def unpause(self, now: float) -> None:
        self.timer.unpause(now)

    def point_started(self, index: int, frequency_hz: float, now: float, tolerance_percent: float = math.nan,
                      criterion: str = "") -> None:
        """Point ``index`` starts at ``frequency_hz`` (Hz), judged by ``criterion`` at ``tolerance_percent`` (%)."""
        self.tolerance_percent, self.criterion = tolerance_percent, criterion
        position = self.position(frequency_hz)
        self.current, self.current_index = position, index
        self.traces = [SeriesTrace(c, k) for c in self.channels for k in self.harmonics]
        self.periods = 0
        self.timer.point_started(frequency_hz, now)
        for key in self.keys_at(position):
            self._set(key, state=SETTLING, gain_db=math.nan, phase_deg=math.nan, periods=0, thd=math.nan,
                      coherence=math.nan)

    def progress(self, index: int, periods: int, states: Sequence[SeriesState], now: float) -> None:
        if index != self.current_index or self.current is None:
            return
        self.periods = periods
        self.timer.progress(periods, states, now)
        by_series = {(t.channel, t.harmonic): t for t in self.traces}
        for s in states:
            trace = by_series.get((s.channel, s.harmonic))
            if trace is not None:
                trace.add(s)
            key = row_key(self.current, s.harmonic, s.channel)
            if s.verdict is not None:
                state = finished_state(s.verdict.converged, s.verdict.status)
            else:
                state = INTEGRATING if periods > 0 else SETTLING
            row = self.rows.get(key)
            if row is not None and (row.state != state or row.periods != s.periods):
                self._set(key, state=state, periods=s.periods)

    def point_finished(self, index: int, points: Sequence[ResponsePoint], skipped: bool, now: float) -> None:
        position = self.current if index == self.current_index else None
        if position is None and points:
            position = self.position(points[0].frequency_hz)
        if position is None:
            return
        if skipped:
            for key in self.keys_at(position):
                self._set(key, state=SKIPPED)
        for p in points:
            self._set(row_key(position, p.harmonic, p.channel), state=point_state(p), gain_db=p.gain_db,
                      phase_deg=p.phase_deg, periods=p.periods, thd=p.thd, coherence=p.coherence)
        if index == self.current_index:
            self.timer.point_finished(self.frequencies_hz[position], max((p.periods for p in points), default=None),
                                      now)  # no points: skipped or refused, not timed
        self.finished.add(position)
        self.current = self.current_index = None

    def fail_current(self) -> None:
        """The sweep stopped inside a point: its unfinished rows failed."""
        if self.current is not None:
            for key in self.keys_at(self.current):
                if self.rows[key].state in ACTIVE_STATES:
                    self._set(key, state=FAILED)
        self.current = self.current_index = None

    def session_ended(self, now: float) -> None:
        self.ended_at = now
        self.fail_current()

    def load_points(self, points: Iterable[ResponsePoint]) -> None:
        """Fill rows from finished points (a results directory); points at other frequencies are ignored."""
        for p in points:
            try:
                position = self.position(p.frequency_hz)
            except ValueError:
                continue
            self._set(row_key(position, p.harmonic, p.channel), state=point_state(p), gain_db=p.gain_db,
                      phase_deg=p.phase_deg, periods=p.periods, thd=p.thd, coherence=p.coherence)
            self.finished.add(position)

    # --- summaries
    @property
    def total(self) -> int:
        return len(self.frequencies_hz)

    @property
    def done(self) -> int:
        """Frequencies finished (measured or skipped)."""
        return len(self.finished)

    def elapsed(self, now: float) -> float | None:
        if self.started_at is None:
            return None
        return (self.ended_at if self.ended_at is not None else now) - self.started_at

    def eta(self, now: float) -> float | None:
        """Seconds to finish the sweep (see :class:`~bodebench.core.eta.SweepTimer`); None when no session runs or
        the time is not known yet."""
        if self.started_at is None or self.ended_at is not None:
            return None
        return self.timer.remaining(now)

    def series_to_go(self, channel: str, harmonic: int) -> float | None:
        """Periods the current point's series still needs by its rule's progress (0: done; None: unknown)."""
        return self.timer.series_to_go().get((channel, harmonic))

    def take_changed(self) -> list[str]:
        """Keys of rows changed since the last call."""
        keys = [k for k in self.rows if k in self.changed]
        self.changed.clear()
        self.state_changed = False
        return keys


class BusRates:
    """Frame rates from counter differences over a sliding window of ``window_s`` seconds."""

    def __init__(self, window_s: float = 1.0) -> None:
        self.window_s = window_s
        self._samples: deque[tuple[float, int, int]] = deque()

    def update(self, now: float, frames_in: int, frames_out: int) -> tuple[float, float]:
        """Add a reading; returns (frames in per s, frames out per s), NaN until two readings span time."""
        samples = self._samples
        if samples and (frames_in < samples[-1][1] or frames_out < samples[-1][2]):
            samples.clear()  # counters restarted (a new session)
        samples.append((now, frames_in, frames_out))
        while len(samples) > 2 and now - samples[1][0] >= self.window_s:
            samples.popleft()
        t0, i0, o0 = samples[0]
        dt = now - t0
        if dt <= 0.0:
            return math.nan, math.nan
        return (frames_in - i0) / dt, (frames_out - o0) / dt

    def reset(self) -> None:
        self._samples.clear()
