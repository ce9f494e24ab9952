"""The sweep's time to go: power-law extrapolation of a rule's progress, the timer against sweeps whose points take
exactly the modelled time, pauses, resumed sweeps, and the real rule's own prediction of when it stops."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bodebench.core.autointegration import Autointegrator, SeriesState
from bodebench.core.eta import SweepTimer, periods_to_go
from bodebench.io.config import AnalysisConfig

FREQS = (1.0, 2.0, 4.0, 8.0, 16.0)


def test_periods_to_go_follows_a_power_law() -> None:
    n = np.arange(1, 101, dtype=float)
    assert periods_to_go(n, 100.0 * n ** -0.5) == pytest.approx(10000 - 100, rel=1e-6)  # ratio 1 at n = 100**2
    assert periods_to_go(n, np.where(n < 10, 1e6, 500.0 / n)) == pytest.approx(400, rel=1e-6)  # last decade
    assert periods_to_go(n, 500.0 / n) == pytest.approx(500 - 100, rel=1e-6)
    assert periods_to_go(n, 0.5 / n) == 0.0
    assert periods_to_go(n, 3.0 + 0.0 * n) is None  # not falling
    # a transient still settling (falling as n**-0.05 over the last decade, ratio 2 at the last period) is
    # followed at the n**-1/2 of steady periods: ratio 2 at n = 100 reaches 1 at 400, not at 100 * 2**20
    assert periods_to_go(n, 2.0 * (n / n[-1]) ** -0.05) == pytest.approx(400 - 100, rel=1e-6)
    assert periods_to_go(n[:3], 10 / n[:3]) is None
    assert periods_to_go([], []) is None


def state(periods: int, ratio: float, done: bool = False) -> SeriesState:
    """A series whose half-width is ``ratio`` times its stopping half-width (1e-3)."""
    from bodebench.core.rules import Verdict

    verdict = Verdict(periods, 1.0, 0.0, 1e-3 * ratio, "converged", "test") if done else None
    return SeriesState("y", 1, periods, 1 + 0j, 1e-3 * ratio, verdict, 1e-3, 1e-3 * ratio)


class Bench:
    """A sweep whose points take exactly ``overhead + ratio * (periods + extra) / f`` seconds, fed to a timer."""

    def __init__(self, timer: SweepTimer, overhead: float, ratio: float, extra: float) -> None:
        self.timer, self.overhead, self.ratio, self.extra = timer, overhead, ratio, extra
        self.now = 100.0

    def duration(self, f: float, periods: float) -> float:
        return self.overhead + self.ratio * (periods + self.extra) / f

    def measure(self, f: float, periods: int) -> None:
        self.timer.point_started(f, self.now)
        self.now += self.duration(f, periods)
        self.timer.point_finished(f, periods, self.now)


def test_the_time_left_is_exact_for_points_that_take_the_modelled_time() -> None:
    """Constant periods per point, a fixed overhead per point and a bench running at 0.3 s per nominal second:
    after three points the timer has both constants and the rest of the sweep's time exactly."""
    timer = SweepTimer(FREQS, extra_periods=3.0, max_periods=10_000)
    bench = Bench(timer, overhead=0.25, ratio=0.3, extra=3.0)
    assert timer.remaining(bench.now) is None  # nothing measured, no prior: unknown
    for f in FREQS[:3]:
        bench.measure(f, 400)
    assert timer.seconds_model() == pytest.approx((0.25, 0.3))
    assert timer.remaining(bench.now) == pytest.approx(sum(bench.duration(f, 400) for f in FREQS[3:]))
    assert timer.done == 3 and timer.total == 5


