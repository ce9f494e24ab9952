"""Stopping rules on synthetic coefficient sequences with known limits."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bodebench.core.fourier import PeriodIntegrator
from bodebench.core.rules import (
    BELOW_RESOLUTION,
    CAPPED,
    CONVERGED,
    CRITERIA,
    NOISE_LIMITED,
    AdaptiveRule,
    ModalFit,
    SeriesHistory,
    adaptive,
    extrapolate_modes,
    least_squares,
    make_rule,
    relative_change_percent,
    settled_estimate,
)
from bodebench.core.rules.modal import _forecast, _modal_fit
from bodebench.sim.plants import CoulombOscillator, FirstOrderLag, LinearOscillator, Plant


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
    for a, b in [(0, 700), (5, 9), (350, 699)]:
        w = z[a:b]
        assert hist.scatter(a, b) == pytest.approx(np.sum(np.abs(w - w.mean()) ** 2), rel=1e-9)
        d = w - w.mean()
        direct = abs(np.sum(d[1:] * np.conj(d[:-1]))) / np.sum(np.abs(d) ** 2)
        assert hist.lag_correlation(a, b) == pytest.approx(direct, rel=1e-9, abs=1e-12)


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
    window, skip = 5, 1
    stops = {name: run(make_rule(name, tolerance_percent=1e-9, skip_periods=skip, window=window), z).period
             for name in ("none", "local", "combined1")}
    assert stops["none"] == 20                # P(19) is the ramp's last value, 2.0, and P(20) repeats it
    assert stops["local"] == 19 + window      # means of the last l at n and n-1 agree once both windows are constant
    assert stops["combined1"] == 18 + window  # P(n) equals the mean of the last l once those l are constant


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
    fit = extrapolate_modes(z[20:50], 2)
    assert fit is not None
    assert abs(fit.limit - zinf) < 1e-9
    assert fit.residual < 1e-9
    # the recurrence forecasts the periods it has not seen
    assert np.max(np.abs(fit.forecast(9) - z[50:59])) < 1e-9


def test_the_fit_recovers_the_limit_of_an_exact_two_mode_sequence_to_round_off() -> None:
    """Exact sequences Z(i) = Z_inf + a lambda_1**i + b lambda_2**i (a damped rotating pair, two real modes, an
    alternating and a real one; transients from 1e-3 to 10 times |Z_inf|; windows of 8 to 60): the two-mode fit's
    limit is Z_inf to round-off. (A least-squares solve that cuts the rank at a singular value it takes for
    round-off, as lstsq's SVD does on this design's mixed scales, left errors up to 1e-7 of |Z_inf| here.)"""
    rng = np.random.default_rng(1)
    fitted = 0
    for _ in range(600):
        n = int(rng.integers(8, 61))
        zinf = complex(rng.normal(), rng.normal()) * 10 ** rng.uniform(-6, 0)
        kind = int(rng.integers(0, 3))
        if kind == 0:
            lams = [rng.uniform(0.3, 0.95) * np.exp(1j * rng.uniform(0.05, 3.0))]
            lams.append(np.conj(lams[0]))
        elif kind == 1:
            lams = list(rng.uniform(0.1, 0.95, 2))
        else:
            lams = [-rng.uniform(0.2, 0.9), rng.uniform(0.2, 0.9)]
        amplitude = 10 ** rng.uniform(-3, 1) * abs(zinf)
        i = np.arange(1, n + 1)
        z = zinf + sum(complex(rng.normal(), rng.normal()) * amplitude * lam ** i for lam in lams)
        fit = extrapolate_modes(z, 2)
        if fit is None:  # a mode that has not decayed over a short window
            continue
        fitted += 1
        assert abs(fit.limit - zinf) <= 1e-12 * abs(zinf), (n, kind, amplitude / abs(zinf))
    assert fitted > 500


@pytest.mark.parametrize("bad", [complex(math.nan, 0.0), complex(0.0, math.inf), complex(-math.inf, math.nan)])
@pytest.mark.parametrize("where", [0, 11, -1])
def test_a_window_with_a_value_that_is_not_finite_has_no_limit(bad: complex, where: int,
                                                               capfd: pytest.CaptureFixture[str]) -> None:
    """A value that is not a number or infinite anywhere in the window: no fit and no limit, and nothing said on
    the terminal (LAPACK, handed such a matrix, may print a complaint or return zeros as if it had solved it)."""
    i = np.arange(1, 25)
    z = (0.3 - 0.7j + 0.5 * (0.8 * np.exp(0.4j)) ** i).astype(complex)
    z[where] = bad
    assert extrapolate_modes(z, 2) is None
    assert extrapolate_modes(z, 1) is None
    assert capfd.readouterr() == ("", "")


def test_a_history_knows_which_stretches_hold_only_finite_values(capfd: pytest.CaptureFixture[str]) -> None:
    """SeriesHistory.all_finite against numpy's isfinite over every stretch of a series with a NaN and an inf in
    it (before them: True; any stretch after the first: False, the running sums being spoilt from there on), and
    the default rule checking such a series period by period: no fit handed to LAPACK, nothing on the terminal."""
    i = np.arange(1, 81)
    z = (0.3 - 0.7j + 0.5 * (0.8 * np.exp(0.4j)) ** i).astype(complex)
    z[40], z[55] = complex(math.nan, 0.0), complex(0.0, math.inf)
    for pieces in ([80], [1] * 80):
        hist = SeriesHistory()
        for chunk in np.split(z, np.cumsum(pieces)[:-1]):
            hist.extend(chunk)
        for a in range(80):
            for b in range(a + 1, 81):
                assert hist.all_finite(a, b) == (b <= 40), (a, b)
    rule = AdaptiveRule(0.01, 1)
    hist = SeriesHistory()
    for n in range(1, 81):
        hist.append(z[n - 1])
        rule.check(hist, n, 1.0)
    assert capfd.readouterr() == ("", "")


def test_extrapolation_refuses_a_beat_that_never_decays() -> None:
    i = np.arange(1, 200)
    z = 1.0 + 0.5 * np.exp(0.05j * i)  # conservative link: a mode on the unit circle
    assert extrapolate_modes(z[100:200], 2) is None


@pytest.mark.parametrize("lam,w", [(0.95, 10), (0.92, 7), (0.98, 30)])
def test_a_fit_refused_for_a_slow_mode_says_how_long_a_window_that_mode_needs(lam: float, w: int) -> None:
    """A window of an exact two-mode transient whose slow mode keeps more than half of itself over it: refused,
    with the window over which lambda**w' = 1/2 (w' = ln 0.5 / ln lambda); a growing mode needs an infinite one,
    and an accepted fit none."""
    i = np.arange(1, 200)
    z = (0.3 - 0.7j) + (0.5 + 0.1j) * lam ** i + (0.2 - 0.3j) * 0.4 ** i
    fit, needed = _modal_fit(z[10:10 + w], 2, 0.5)
    assert fit is None
    assert needed == pytest.approx(math.log(0.5) / math.log(lam), rel=1e-6)
    fit, needed = _modal_fit(z[10:10 + math.ceil(needed) + 2], 2, 0.5)
    assert fit is not None and needed == 0.0
    growing = (0.3 - 0.7j) + (0.5 + 0.1j) * 1.02 ** i + (0.2 - 0.3j) * 0.4 ** i
    assert _modal_fit(growing[10:30], 2, 0.5) == (None, math.inf)


def count_fits(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """A one-element list that counts the modal fits made from now on."""
    made = [0]
    fit = adaptive._modal_fit

    def counted(z: np.ndarray, modes: int, max_decay: float, finite: bool = False):  # type: ignore[no-untyped-def]
        made[0] += 1
        return fit(z, modes, max_decay, finite)

    monkeypatch.setattr(adaptive, "_modal_fit", counted)
    return made


def test_fits_refused_for_a_slow_mode_are_put_off_without_moving_the_stop(monkeypatch: pytest.MonkeyPatch) -> None:
    """Exact transients with a slow mode (refused until the windows are long enough) and the friction link far above
    resonance (the same): with fits put off, the verdict is the one the rule making every scheduled fit gives, to
    the bit, from at most half its fits. Where fits pass at isolated periods (faint noise on a fast oscillator
    far above resonance; a mode near -1, or three modes fitted with two, whose fitted rates wander), nothing is
    put off that would move the stop."""
    i = np.arange(1, 3001)
    saved = [((0.3 - 0.7j) + (0.5 + 0.1j) * lam ** i + (0.2 - 0.3j) * 0.4 ** i, 0.01) for lam in (0.93, 0.95, 0.97)]
    friction = CoulombOscillator(2.533e-4, 1.0, 0.008)
    saved += [(simulated(friction, ratio * friction.natural_frequency_hz, 0.01)[:, 0], 0.01) for ratio in (8.0, 10.0)]
    kept = []
    for zeta in (0.01, 0.05):
        plant = LinearOscillator(2.533e-4, 1.0, zeta)
        f = 10.0 * plant.natural_frequency_hz
        steady = abs(simulated(plant, f, 0.01)[-1, 0])
        kept.append((simulated(plant, f, 0.01, noise=1e-5 * steady * math.sqrt(STEPS), seed=1)[:, 0], 0.01))
    alternating = (0.9066 - 0.2636j) + (0.0445 - 0.0354j) * (-0.99619 + 1e-4j) ** i
    for seed in range(8):
        rng = np.random.default_rng(seed)
        kept.append((alternating + 1e-6 * (rng.normal(size=i.size) + 1j * rng.normal(size=i.size)), 0.001))
    three = (1.084 + 1.043j) + (0.380 + 0.123j) * (0.653 - 0.460j) ** i + (-0.016 - 0.004j) * 0.966 ** i \
        + (-0.022 - 0.031j) * 0.924 ** i
    rng = np.random.default_rng(0)
    kept.append((three + 1e-9 * (rng.normal(size=i.size) + 1j * rng.normal(size=i.size)), 0.1))
    made = count_fits(monkeypatch)
    for k, (z, eps) in enumerate(saved + kept):
        reference = np.maximum.accumulate(np.abs(z))
        counts = []
        verdicts = []
        for fit_delay in (0, 2):
            made[0] = 0
            verdicts.append(replay(z, reference, eps, screened=True, chunk=256, fit_delay=fit_delay))
            counts.append(made[0])
        every, put_off = verdicts
        assert every.method == "extrapolated"
        assert put_off == every
        if k < len(saved):
            assert counts[1] <= 0.5 * counts[0], counts


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
    more (an interval too wide) nor far fewer (stopping on a spread that happened to be low); and at most about 2 %
    of the converged points are more than eps off (the stop takes the noise disc at 98 %)."""
    rng = np.random.default_rng(7)
    zinf, sigma, covered, beyond, trials = 1.0 - 1.0j, 2e-3, 0, 0, 400
    for _ in range(trials):
        z = zinf + sigma * (rng.normal(size=4000) + 1j * rng.normal(size=4000))
        verdict = run(AdaptiveRule(0.05, 1, modes=0), z)
        assert verdict.status == CONVERGED
        assert verdict.uncertainty <= 0.05e-2 * abs(complex(verdict.p, verdict.q))
        error = abs(complex(verdict.p, verdict.q) - zinf)
        covered += error <= verdict.uncertainty
        beyond += error > 0.05e-2 * abs(zinf)
    assert 0.92 <= covered / trials <= 0.98
    assert beyond / trials <= 0.025


