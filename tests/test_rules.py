"""Stopping rules on synthetic coefficient sequences with known limits."""

from __future__ import annotations

import math

import numpy as np
import pytest

from instrument.rules import (BELOW_RESOLUTION, CAPPED, CONVERGED, CRITERIA, AdaptiveRule, SeriesHistory,
                              extrapolate_modes, make_rule, relative_change_percent)


def run(rule, z: np.ndarray, reference: float | None = None, cap: int | None = None):
    """Replay a rule period by period, as the sampler does; returns the verdict."""
    hist = SeriesHistory()
    hist.extend(z)
    cap = cap or z.size
    for n in range(1, cap + 1):
        ref = abs(z[n - 1]) if reference is None else reference
        verdict = rule.check(hist, n, ref)
        if verdict is not None:
            return verdict
    return rule.capped(hist, cap, abs(z[cap - 1]) if reference is None else reference)


def test_history_running_sums_match_direct_means() -> None:
    rng = np.random.default_rng(1)
    z = rng.normal(size=700) + 1j * rng.normal(size=700)
    hist = SeriesHistory()
    for chunk in np.array_split(z, 13):
        hist.extend(chunk)
    assert hist.n == 700
    for a, b in [(0, 1), (0, 700), (5, 9), (350, 699)]:
        assert hist.mean(a, b) == pytest.approx(z[a:b].mean(), rel=1e-12)
    assert hist.at(42) == z[41]


def test_relative_change_is_the_printed_quantity() -> None:
    assert relative_change_percent(2.0, -1.9) == pytest.approx(5.0)
    assert relative_change_percent(0.0, 1e-30) == math.inf
    assert math.isnan(relative_change_percent(0.0, 0.0))


def test_full_averaging_stops_where_the_printed_inequality_first_holds() -> None:
    """One transient period of size S: Pc(n) = Z + S/(n - n_k); the rule stops at the first n whose change
    S/((n-n_k)(n-n_k-1)) relative to |Pc(n)| is within eps, leaving an error S/(n-n_k) far above eps."""
    eps, skip, zinf, s = 0.01, 1, 1.0 - 0.5j, 0.3 + 0.1j
    z = np.full(5000, zinf, dtype=complex)
    z[skip] += s  # period n_k + 1, the first analysed one
    verdict = run(make_rule("full", tolerance_percent=eps, skip_periods=skip, window=5), z)
    # independent computation of the stopping period from the printed formulas
    expected = None
    for n in range(skip + 2, z.size + 1):
        pc = zinf + s / (n - skip)
        pp = zinf + s / (n - 1 - skip)
        okp = abs(abs(pc.real) - abs(pp.real)) / abs(pc.real) * 100 <= eps
        okq = abs(abs(pc.imag) - abs(pp.imag)) / abs(pc.imag) * 100 <= eps
        if okp and okq:
            expected = n
            break
    assert verdict.period == expected
    err = abs(complex(verdict.p, verdict.q) - zinf) / abs(zinf)
    assert err == pytest.approx(abs(s) / (expected - skip) / abs(zinf), rel=1e-9)
    assert err * 100 > 10 * eps  # the weak spot: the average never forgets the transient


def test_adaptive_forgets_the_transient_and_meets_eps() -> None:
    eps, zinf, s = 0.01, 1.0 - 0.5j, 0.3 + 0.1j
    z = np.full(5000, zinf, dtype=complex)
    z[1] += s
    verdict = run(make_rule("adaptive", tolerance_percent=eps, skip_periods=1, window=5), z)
    assert verdict.status == CONVERGED
    assert abs(complex(verdict.p, verdict.q) - zinf) / abs(zinf) * 100 <= eps


def test_printed_rules_stall_on_a_zero_coefficient_and_adaptive_does_not() -> None:
    """Q = 0 exactly (phase 0): |Qc| is 0 so the printed relative test is 0/0 and never passes."""
    n = np.arange(1, 3001)
    z = (1.0 + 0.5 * 0.8 ** n).astype(complex)
    for name in ("full", "none", "local", "combined1", "combined2", "combined3"):
        verdict = run(make_rule(name, tolerance_percent=0.01, skip_periods=1, window=5), z)
        assert verdict.status == CAPPED, name
        assert not verdict.converged
    verdict = run(make_rule("adaptive", tolerance_percent=0.01, skip_periods=1, window=5), z)
    assert verdict.status == CONVERGED and verdict.period < 200
    assert abs(verdict.p - 1.0) <= 1e-4 and abs(verdict.q) <= 1e-4