def test_the_current_point_counts_what_its_rule_still_needs() -> None:
    """Halfway through a point whose series' ratio falls as n**-1/2 (stopping at n = 1600): what is left is the
    rest of its periods and its ramp out, at the bench's seconds per period, plus the points after it."""
    timer = SweepTimer(FREQS, extra_periods=3.0, max_periods=10_000, seconds_per_period=1.0)
    bench = Bench(timer, overhead=0.0, ratio=1.0, extra=3.0)
    for f in FREQS[:2]:
        bench.measure(f, 1600)
    f = FREQS[2]
    timer.point_started(f, bench.now)
    ramp_out = 1.0
    bench.now += (3.0 - ramp_out) / f  # ramp in and settle
    for n in range(10, 801, 10):
        bench.now += 10 / f
        timer.progress(n, [state(n, 40.0 / math.sqrt(n))], bench.now)
    assert timer.current_periods_to_go() == pytest.approx(800, rel=1e-6)
    expected = (800 + ramp_out) / f + sum(bench.duration(g, 1600) for g in FREQS[3:])
    assert timer.remaining(bench.now) == pytest.approx(expected, rel=1e-6)
    assert timer.series_to_go() == {("y", 1): pytest.approx(800, rel=1e-6)}


def test_the_rule_cap_bounds_the_periods_to_go() -> None:
    timer = SweepTimer(FREQS, max_periods=500, seconds_per_period=1.0)
    timer.point_started(1.0, 0.0)
    for n in range(10, 201, 10):
        timer.progress(n, [state(n, 1000.0 / n)], float(n))
    assert timer.current_periods_to_go() == pytest.approx(300)  # the power law says 800, the cap 500 - 200
    assert timer.predicted_periods(4.0) is None
    # the points after it are predicted from the current one: 500 periods each
    assert timer.remaining(200.0) == pytest.approx(300 + sum(500 / f for f in FREQS[1:]))


def test_a_pause_stops_the_clock() -> None:
    """While paused the time left stands still; once going on, the pause is not taken for a slower bench."""
    timer = SweepTimer(FREQS, seconds_per_period=1.0)
    bench = Bench(timer, overhead=0.0, ratio=2.0, extra=0.0)
    bench.measure(1.0, 100)  # 200 s: the bench runs at 2 s per nominal s
    timer.point_started(2.0, bench.now)
    for n in range(10, 51, 10):
        bench.now += 2.0 * 10 / 2.0
        timer.progress(n, [state(n, 100.0 / n)], bench.now)
    before = timer.remaining(bench.now)
    timer.pause(bench.now)
    assert timer.remaining(bench.now + 1000.0) == pytest.approx(before)
    bench.now += 1000.0
    timer.unpause(bench.now)
    assert timer.remaining(bench.now) == pytest.approx(before)
    for n in range(60, 101, 10):
        bench.now += 2.0 * 10 / 2.0
        timer.progress(n, [state(n, 100.0 / n, done=n == 100)], bench.now)
    timer.point_finished(2.0, 100, bench.now)
    assert timer.seconds_model() == pytest.approx((0.0, 2.0))
    assert timer.remaining(bench.now) == pytest.approx(sum(2.0 * 100 / f for f in FREQS[2:]))


def test_a_resumed_sweep_counts_what_is_on_disk_and_predicts_from_it() -> None:
    """Frequencies measured before an interruption are done; the rest are predicted, interpolated in log
    frequency, from the periods those took; on a real-time bench the time is known before the first point."""
    timer = SweepTimer(FREQS, extra_periods=2.0, seconds_per_period=1.0)
    timer.already_measured({1.0: 1000, 16.0: 200})
    assert timer.done == 2
    assert timer.predicted_periods(4.0) == pytest.approx(600)  # halfway in log f
    assert timer.remaining(0.0) == pytest.approx(sum((1000 - 200 * math.log2(f) + 2.0) / f for f in (2, 4, 8)))
    timer.already_measured({2.0: 100, 4.0: 3000})  # beyond them, the median of the three nearest
    assert timer.predicted_periods(0.5) == pytest.approx(1000)  # 1, 2 and 4 Hz
    timer.point_finished(2.0, 800, 802 / 2.0)
    assert timer.done == 4