def test_every_criterion_is_constructible_and_unknown_ones_are_refused() -> None:
    for name in CRITERIA:
        assert make_rule(name, tolerance_percent=0.01, skip_periods=1, window=5).name == name
    with pytest.raises(ValueError, match="unknown criterion"):
        make_rule("median", tolerance_percent=0.01, skip_periods=1, window=5)
    with pytest.raises(ValueError, match="fit_delay must be >= 0, got -1"):
        AdaptiveRule(0.01, 1, fit_delay=-1)


def error_in_eps(verdict, zinf: complex, eps: float) -> float:
    return abs(complex(verdict.p, verdict.q) - zinf) / abs(zinf) / (eps / 100)


@pytest.mark.parametrize("tau,amplitude", [(110.0, 2.2e-3), (400.0, 1e-2), (40.0, 0.5)])
def test_a_slow_monotone_transient_is_not_taken_for_a_plateau(tau: float, amplitude: float) -> None:
    """The friction link's slow drift of Fbar 0.95 at 10 f_n: Z(i) = Z_inf (1 + a exp(-i / tau)), changing by far
    less than eps per period from the first one. A rule may stop only once the drift is seen to die."""
    i = np.arange(1, 20001)
    zinf = -1.8e-7 - 6.9e-7j
    z = zinf * (1 + amplitude * np.exp(-i / tau))
    for eps in (0.01, 0.1):
        verdict = run(AdaptiveRule(eps, 1), z)
        assert verdict.status == CONVERGED
        assert error_in_eps(verdict, zinf, eps) <= 1.0
        assert verdict.period > tau  # the drift was watched for longer than its own time constant


