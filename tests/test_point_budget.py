"""A point's time budget (``[analysis] max_point_s``): a harmonic whose truth is zero, under noise, ends in bounded
bench time, and says what eps would have needed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bodebench.core.autointegration import (
    DEFAULT_BENCH_POINT_S,
    MIN_BUDGET_PERIODS,
    Autointegrator,
    period_budget,
)
from bodebench.core.rules import MIN_NOISE_EVIDENCE
from bodebench.io.tables import AnalysisConfig
from bodebench.status import PointStatus


@pytest.mark.parametrize("f", [0.01, 0.3, 1.0, 3.0, 33.3, 100.0, 1000.0])
@pytest.mark.parametrize("max_point_s", [None, 5.0, 600.0, 1e6])
def test_the_budget_is_the_time_in_periods_within_its_bounds(f: float, max_point_s: float | None) -> None:
    analysis = AnalysisConfig(max_periods=20000, max_point_s=max_point_s)
    seconds = DEFAULT_BENCH_POINT_S if max_point_s is None else max_point_s
    assert period_budget(analysis, f, on_bench=True) == min(20000, max(256, math.ceil(seconds * f)))
    offline = 20000 if max_point_s is None else min(20000, max(256, math.ceil(max_point_s * f)))
    assert period_budget(analysis, f, on_bench=False) == offline  # offline: only a budget asked for
    assert MIN_BUDGET_PERIODS == 256


def jittered_linear_response(f: float, rate: float, periods: int, noise: float, seed: int
                             ) -> tuple[np.ndarray, np.ndarray]:
    """A bench's samples of a linear response (harmonics 2 and 3 exactly zero): a sine of amplitude 1 at times
    jittered by 20 % of a sample interval around a fixed rate, with white noise of ``noise`` rms."""
    rng = np.random.default_rng(seed)
    n = int(periods / f * rate) + 1
    t = np.arange(n) / rate + rng.uniform(-0.1, 0.1, n) / rate
    t[0] = 0.0
    y = np.sin(2 * np.pi * f * t + 0.7) + noise * rng.standard_normal(n)
    return t, y[:, None]


def test_a_zero_harmonic_under_noise_ends_noise_limited_within_its_evidence_not_at_max_periods() -> None:
    """At 3 Hz the noise on harmonic 3 (truth zero) would need about ten thousand periods for eps at its absolute
    floor: within twice max_periods (20,000 periods, 1.9 h), so without a time budget the point would run for most
    of an hour; with the bench's 600 s budget (1,800 periods) it ends after its noise evidence, its interval holding
    the truth."""
    f, rate = 3.0, 2000.0
    analysis = AnalysisConfig(harmonics=(1, 3), tolerance_percent=0.1, max_periods=20000)
    t, y = jittered_linear_response(f, rate, 400, noise=6e-4, seed=11)
    sampler = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0)
    assert sampler.max_periods == 1800
    sampler.feed(t, y)
    assert sampler.done
    first, third = sampler.points()
    assert first.status == PointStatus.CONVERGED
    assert third.status == PointStatus.NOISE_LIMITED and not third.within_eps
    assert third.periods <= MIN_NOISE_EVIDENCE + 32  # judged on its evidence, after harmonic 1 settled
    # eps was out of reach of this budget, and within reach of max_periods' twice: the budget made the difference
    assert 2 * sampler.max_periods < third.periods_needed < 2 * analysis.max_periods
    assert abs(complex(third.p, third.q)) <= third.uncertainty  # the 95 % disc holds the truth, zero


def test_a_quiet_zero_harmonic_still_ends_below_resolution() -> None:
    """Without noise the budget changes nothing: harmonic 3 is zero to within the floor and says so."""
    f, rate = 3.0, 2000.0
    analysis = AnalysisConfig(harmonics=(1, 3), tolerance_percent=0.1)
    t, y = jittered_linear_response(f, rate, 200, noise=0.0, seed=3)
    sampler = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0)
    sampler.feed(t, y)
    first, third = sampler.points()
    assert first.status == PointStatus.CONVERGED and third.status == PointStatus.BELOW_RESOLUTION
    assert abs(complex(third.p, third.q)) < 1e-9