def test_the_adaptive_rule_predicts_its_own_stop() -> None:
    """A noisy sine through the real sampler, eight noise seeds: a quarter of the way, the periods to go the rule's
    progress predicts put the stop within a factor 1.25 of where the rule actually stops, and without a bias (their
    geometric mean within 10 % of 1). The stop compares the noise disc at 98 %, wider than the stated 95 % one: a
    prediction that followed the stated interval would put the stop about a quarter early."""
    f, rate = 5.0, 1000.0
    settings = AnalysisConfig(harmonics=(1,), tolerance_percent=0.2, max_periods=100_000, max_point_s=1e6)
    ratios = []
    for seed in range(1, 9):
        sampler = Autointegrator(f, 1.0, ["y"], settings)
        timer = SweepTimer((f,), max_periods=settings.max_periods, seconds_per_period=1.0)
        timer.point_started(f, 0.0)
        rng = np.random.default_rng(seed)
        block = int(20 * rate / f)
        start, history = 0, []
        while not sampler.done:
            t = (start + np.arange(block)) / rate
            y = 0.8 * np.sin(2 * math.pi * f * t + 0.3) + 0.5 * rng.standard_normal(block)
            sampler.feed(t, y[:, None])
            timer.progress(sampler.periods, sampler.states(), t[-1])
            history.append((sampler.periods, timer.current_periods_to_go()))
            start += block
        stopped = sampler.points()[0].periods
        assert stopped > 400  # long enough for the prediction to mean something
        at, to_go = next((n, g) for n, g in history if n >= stopped / 4 and g is not None)
        ratios.append((at + to_go) / stopped)
    assert all(1 / 1.25 < r < 1.25 for r in ratios), ratios
    assert 0.9 < math.exp(np.mean(np.log(ratios))) < 1.1, ratios


def test_any_progress_gives_a_finite_time_or_none() -> None:
    """Random sweeps with whatever a series may report (NaN, inf, zero tolerance, ratios rising or flat, from
    1e-300 to 1e300): the timer never raises, and its time left is None or finite and not negative."""
    rng = np.random.default_rng(11)
    values = [math.nan, math.inf, 0.0, 1e-300, 1e300, 1.0]
    for _ in range(200):
        freqs = tuple(sorted(set(np.round(10 ** rng.uniform(-1, 3, rng.integers(1, 6)), 3))))
        timer = SweepTimer(freqs, extra_periods=float(rng.integers(0, 5)), max_periods=int(rng.integers(10, 10**6)),
                           seconds_per_period=None if rng.random() < 0.5 else float(rng.uniform(0.01, 3)))
        now = 0.0
        scale, slope = float(10 ** rng.uniform(0, 300)), float(rng.uniform(-2.0, 0.5))
        for f in freqs:
            timer.point_started(f, now)
            n = 0
            for _ in range(int(rng.integers(0, 60))):
                n += int(rng.integers(0, 50))
                now += float(rng.exponential(0.1))
                u = float(rng.choice(values)) if rng.random() < 0.1 else scale * max(n, 1) ** slope \
                    if rng.random() < 0.7 else float(10 ** rng.uniform(-300, 300))
                tol = float(rng.choice(values)) if rng.random() < 0.1 else 1.0
                timer.progress(n, [SeriesState("y", 1, n, 1 + 0j, u, None, tol, u)], now)
                if rng.random() < 0.1:
                    (timer.pause if not timer.paused else timer.unpause)(now)
                left = timer.remaining(now)
                assert left is None or (math.isfinite(left) and left >= 0.0), left
            timer.point_finished(f, None if rng.random() < 0.2 else n, now)
        assert timer.remaining(now) == 0.0


def test_each_point_is_predicted_within_its_own_budget() -> None:
    """With a budget per frequency (a time budget leaves a low frequency fewer periods), a prediction from the
    measured points never exceeds the budget of the frequency predicted."""
    timer = SweepTimer((1.0, 10.0, 100.0), max_periods=(600, 6000, 20000), seconds_per_period=1.0)
    timer.already_measured({100.0: 5000})
    assert timer.predicted_periods(10.0) == pytest.approx(5000)
    assert timer.predicted_periods(1.0) == pytest.approx(600)  # the measured 5000 periods do not fit 1 Hz's budget
    with pytest.raises(ValueError, match="one per frequency"):
        SweepTimer((1.0, 10.0), max_periods=(600,))