def test_a_transient_aliased_by_the_batches_is_not_averaged_away() -> None:
    """An oscillator at exactly 5 f_n: its free oscillation turns 72 degrees per period, so any window of a
    multiple of 5 periods averages it to nearly nothing while it decays over hundreds of periods."""
    i = np.arange(1, 20001)
    lam = math.exp(-2 * math.pi * 0.003 / 5) * np.exp(2j * math.pi / 5)
    zinf = 0.03 - 0.001j
    z = zinf + 0.03 * lam ** i + 0.01 * np.conj(lam) ** i
    for rule in (AdaptiveRule(0.01, 1), AdaptiveRule(0.01, 1, modes=0)):
        verdict = run(rule, z)
        assert verdict.status == CONVERGED
        assert error_in_eps(verdict, zinf, 0.01) <= 1.0


def test_a_drift_that_never_ends_is_capped_not_converged() -> None:
    i = np.arange(1, 5001)
    z = (1.0 + 0.5j) * (1 + 1e-5 * i)  # grows by 1e-5 per period for ever
    verdict = run(AdaptiveRule(0.01, 1, max_periods=5000), z)
    assert verdict.status == CAPPED
    assert not verdict.within_eps


def test_noise_beyond_the_budget_ends_noise_limited_early_with_the_periods_it_would_need() -> None:
    rng = np.random.default_rng(11)
    zinf, sigma = 1.0 + 1.0j, 0.05
    z = zinf + sigma * (rng.normal(size=20000) + 1j * rng.normal(size=20000))
    verdict = run(AdaptiveRule(0.01, 1, max_periods=20000), z)
    assert verdict.status == NOISE_LIMITED
    assert verdict.period < 2000  # judged hopeless early, not after the whole budget
    assert not verdict.converged and not verdict.within_eps
    # the disc shrinks as 1/sqrt(n): reaching eps/100 |Z| takes (U / tol)^2 times the periods spent, U the disc at
    # the stop's 98 % level: the stated 95 % disc times the ratio of the two chi-square(2) quantiles (the
    # degrees of freedom of so many periods are many)
    tol = 1e-4 * abs(zinf)
    from scipy import stats

    stop_over_stated = stats.chi2.ppf(0.98, 2) / stats.chi2.ppf(0.95, 2)
    assert verdict.periods_needed == pytest.approx(
        verdict.period * (verdict.uncertainty / tol) ** 2 * stop_over_stated, rel=0.01)
    assert verdict.periods_needed > 2 * 20000
    assert abs(complex(verdict.p, verdict.q) - zinf) <= verdict.uncertainty