def test_fixed_schemes_take_exactly_their_periods() -> None:
    z = np.arange(1, 101) * (1 + 1j)
    first = run(make_rule("first_period", tolerance_percent=0.01, skip_periods=1, window=5), z)
    sixth = run(make_rule("sixth_of_six", tolerance_percent=0.01, skip_periods=1, window=5), z)
    fixed = run(make_rule("fixed", tolerance_percent=0.01, skip_periods=1, window=5,
                          settle_periods=10, average_periods=4), z)
    assert (first.period, first.p) == (1, 1.0)
    assert (sixth.period, sixth.p) == (6, 6.0)
    assert (fixed.period, fixed.p) == (14, pytest.approx(np.mean([11, 12, 13, 14])))


def test_local_and_combined_rules_compare_what_the_paper_prints() -> None:
    """A sequence that becomes constant at period 20: every comparison is exactly satisfied one period later
    at the latest, so each rule's stopping period follows from its definition."""
    z = np.concatenate([np.linspace(3, 2, 19), np.full(200, 2.0)]) * (1 - 1j)
    l, skip = 5, 1
    stops = {name: run(make_rule(name, tolerance_percent=1e-9, skip_periods=skip, window=l), z).period
             for name in ("none", "local", "combined1")}
    assert stops["none"] == 20           # P(19) is the ramp's last value, 2.0, and P(20) repeats it
    assert stops["local"] == 19 + l      # means of the last l at n and n-1 agree once both windows are constant
    assert stops["combined1"] == 18 + l  # P(n) equals the mean of the last l once those l are constant


def test_adaptive_reports_below_resolution_for_a_coefficient_that_is_zero() -> None:
    rng = np.random.default_rng(3)
    z = 1e-12 * (rng.normal(size=400) + 1j * rng.normal(size=400))
    verdict = run(AdaptiveRule(0.01, 1), z, reference=1.0)
    assert verdict.status == BELOW_RESOLUTION
    assert verdict.converged


@pytest.mark.parametrize("lam", [0.9 * np.exp(0.7j), 0.97 * np.exp(0.2j), 0.6])
def test_extrapolation_is_exact_for_geometric_transients(lam: complex) -> None:
    i = np.arange(1, 60)
    zinf = 0.3 - 0.7j
    z = zinf + 0.5 * lam ** i + (0.2 - 0.1j) * np.conj(lam) ** i
    fit = extrapolate_modes(z[20:50], 2, predict=9)
    assert fit is not None
    assert abs(fit.limit - zinf) < 1e-9
    assert fit.residual < 1e-9
    # the recurrence forecasts the periods it has not seen
    assert np.max(np.abs(fit.prediction - z[50:59])) < 1e-9


def test_extrapolation_refuses_a_beat_that_never_decays() -> None:
    i = np.arange(1, 200)
    z = 1.0 + 0.5 * np.exp(0.05j * i)  # conservative link: a mode on the unit circle
    assert extrapolate_modes(z[100:200], 2) is None


def test_adaptive_stops_early_on_a_slow_modal_transient() -> None:
    """A transient decaying by 3 % per period: the window mean would need ~600 periods, the fit a fraction."""
    i = np.arange(1, 3001)
    lam = 0.97 * np.exp(0.3j)
    zinf = 0.01 - 0.002j
    z = zinf + 0.02 * lam ** i + 0.02 * np.conj(lam) ** i
    verdict = run(AdaptiveRule(0.01, 1), z)
    assert verdict.status == CONVERGED
    assert verdict.period < 200
    assert abs(complex(verdict.p, verdict.q) - zinf) / abs(zinf) * 100 <= 0.01


def test_adaptive_does_not_claim_convergence_on_a_beat() -> None:
    i = np.arange(1, 2001)
    z = 1.0 + 0.5 * np.exp(0.01j * i) + 0.5 * np.exp(-0.01j * i)
    verdict = run(AdaptiveRule(0.01, 1), z, cap=2000)
    assert verdict.status == CAPPED


def test_adaptive_uncertainty_covers_the_truth_at_its_stated_level_under_noise() -> None:
    """White noise on every period: the 95 % disc covers the true value in 95 % of the trials, neither far
    more (an interval too wide) nor far fewer (stopping on a spread that happened to be low)."""
    rng = np.random.default_rng(7)
    zinf, sigma, covered, trials = 1.0 - 1.0j, 2e-3, 0, 200
    for _ in range(trials):
        z = zinf + sigma * (rng.normal(size=4000) + 1j * rng.normal(size=4000))
        verdict = run(AdaptiveRule(0.05, 1, modes=0), z)
        assert verdict.status == CONVERGED
        assert verdict.uncertainty <= 0.05e-2 * abs(complex(verdict.p, verdict.q))
        covered += abs(complex(verdict.p, verdict.q) - zinf) <= verdict.uncertainty
    assert 0.91 <= covered / trials <= 0.985


def test_every_criterion_is_constructible_and_unknown_ones_are_refused() -> None:
    for name in CRITERIA:
        assert make_rule(name, tolerance_percent=0.01, skip_periods=1, window=5).name == name
    with pytest.raises(ValueError, match="unknown criterion"):
        make_rule("median", tolerance_percent=0.01, skip_periods=1, window=5)