def test_the_settled_estimate_is_purely_statistical_when_no_drift_is_seen() -> None:
    rng = np.random.default_rng(5)
    hist = SeriesHistory()
    hist.extend(2.0 + 0.01 * (rng.normal(size=4001) + 1j * rng.normal(size=4001)))
    est = settled_estimate(hist, 1, 4001)
    assert est.bounded and est.white and est.bias == 0.0
    # three of four blocks averaged: sigma/sqrt(3000) per component, the 95 % disc radius ~2.45 of those
    assert est.uncertainty == pytest.approx(2.4477 * 0.01 / math.sqrt(3000), rel=0.1)
    assert est.uncertainty_1d == pytest.approx(1.96 * 0.01 / math.sqrt(3000), rel=0.1)


def test_a_point_ended_by_its_budget_states_the_periods_own_spread_and_one_that_stops_the_larger() -> None:
    """White periods whose eight batch means a block happen to scatter more than the periods predict (within the
    white test's factor 2). A point that stops on its spread states the batch means' spread with its 42 degrees of
    freedom (at the stop a spread is more often low than high), the stop's own; one that ends for its budget
    (noise-limited, capped) was not chosen by its spread and states the periods' own with their 6 (L - 1), which
    the larger of the two overstates. Both worked out here from the definitions with scipy's quantiles."""
    from scipy import stats

    length = 64
    for seed in range(50):
        rng = np.random.default_rng(seed)
        z = 1.0 + 0.01 * (rng.normal(size=1 + 4 * length) + 1j * rng.normal(size=1 + 4 * length))
        blocks = z[1 + length:].reshape(3, length)
        period_var = np.sum(np.abs(blocks - blocks.mean(axis=1, keepdims=True)) ** 2) / (6 * (length - 1))
        batches = blocks.reshape(3, 8, length // 8).mean(axis=2)
        batch_var = np.sum(np.abs(batches - blocks.mean(axis=1, keepdims=True)) ** 2) * (length // 8) / 42
        if period_var < batch_var < 1.5 * period_var:
            break
    assert period_var < batch_var  # a seed found where the two differ
    hist = SeriesHistory()
    hist.extend(z)
    assert hist.lag_correlation(1 + length, 1 + 4 * length) <= 2.0 / math.sqrt(3 * length)  # no inflation
    for ended_by_budget, var, dof in ((False, batch_var, 42), (True, period_var, 6 * (length - 1))):
        est = settled_estimate(hist, 1, 1 + 4 * length, ended_by_budget)
        assert est.white and est.bias == 0.0 and est.value == pytest.approx(blocks.mean(), rel=1e-12)
        sigma = math.sqrt(var / (3 * length))
        assert est.uncertainty == pytest.approx(math.sqrt(2 * stats.f.ppf(0.95, 2, dof)) * sigma, rel=1e-9)
        assert est.uncertainty_1d == pytest.approx(stats.t.ppf(0.975, dof) * sigma, rel=1e-9)
        stop = math.sqrt(2 * stats.f.ppf(0.98, 2, 42) * batch_var / (3 * length))
        assert est.stop_statistical == pytest.approx(stop, rel=1e-9)


def test_printed_rules_carry_the_honest_uncertainty_and_flag_a_stop_outside_their_eps() -> None:
    """Full averaging from n_k = 1 on a decaying transient: it stops with an error far above eps; the verdict's
    uncertainty, taken from the same history, covers that error and says it is outside eps."""
    i = np.arange(1, 5001)
    zinf = 1.0 - 0.5j
    z = zinf + 0.5 * 0.9 ** i
    verdict = run(make_rule("full", tolerance_percent=0.01, skip_periods=1, window=5), z)
    assert verdict.status == CONVERGED  # the printed rule's own word
    assert error_in_eps(verdict, zinf, 0.01) > 2
    assert not verdict.within_eps
    assert abs(complex(verdict.p, verdict.q) - zinf) <= verdict.uncertainty
    honest = run(AdaptiveRule(0.01, 1), z)
    assert honest.within_eps and error_in_eps(honest, zinf, 0.01) <= 1


def test_history_sums_do_not_depend_on_how_the_periods_arrive() -> None:
    """Periods one at a time, in small and in large chunks: the same running sums, lag-2 products included."""
    rng = np.random.default_rng(2)
    z = 3.0 + rng.normal(size=400) + 1j * rng.normal(size=400)
    d = z - z[0]
    lag2 = np.concatenate([[0, 0, 0], np.cumsum(d[2:] * np.conj(d[:-2]))])
    for sizes in ([400], [1] * 400, [1, 2, 3, 7, 9, 378], [8] * 50):
        hist = SeriesHistory()
        for chunk in np.split(z, np.cumsum(sizes)[:-1]):
            hist.extend(chunk)
        assert hist.n == 400
        assert np.array_equal(np.array(hist._lag2_list), hist.arrays()[4][:401])  # the list and the array agree
        assert np.allclose(hist._lag2_list, lag2, rtol=1e-12, atol=1e-9)
        assert hist.mean(17, 301) == pytest.approx(z[17:301].mean(), rel=1e-12)
        assert hist.scatter(100, 200) == pytest.approx(np.sum(np.abs(z[100:200] - z[100:200].mean()) ** 2), rel=1e-9)


# --- the screened rule against the rule that runs every analysis at every period, on simulated series ---

STEPS = 50          # integration steps per period of the battery
SIDE_HARMONICS = (1, 3)
SIDE_PERIODS = 3000  # max_periods of the battery


def simulated(plant: Plant, frequency_hz: float, amplitude: float, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """Per-period coefficients (periods, harmonics 1 and 3) of the plant's first output from rest under
    amplitude * sin(2 pi f t), with white noise of standard deviation ``noise`` (output units) on every sample."""
    h = 1.0 / (STEPS * frequency_hz)
    y = plant.run_sine(plant.initial_state(), 0.0, h, SIDE_PERIODS * STEPS, amplitude, frequency_hz)[:, 0]
    if noise:
        y = y + np.random.default_rng(seed).normal(0.0, noise, y.size)
    t = np.arange(y.size + 1) * h
    p, q = PeriodIntegrator(frequency_hz, SIDE_HARMONICS, 1).feed(t, np.concatenate([[0.0], y])[:, None])
    return (p + 1j * q)[:, 0, :]


def replay(z: np.ndarray, reference: np.ndarray, eps: float, screened: bool, chunk: int, fit_delay: int = 2):
    """The adaptive rule on one series, the history growing by ``chunk`` periods at a time, checked every period."""
    rule = AdaptiveRule(eps, 1, max_periods=SIDE_PERIODS, screened=screened, fit_delay=fit_delay)
    hist = SeriesHistory()
    for n in range(1, z.size + 1):
        if n > hist.n:
            hist.extend(z[hist.n:hist.n + chunk])
        verdict = rule.check(hist, n, float(reference[n - 1]))
        if verdict is None and n >= SIDE_PERIODS:
            verdict = rule.capped(hist, n, float(reference[n - 1]))
        if verdict is not None:
            return verdict
    raise AssertionError("no verdict at max_periods")


def side_by_side(z: np.ndarray, eps: float, exact: np.ndarray | None) -> tuple[list[tuple[str, str]], list[bool]]:
    """Every-period and screened verdicts on each harmonic of one simulated series.

    The every-period rule makes every analysis at every period of its schedule (no screen, no fit put off); the
    screened rule runs on a history filled 256 periods at a time (screens worked out for many periods at
    once) and on one filled period by period (one at a time). Returns the (status, method) of each verdict and,
    where the response is known, whether each stated disc holds it (to the round-off of the simulation)."""
    reference = np.max(np.abs(z), axis=1)  # the channel's largest coefficient, as the Autointegrator passes it
    scale = float(np.max(reference))
    seen, covered = [], []
    for k in range(z.shape[1]):
        every = replay(z[:, k], reference, eps, screened=False, chunk=256, fit_delay=0)
        for chunk in (256, 1):
            screened = replay(z[:, k], reference, eps, screened=True, chunk=chunk)
            assert every.period <= screened.period <= every.period + 2
            assert (screened.status, screened.method, screened.within_eps) == (every.status, every.method,
                                                                                every.within_eps)
            gap = abs(complex(screened.p, screened.q) - complex(every.p, every.q))
            if screened.period == every.period:  # the same analysis of the same periods, to round-off
                assert gap <= 1e-9 * scale + 1e-9 * abs(complex(every.p, every.q))
                assert screened.uncertainty == pytest.approx(every.uncertainty, rel=1e-6, abs=1e-9 * scale,
                                                             nan_ok=True)
            else:
                assert gap <= every.uncertainty + screened.uncertainty
            if exact is not None and screened.status in (CONVERGED, BELOW_RESOLUTION):
                error = abs(complex(screened.p, screened.q) - exact[k])
                covered.append(bool(error <= screened.uncertainty + 1e-11 * abs(exact[0])))
        seen.append((every.status, every.method))
    return seen, covered


LINEAR_DAMPING = (0.001, 0.01, 0.05, 0.2, 0.7)
LINEAR_RATIOS = (0.1, 0.5, 0.97, 1.0, 2.0, 10.0)
LAG_RATIOS = (0.1, 1.0, 10.0)
FRICTION_FBARS = (0.2, 0.6, 0.8, 0.95)
FRICTION_RATIOS = (0.5, 1.0, 2.0, 10.0)
# (noise, as a fraction of the steady amplitude; eps, %; seeds). Faint noise puts the modal fit's residual and
# prediction error near its tolerance, where its screens decide.
NOISE_SETTINGS = {"clean": (0.0, 0.01, (0,)), "faint": (1e-4, 0.01, (4, 5)), "noisy": (3e-3, 0.1, (1, 2)),
                  "noisy tight": (3e-3, 0.01, (3,))}


def battery(family: str) -> list[tuple[Plant, float, float, np.ndarray | None]]:
    """(plant, f, input amplitude, exact response per harmonic or None) of one plant family."""
    cases: list[tuple[Plant, float, float, np.ndarray | None]] = []
    if family == "linear":
        mass, stiffness, amplitude = 0.37, 5.3, 0.7
        fn = math.sqrt(stiffness / mass) / (2 * math.pi)
        for zeta in LINEAR_DAMPING:
            for ratio in LINEAR_RATIOS:
                plant = LinearOscillator(mass, stiffness, zeta)
                g = complex(plant.frequency_response(np.array([ratio * fn]))[0, 0])
                cases.append((plant, ratio * fn, amplitude, np.array([amplitude * g, 0.0])))
    elif family == "lag":
        tau, gain, amplitude = 0.05, 2.5, 0.3
        for ratio in LAG_RATIOS:
            plant = FirstOrderLag(tau, gain)
            f = ratio / (2 * math.pi * tau)
            g = complex(plant.frequency_response(np.array([f]))[0, 0])
            cases.append((plant, f, amplitude, np.array([amplitude * g, 0.0])))
    else:
        mass, stiffness, amplitude = 2.533e-4, 1.0, 0.01
        for fbar in FRICTION_FBARS:
            for ratio in FRICTION_RATIOS:
                plant = CoulombOscillator(mass, stiffness, fbar * amplitude)
                cases.append((plant, ratio * plant.natural_frequency_hz, amplitude, None))
    return cases


@pytest.mark.slow
@pytest.mark.parametrize("setting", list(NOISE_SETTINGS))
@pytest.mark.parametrize("family", ["linear", "lag", "friction"])
def test_the_screened_rule_stops_where_the_every_period_rule_stops(family: str, setting: str) -> None:
    """The screens skip only analyses that cannot give a verdict, and a fit is put off for a slow mode by two
    periods at most: over linear oscillators (damping 0.001..0.7 at 0.1..10 f_n), first-order lags and the
    Coulomb friction link (Fbar 0.2..0.95 at 0.5..10 f_n), simulated from rest, clean and with white noise on
    every sample (several seeds), the screened rule stops within two periods of the rule that runs everything
    at every period of its schedule, with the same status and, to round-off, the same value and uncertainty;
    where the response is known exactly, the stated uncertainty covers it (with noise, at about its 95 %
    level)."""
    noise_relative, eps, seeds = NOISE_SETTINGS[setting]
    seen: set[tuple[str, str]] = set()
    covered: list[bool] = []
    for plant, f, amplitude, exact in battery(family):
        clean = simulated(plant, f, amplitude)
        steady = abs(clean[-1, 0])
        for seed in seeds:
            z = simulated(plant, f, amplitude, noise_relative * steady, seed) if noise_relative else clean
            kinds, holds = side_by_side(z, eps, exact)
            seen.update(kinds)
            covered += holds
    if noise_relative == 0.0:
        assert all(covered)  # no noise: the stated disc holds the exact response at every converged point
    elif covered:
        assert np.mean(covered) >= 0.85  # noise: 95 % discs, over a few dozen points
    statuses = {status for status, _ in seen}
    methods = {method for _, method in seen}
    # the battery reaches the verdicts the screens guard
    if family != "lag":
        assert CONVERGED in statuses and "settled mean" in methods
    if family == "friction" and setting == "clean":
        assert CAPPED in statuses and "extrapolated" in methods
    if family == "linear" and setting == "clean":
        assert BELOW_RESOLUTION in statuses and "extrapolated" in methods
    if setting == "faint" and family != "lag":
        assert "extrapolated" in methods and "settled mean" in methods
    if setting == "noisy tight" and family != "lag":
        assert NOISE_LIMITED in statuses


def test_modal_forecast_is_the_recurrence_as_scipy_filters_it() -> None:
    """The modal fit's forecast against scipy.signal.lfilter running the same recurrence: bit for bit."""
    from scipy.signal import lfilter

    rng = np.random.default_rng(7)
    for _ in range(100):
        order = int(rng.integers(1, 4))
        alpha = rng.uniform(-0.6, 0.6, order)
        last = rng.normal(size=order) + 1j * rng.normal(size=order)
        limit = complex(rng.normal(), rng.normal())
        steps = int(rng.integers(1, 2000))
        past = [complex(v) - limit for v in last[::-1]]
        zi = np.array([sum(alpha[m + k] * past[k] for k in range(order - m)) for m in range(order)], dtype=complex)
        expected = limit + lfilter([1.0], np.concatenate([[1.0], -alpha]), np.zeros(steps, dtype=complex), zi=zi)[0]
        assert np.array_equal(_forecast(last, alpha, limit, steps), expected)


def test_forecast_error_is_the_largest_distance_of_the_forecast_from_what_followed() -> None:
    """ModalFit.forecast_error against the forecast array the fit makes (ModalFit.forecast): the same recurrence,
    the same largest |forecast - value| (to the last bit of numpy's complex abs), NaN where the forecast is not
    a number; and for a window settled to round-off, the distance from its mean."""
    rng = np.random.default_rng(5)
    checked = 0
    for _ in range(400):
        n = int(rng.integers(8, 60))
        i = np.arange(1, 2 * n + 1)
        lam = rng.uniform(0.3, 0.98) * np.exp(1j * rng.uniform(0.0, 3.0))
        z = complex(rng.normal(), rng.normal()) + complex(rng.normal(), rng.normal()) * lam ** i
        z = z + 10 ** rng.uniform(-12, -3) * (rng.normal(size=i.size) + 1j * rng.normal(size=i.size))
        fit = extrapolate_modes(z[:n], 2)
        if fit is None:
            continue
        expected = float(np.max(np.abs(fit.forecast(n) - z[n:])))
        assert fit.forecast_error(z[n:]) == pytest.approx(expected, rel=4 * np.finfo(float).eps)
        checked += 1
    assert checked > 300
    flat = np.full(12, 1.0 + 2.0j)
    settled = extrapolate_modes(flat, 2)
    assert settled is not None and settled.alpha == ()
    assert settled.forecast_error(np.array([1.0 + 2.0j, 1.5 + 2.0j])) == 0.5
    assert math.isnan(settled.forecast_error(np.array([1.0 + 2.0j, complex(math.nan, 0.0)])))
    # nothing followed: no distance, whatever the number of modes
    for alpha in ((), (0.5,), (0.5, 0.25), (0.5, 0.25, -0.1)):
        fit = ModalFit(1.0 + 0.0j, 0.0, alpha, tuple([1.0 + 0.0j] * len(alpha)))
        assert fit.forecast_error(np.array([], dtype=complex)) == 0.0


def test_student_t_factor_is_scipy_stats_quantile() -> None:
    from scipy import stats

    from bodebench.core.rules.intervals import _line_factor

    for dof in (1, 2, 3, 5, 7, 10, 31, 100, 1000, 100_000):
        for confidence in (0.9, 0.95, 0.99):
            assert _line_factor(dof, confidence) == pytest.approx(float(stats.t.ppf(0.5 + confidence / 2, dof)),
                                                                  rel=1e-12)



@pytest.mark.parametrize("lam", [0.5, 0.7, 0.9])
def test_extrapolation_refuses_a_window_that_steps_at_its_end(lam: float) -> None:
    """A window settled to 1e-10 but for a step of 5e-3 in its last value (a glitch): the fitted mode grows by a
    factor so large that its 63rd power overflows a float; the fit is refused (no mode decayed), not raised."""
    limit = -0.0887948951 + 0.0821375646j
    z = limit + 1e-10 * (1 + 0.3j) * lam ** np.arange(63)
    z[-1] = limit + 0.005
    assert extrapolate_modes(z, 2) is None


def test_a_clean_series_near_round_off_states_what_its_fit_leaves() -> None:
    """Two decaying modes on a limit of 5e-7, no noise, eps 5.4e-7 %: the tolerance is a few ulps of the values,
    so the fit's residual must be that of the solution the fit returns (the least-squares problem's own residual,
    orders of magnitude smaller for this badly scaled design, once stopped this series at period 29 with an
    error above both its stated uncertainty and the tolerance)."""
    limit = -5.321111325226112e-07 - 1.1659489346600915e-07j
    t = np.arange(600)
    z = limit + (-2.0959470479683976e-07 + 3.885990453520887e-08j) * 0.8505550967732581 ** t \
        + (-7.041964127625779e-07 + 9.853105694603568e-08j) * 0.9105022657738354 ** t
    eps = 5.391763802037627e-07
    verdict = run(AdaptiveRule(eps, 1, max_periods=600), z)
    error = abs(complex(verdict.p, verdict.q) - limit)
    assert verdict.status == CONVERGED
    assert error <= verdict.uncertainty
    assert error <= eps / 100 * abs(limit)


@pytest.mark.parametrize("modes", [1, 2, 3])
def test_the_fit_residual_is_the_rms_error_of_the_recurrence_it_returns(modes: int) -> None:
    """The modal fit's residual against the one-step errors of the recurrence it returns, worked out here with
    numpy from its alpha and limit (intercept = limit (1 - sum alpha)): their rms over the P and Q rows of the
    window, over |1 - sum alpha|. Windows of one to three decaying modes with noise well above round-off."""
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(150):
        n = int(rng.integers(2 * modes + 3, 80))
        i = np.arange(n)
        limit = complex(rng.normal(), rng.normal())
        z = np.full(n, limit)
        for _ in range(int(rng.integers(1, 4))):
            lam = rng.uniform(0.3, 0.95) * np.exp(1j * rng.uniform(-3.0, 3.0))
            z = z + complex(rng.normal(), rng.normal()) * lam ** i
        z = z + 1e-4 * (rng.normal(size=n) + 1j * rng.normal(size=n))
        fit, _ = _modal_fit(z, modes, 1.0)
        if fit is None or not fit.alpha:
            continue
        alpha = np.array(fit.alpha)
        den = 1.0 - alpha.sum()
        predicted = fit.limit * den + sum(alpha[r - 1] * z[modes - r:n - r] for r in range(1, modes + 1))
        errors = z[modes:] - predicted
        expected = math.sqrt(float(np.sum(np.abs(errors) ** 2)) / (2 * errors.size)) / abs(den)
        assert fit.residual == pytest.approx(expected, rel=1e-6)
        checked += 1
    assert checked > 100


def test_a_fit_whose_workspace_query_failed_is_solved_by_numpy_to_the_same_limit(monkeypatch: pytest.MonkeyPatch
                                                                                 ) -> None:
    """Where LAPACK's workspace query for a window length failed, the fit is solved by numpy's lstsq instead: the
    same limit and residual as dgelsy's (to 1e-12 on a well-conditioned window), the fit otherwise unchanged."""
    i = np.arange(40)
    z = (0.3 - 0.2j) + (0.5 + 0.1j) * (0.8 * np.exp(0.6j)) ** i + 0.2 * 0.6 ** i
    z = z + 1e-3 * np.random.default_rng(2).normal(size=(40, 2)) @ np.array([1.0, 1.0j])
    lapack_fit, _ = _modal_fit(z, 2, 0.5)
    design = least_squares._design(z.size, 2)
    monkeypatch.setitem(least_squares._DESIGNS, (z.size, 2), design._replace(lwork=0))
    numpy_fit, _ = _modal_fit(z, 2, 0.5)
    assert lapack_fit is not None and numpy_fit is not None
    assert abs(numpy_fit.limit - lapack_fit.limit) <= 1e-12 * abs(lapack_fit.limit)
    assert numpy_fit.residual == pytest.approx(lapack_fit.residual, rel=1e-9)
    assert numpy_fit.alpha == pytest.approx(lapack_fit.alpha, rel=1e-12)


def test_no_screen_spares_a_verdict_over_the_rule_tests() -> None:
    """The rule tests in a process with BODEBENCH_CHECK_SCREENS=1, where every AdaptiveRule runs the full analysis
    beside each screen that spared one and fails where that analysis gives a verdict: every test of this file and
    of test_friction_link.py but the slow battery, and of the battery the friction link with faint noise (where the
    fit's screens decide near its tolerance). Between them they reach every screen."""
    root = Path(__file__).resolve().parent.parent
    env = {key: value for key, value in os.environ.items()
           if not key.startswith("PYTEST_XDIST") and key != "PYTEST_CURRENT_TEST"}
    env[adaptive.CHECK_SCREENS_VARIABLE] = "1"
    selection = ("(not test_the_screened_rule_stops_where_the_every_period_rule_stops or friction-faint) "
                 "and not test_no_screen_spares_a_verdict_over_the_rule_tests")
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-k", selection,
                           "tests/test_rules.py", "tests/test_friction_link.py"],
                          cwd=root, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert " passed" in done.stdout and " deselected" in done.stdout
