"""What the bench's grid and surroundings do that no spread between periods shows: a disturbance line on a measured
harmonic, and a harmonic the sample rate folds onto one. Pure checks against the arithmetic of each effect, and the
whole chain with a simulated drive whose sensor picks up hum."""

from __future__ import annotations

import math
import tomllib
import uuid
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bodebench.core.autointegration import Autointegrator
from bodebench.core.benchgrid import (
    FOLD_IMAGES,
    FOLD_TURN,
    LINE_TURNS,
    MIN_BEAT_PERIODS,
    disturbance_lines,
    flag_disturbed,
    fold_beat,
    fold_bound,
    folding_harmonic,
    line_leak,
    lines_beyond_fit,
    lines_on_fit,
    lines_on_harmonics,
    move_off_disturbances,
    move_off_folds,
    turning_amplitude,
)
from bodebench.core.phase_average import PhaseAverage, waveform_fold_bound
from bodebench.core.response import ResponsePoint
from bodebench.core.rules import RESOLUTION
from bodebench.io.config import AnalysisConfig, parse_config
from bodebench.status import PointStatus


def test_mains_counts_with_its_second_and_third_harmonic() -> None:
    assert disturbance_lines([50.0]) == (50.0, 100.0, 150.0)
    assert disturbance_lines([50.0, 60.0]) == (50.0, 60.0, 100.0, 120.0, 150.0, 180.0)
    assert disturbance_lines([]) == ()


@pytest.mark.parametrize("f", [50.0, 50 / 3, 25.0, 100.0, 33.3, 49.5, 149.0 / 3])
def test_a_moved_plan_leaves_every_measured_harmonic_a_beat_of_at_most_the_limit_and_moves_little(f: float) -> None:
    lines = disturbance_lines([50.0])
    harmonics = (1, 2, 3)
    (g,), notes = move_off_disturbances([f], harmonics, lines)
    for k in harmonics:
        for d in lines:
            assert abs(d - k * g) * MIN_BEAT_PERIODS >= g * (1 - 1e-6), (f, g, k, d)
    assert abs(g / f - 1) <= 2.5 / 100
    assert bool(notes) == (g != f)


def test_a_frequency_clear_of_every_line_is_not_moved() -> None:
    frequencies = (2.0, 7.0, 12.0, 20.0, 31.0)
    assert move_off_disturbances(frequencies, (1, 3), disturbance_lines([50.0])) == (frequencies, ())


@pytest.mark.parametrize("rate, f, harmonics, expected", [
    (200.0, 8.0, (1, 2, 3), (22, 3)),  # 25 samples a period: 22 = 25 - 3
    (2000.0, 50.0, (1, 3), None),  # 40 samples: 37 folds onto 3, above the orders that are warned of
    (200.0, 11.0, (1, 3), None),  # 18.18 samples: nothing folds exactly
    (1000.0, 80.0, (1,), (24, 1)),  # 12.5 samples: two periods are 25 samples, and 25 - 1 = 24
])
def test_the_lowest_folding_harmonic_is_the_one_the_arithmetic_of_aliasing_gives(
        rate: float, f: float, harmonics: tuple[int, ...], expected: tuple[int, int] | None) -> None:
    found = folding_harmonic(rate, f, harmonics)
    if expected is None:
        assert found is None
        return
    j, k = found  # type: ignore[misc]
    # independently: sampled at the rate, harmonic j is indistinguishable from harmonic k (the same samples)
    t = np.arange(400) / rate
    np.testing.assert_allclose(np.cos(2 * np.pi * j * f * t), np.cos(2 * np.pi * k * f * t), atol=1e-6)
    assert k in harmonics and j > max(harmonics)
    for lower in range(max(harmonics) + 1, j):  # and no lower harmonic is
        assert not any(np.allclose(np.cos(2 * np.pi * lower * f * t), np.cos(2 * np.pi * kk * f * t), atol=1e-6)
                       for kk in harmonics)


def test_hum_on_a_measured_harmonic_converges_to_the_hum_and_is_flagged_while_off_harmonic_hum_is_not() -> None:
    """A linear response (harmonic 3 exactly zero) with 5 % hum at 50 Hz, measured at 50/3 Hz: harmonic 3 comes out as
    the hum itself with an interval of nothing, the failure no spread can show; flagged, it claims nothing."""
    f, rate, hum = 50.0 / 3.0, 2000.0, 0.05
    t = np.arange(0, int(60 / f * rate) + 1) / rate
    y = np.sin(2 * np.pi * f * t + 0.4) + hum * np.sin(2 * np.pi * 50.0 * t)
    sampler = Autointegrator(f, 1.0, ("y",), AnalysisConfig(harmonics=(1, 3), tolerance_percent=0.01), t0=0.0)
    sampler.feed(t, y[:, None])
    first, third = sampler.points()
    assert abs(complex(third.p, third.q)) == pytest.approx(hum, rel=1e-6) and third.uncertainty < 1e-9
    flagged = flag_disturbed([first, third], disturbance_lines([50.0]))
    assert flagged[0] == first  # harmonic 1 lies 33 Hz from every line
    assert flagged[1].status == PointStatus.DISTURBED and not flagged[1].converged and not flagged[1].within_eps


@pytest.mark.slow
def test_a_simulated_drive_with_hum_on_the_virtual_bus_flags_the_point_on_the_line_or_moves_it(tmp_path: Path) -> None:
    from bodebench.bench.procedure import SweepProcedure
    from bodebench.io.results import load_response

    def config(policy: str) -> dict:
        return {
            "plant": {"model": "lag", "time_constant": 0.01, "gain": 1.0},
            "excitation": {"amplitude": 0.01, "frequencies_hz": [50.0 / 3.0]},
            "analysis": {"harmonics": [1, 3], "tolerance_percent": 0.1, "disturbances": policy, "max_periods": 400},
            "bench": {"transport": "can", "rate_hz": 2000, "clock": "lockstep", "timebase": "counter"},
            "can": {"interface": "virtual", "channel": f"hum-{uuid.uuid4().hex[:8]}"},
            "safety": {"max_amplitude": 0.02, "watchdog_s": 5.0},
            "simulator": {"hum": 0.0002, "hum_hz": 50.0},
        }

    flagged = parse_config(config("flag"), "hum.toml")
    assert flagged.cases[0].disturbance_lines == (50.0, 100.0, 150.0)  # the simulated drive's own hum
    SweepProcedure(flagged, tmp_path / "flag").run()
    points = {p.harmonic: p for p in load_response(tmp_path / "flag")}
    assert points[3].status == PointStatus.DISTURBED and not points[3].converged
    assert points[1].converged
    # analysed again from its samples, the sweep flags the same point: the lines come from the stored configuration
    from bodebench.analysis.reanalyse import reanalyse
    assert [(p.harmonic, p.status, p.p) for p in reanalyse(tmp_path / "flag").response] == \
        [(p.harmonic, p.status, p.p) for p in load_response(tmp_path / "flag")]

    moved = parse_config(config("move"), "hum.toml")
    (g,) = moved.cases[0].excitation.frequencies_hz
    assert g != 50.0 / 3.0 and moved.cases[0].plan_notes
    SweepProcedure(moved, tmp_path / "move").run()
    points = {p.harmonic: p for p in load_response(tmp_path / "move")}
    assert points[1].frequency_hz == g
    assert points[3].status != PointStatus.DISTURBED
    # the hum now turns against harmonic 3 within 50 periods: a converged harmonic 3 holds the truth (zero, the lag
    # is linear) within its interval, and one that did not converge says so
    third = points[3]
    assert not third.converged or abs(complex(third.p, third.q)) <= third.uncertainty + 1e-3 * 0.1 / 100 * 0.01
    assert math.isfinite(third.uncertainty)


def aliased_frequency(frequency_hz: float, rate_hz: float) -> float:
    """Where a component at ``frequency_hz`` appears when sampled at ``rate_hz``: folded into [0, rate / 2]."""
    return abs((frequency_hz + rate_hz / 2) % rate_hz - rate_hz / 2)


@pytest.mark.parametrize("seed", range(6))
def test_a_plan_moved_off_folds_folds_no_harmonic_onto_a_measured_one_and_moves_little(seed: int) -> None:
    """Drawn rates and frequencies, many with a whole number of samples a period: after the move, every harmonic j
    up to FOLD_IMAGES x N, sampled, lands at least FOLD_TURN / m harmonics (m its image) from every measured harmonic
    (checked by folding each one, not by the mover's own arithmetic); a frequency moves by under half a sample a
    period."""
    rng = np.random.default_rng(seed)
    harmonics = (1, 2, 3)
    rates = 10 ** rng.uniform(2, 4, 20)
    samples = np.where(rng.random(20) < 0.5, rng.integers(24, 400, 20), rng.uniform(24, 400, 20))
    frequencies = rates / samples
    for rate, f in zip(rates, frequencies, strict=True):
        (g,), _ = move_off_folds(rate, [f], harmonics)
        n = rate / g
        assert abs(n - rate / f) <= 0.5 and g <= f * (1 + 1e-12) or g != f
        for j in range(max(harmonics) + 1, int(FOLD_IMAGES * n)):
            alias = aliased_frequency(j * g, rate)
            image = max(1, round(j * g / rate))
            for k in harmonics:
                assert abs(alias - k * g) >= g * FOLD_TURN / image * (1 - 1e-6), (rate, f, g, j, k)
    f = 1000.0 / 97.382  # a fraction of a sample a period far from every small denominator: nothing to move
    (g,), notes = move_off_folds(1000.0, [f], harmonics)
    assert g == f and notes == ()


def clipped_sine_coefficient(k: int, clip: float) -> complex:
    """Harmonic k (P + jQ, P with sin) of min(max(sin, -clip), clip) over one period, by an independent route:
    the trapezoid on 2**16 points a period of the exact waveform (error far below 1e-9 for its kinks' harmonics)."""
    t = np.arange(2**16) / 2**16
    y = np.clip(np.sin(2 * np.pi * t), -clip, clip)
    return complex(2 * np.mean(y * np.sin(2 * np.pi * k * t)), 2 * np.mean(y * np.cos(2 * np.pi * k * t)))


def test_a_saturated_drive_on_a_whole_grid_is_wrong_and_converged_and_moved_off_the_fold_it_is_right() -> None:
    """A drive saturating at 60 % of its swing, sampled at 69 samples a period: harmonics 67 and 71 fold exactly
    onto harmonic 2 (zero by symmetry), every period alike, and harmonic 2 converges to the folded value. At the
    frequency the plan moves it to, the folds turn and every converged claim holds."""
    rate, clip = 297.6, 0.6
    f = rate / 69
    analysis = AnalysisConfig(harmonics=(1, 2, 3), tolerance_percent=0.01)

    def measure(g: float) -> list:
        sampler = Autointegrator(g, 1.0, ("y",), analysis, t0=0.0)
        chunk, start = int(100 / g * rate), 0
        while not sampler.done:
            t = (start + np.arange(chunk)) / rate
            sampler.feed(t, np.clip(np.sin(2 * np.pi * g * t), -clip, clip)[:, None])
            start += chunk
        return sampler.points()

    truth = {k: clipped_sine_coefficient(k, clip) for k in (1, 2, 3)}
    floor = 1e-3 * abs(truth[1])  # the rule's absolute floor: the channel's largest coefficient

    def error_in_eps(point) -> float:
        tolerance = analysis.tolerance_percent / 100 * max(abs(truth[point.harmonic]), floor)
        return abs(complex(point.p, point.q) - truth[point.harmonic]) / tolerance

    second = measure(f)[1]
    assert second.converged and error_in_eps(second) > 100  # folded content taken for the response
    (g,), notes = move_off_folds(rate, [f], analysis.harmonics)
    assert g != f and len(notes) == 1 and abs(g / f - 1) < 0.5 / 69
    for point in measure(g):
        assert not point.converged or error_in_eps(point) <= 2.0, (point.harmonic, point.status, error_in_eps(point))


def test_the_loader_moves_a_bench_plan_off_folds_only_when_asked() -> None:
    def config(folds: str | None) -> dict:
        analysis = {"harmonics": [1, 3]} | ({"folds": folds} if folds else {})
        return {
            "plant": {"model": "lag", "time_constant": 0.01, "gain": 1.0},
            "excitation": {"amplitude": 0.01, "frequencies_hz": [5.0, 1000.0 / 97.382, 40.0]},
            "analysis": analysis,
            "bench": {"transport": "can", "rate_hz": 1000, "clock": "lockstep", "timebase": "counter"},
            "can": {"interface": "virtual", "channel": "folds"},
            "safety": {"max_amplitude": 0.02},
            "simulator": {},
        }

    bounded = parse_config(config(None), "folds.toml").cases[0]  # the default: bound, in every interval
    assert bounded.excitation.frequencies_hz == (5.0, 1000.0 / 97.382, 40.0)
    assert not any("folds exactly onto measured harmonic" in note for note in bounded.plan_notes)
    kept = parse_config(config("keep"), "folds.toml").cases[0]
    assert kept.excitation.frequencies_hz == (5.0, 1000.0 / 97.382, 40.0)
    # warned, not moved: 25 samples a period fold harmonic 22 onto 3
    assert any("folds exactly onto measured harmonic" in note for note in kept.plan_notes)
    moved = parse_config(config("move"), "folds.toml").cases[0]
    new = moved.excitation.frequencies_hz
    assert new[1] == 1000.0 / 97.382 and new[0] != 5.0 and new[2] != 40.0  # 200 and 25 samples a period moved
    assert all(fold_beat(1000.0, f) >= FOLD_TURN for f in new)
    assert any("2 of 3 frequencies moved" in note for note in moved.plan_notes)


def _clipped_sine(t: np.ndarray, f: float, level: float = 0.6) -> np.ndarray:
    """A saturating response: sin(2 pi f t) clipped at +-level (odd: its even harmonics are exactly zero)."""
    return np.clip(np.sin(2 * np.pi * f * t), -level, level)


def _harmonics_of_clipped_sine(orders: list[int], level: float = 0.6, points: int = 1 << 16) -> np.ndarray:
    """P + jQ (P multiplies sin, Q cos) of the clipped sine's harmonics, from the DFT of 2^16 samples of a period
    (its harmonics fall as 1/j^2: what that grid folds onto order 3 is below 1e-9)."""
    u = np.arange(points) / points
    spectrum = np.fft.rfft(np.clip(np.sin(2 * np.pi * u), -level, level)) * 2 / points
    return np.array([-spectrum[j].imag + 1j * spectrum[j].real for j in orders])


def test_a_wider_basis_takes_harmonics_above_the_measured_ones_exactly_on_a_jittered_grid() -> None:
    """Harmonics 1 .. 8 on a grid that fits no period (2.7 % jitter): solved with the measured 1 .. 3 alone, the
    others leak into them by the trapezoid's error; with the basis up to 8 every coefficient is exact, the measured
    ones and the eight above (kept in ``high``)."""
    from bodebench.core.fourier import ExactPeriodIntegrator

    rng = np.random.default_rng(7)
    f, rate = 3.7, 3.7 * 41.37
    z = rng.normal(size=8) + 1j * rng.normal(size=8)
    t = (np.arange(int(40 * rate / f)) + rng.uniform(-0.027, 0.027, int(40 * rate / f))) / rate - 0.5 / rate
    y = sum(z[j - 1].real * np.sin(2 * np.pi * j * f * t) + z[j - 1].imag * np.cos(2 * np.pi * j * f * t)
            for j in range(1, 9))
    narrow = ExactPeriodIntegrator(f, (1, 2, 3), 1, 0.0)
    p, q = narrow.feed(t, y)
    assert np.max(np.abs(p[:, 0] + 1j * q[:, 0] - z[:3])) > 1e-6  # the leak the wider basis removes
    wide = ExactPeriodIntegrator(f, (1, 2, 3), 1, 0.0, fit_order=8)
    p, q = wide.feed(t, y)
    assert wide.high_harmonics == (4, 5, 6, 7, 8)
    assert np.max(np.abs(p[:, 0] + 1j * q[:, 0] - z[:3])) < 1e-9
    assert np.max(np.abs(wide.high[:, 0] - z[3:])) < 1e-9


def test_a_fold_the_record_shows_widens_the_interval_and_ends_alias_limited() -> None:
    """A clipped sine sampled at 69 samples a period: harmonics 67 and 71 fold onto harmonic 2 (truly zero) the same
    in every period. Without the rate the sampler cannot know it and says converged with an interval that misses;
    with it and ``folds = "bound"`` (the default), the bound read from the record covers the fold and the point
    claims nothing (with ``folds = "keep"`` it stays as it was)."""
    f, n_per = 2.3, 69
    t = np.arange(60 * n_per + 1) / (n_per * f)
    y = _clipped_sine(t, f)[:, None]
    truth = _harmonics_of_clipped_sine([1, 2, 3])
    analysis = AnalysisConfig(harmonics=(1, 2, 3), tolerance_percent=0.01)
    blind = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0)
    blind.feed(t, y)
    second = blind.points()[1]
    assert second.converged and abs(complex(second.p, second.q) - truth[1]) > second.uncertainty
    kept = Autointegrator(f, 1.0, ("y",), replace(analysis, folds="keep"), t0=0.0, samples_per_period=n_per)
    kept.feed(t, y)
    kept_second = kept.points()[1]
    assert kept_second.converged and abs(complex(kept_second.p, kept_second.q) - truth[1]) > kept_second.uncertainty
    told = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0, samples_per_period=n_per)
    told.feed(t, y)
    for point, exact in zip(told.points(), truth, strict=True):
        assert abs(complex(point.p, point.q) - exact) <= point.uncertainty
    assert told.points()[1].status == PointStatus.ALIAS_LIMITED and not told.points()[1].converged


def test_a_linear_response_with_noise_gets_no_fold_bound() -> None:
    """Nothing above the measured harmonics but noise: what the noise leaves in their average keeps the bound far
    inside the tolerance, and the point converges as before."""
    rng = np.random.default_rng(3)
    f, rate = 4.1, 4.1 * 57.3
    t = np.arange(int(300 * rate / f)) / rate
    y = (np.sin(2 * np.pi * f * t + 0.3) + 1e-3 * rng.normal(size=t.size))[:, None]
    analysis = AnalysisConfig(harmonics=(1,), tolerance_percent=0.1, folds="bound")
    sampler = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0, samples_per_period=rate / f)
    sampler.feed(t, y)
    assert sampler.fold_bounds().max() < 0.01 * 1e-3  # 1 % of the tolerance's half-width, 0.1 % of |Z| = 1
    assert sampler.points()[0].status == PointStatus.CONVERGED


@pytest.mark.parametrize("samples", [150, 120, 64, 39])
@pytest.mark.parametrize("output", ["relay", "staircase"])
def test_an_output_with_steps_on_a_whole_grid_claims_nothing_it_does_not_hold(samples: int, output: str) -> None:
    """A relay (r sign(sin)) or a coarse quantiser's staircase, sampled a whole number of times a period: its
    spectrum falls only as 1/j, so the folds stand still on the measured harmonics and no averaging removes them.
    Against the exact coefficients (the relay's 4r/(pi m) on odd m; the staircase's from a fine grid of 2^16 points
    a period, which its steps do not fold onto harmonics 1-3 to 1e-9 of them), no harmonic that says converged
    is more than 2 eps off, and a converged one's interval holds the truth."""
    f, eps, phase = 5.657, 0.1, 4.78
    rate = samples * f
    if output == "relay":
        def signal(t: np.ndarray) -> np.ndarray:
            return 0.294 * np.sign(np.sin(2 * np.pi * f * t + phase))
    else:
        step = 0.0948 * 2 / 39  # 39 steps peak to peak
        def signal(t: np.ndarray) -> np.ndarray:
            return step * np.round(0.0948 * np.sin(2 * np.pi * f * t + phase) / step)
    fine = np.arange(1 << 16) / ((1 << 16) * f)
    spectrum = 2.0 * np.fft.rfft(signal(fine)) / fine.size
    truth = {k: complex(-spectrum[k].imag, spectrum[k].real) for k in (1, 2, 3)}  # p (sin) + i q (cos)
    analysis = AnalysisConfig(harmonics=(1, 2, 3), tolerance_percent=eps, max_periods=400, folds="bound")
    sampler = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0, samples_per_period=float(samples))
    t = (np.arange(int(410 * samples)) - 0.75) / rate  # t0 = 0 between two samples
    for point in _fed(sampler, t, signal(t)[:, None]):
        z = truth[point.harmonic]
        error = abs(complex(point.p, point.q) - z) / (eps / 100 * max(abs(z), RESOLUTION * abs(truth[1])))
        if point.converged:
            assert error <= 2.0, (point.harmonic, point.status, error)
            assert abs(complex(point.p, point.q) - z) <= point.uncertainty, (point.harmonic, error)


@pytest.mark.slow
def test_folds_bound_on_the_virtual_bus_marks_the_whole_grid_points_and_reanalysis_agrees(tmp_path: Path) -> None:
    """The friction link at 20 Hz sampled at 1 kHz (50 samples a period: its high harmonics fold exactly onto 1 and
    3) with ``folds = "bound"``: the sweep over the virtual bus ends its points ``alias_limited`` with the bound in
    their intervals (what folds is 0.2 x eps on harmonic 1 and 1.9 x eps on 3, against the fine grid of the test
    below: the default 1/j^2 errs large on this plant, whose harmonics fall as 1/j^3), and
    the analysis again from the samples, which reads the rate from the run's configuration, gives the same statuses
    and intervals."""
    from bodebench.analysis.reanalyse import reanalyse
    from bodebench.bench.procedure import SweepProcedure
    from bodebench.io.results import load_response

    data = {
        "plant": {"model": "coulomb", "mass": 2.533e-4, "stiffness": 1.0, "friction": 0.008},
        "excitation": {"amplitude": 0.01, "frequencies_hz": [20.0]},
        "analysis": {"harmonics": [1, 3], "tolerance_percent": 0.01, "folds": "bound", "max_periods": 400},
        "bench": {"transport": "can", "rate_hz": 1000, "clock": "lockstep", "timebase": "counter"},
        "can": {"interface": "virtual", "channel": f"folds-{uuid.uuid4().hex[:8]}"},
        "safety": {"max_amplitude": 0.02, "max_rate": 5.0, "watchdog_s": 5.0},
        "simulator": {},
    }
    config = parse_config(data, "folds.toml")
    assert not any("folds exactly" in note for note in config.cases[0].plan_notes)  # the intervals carry it
    SweepProcedure(config, tmp_path).run()
    measured = load_response(tmp_path).points
    assert {p.status for p in measured} == {PointStatus.ALIAS_LIMITED}
    assert not any(p.converged or p.within_eps for p in measured)
    again = reanalyse(tmp_path).response.points
    assert [p.status for p in again] == [p.status for p in measured]
    assert [p.uncertainty for p in again] == pytest.approx([p.uncertainty for p in measured], rel=1e-9)


def test_a_period_too_sparse_for_the_wider_basis_is_solved_for_the_measured_harmonics_alone() -> None:
    """A 60 ms gap in every second at 5 Hz: the periods it cuts cannot resolve harmonics up to 8, so they are solved
    for the measured harmonic alone, exactly as without the wider basis, and keep no coefficients above it."""
    from bodebench.core.fourier import ExactPeriodIntegrator

    f, rate = 5.0, 1000.0
    t = np.arange(0, 20, 1 / rate)
    t = t[((t - 0.5) % 1.0) >= 0.06]
    y = (0.01 * np.sin(2 * np.pi * f * t + 0.3))[:, None]
    narrow = ExactPeriodIntegrator(f, (1,), 1, 0.0)
    wide = ExactPeriodIntegrator(f, (1,), 1, 0.0, fit_order=8)
    p_n, q_n, whole_n = narrow.feed_marked(t, y)
    p_w, q_w, whole_w = wide.feed_marked(t, y)
    assert whole_w.all() and whole_n.all()
    assert np.max(np.abs(p_w + 1j * q_w - (p_n + 1j * q_n))) < 1e-15
    assert np.max(np.abs(p_w[:, 0, 0] + 1j * q_w[:, 0, 0] - 0.01 * np.exp(0.3j))) < 1e-15
    cut = np.isnan(wide.high).any(axis=(1, 2))
    assert 15 <= cut.sum() <= 25 and np.isfinite(wide.high[~cut]).all()


def _friction_link_on_a_fine_grid(frequency_hz: float, rate_hz: float, harmonics: list[int],
                                  fine: int = 32) -> np.ndarray:
    """What a sweep of ``configs/sim_can.toml``'s plant should give: the setpoint held over each controller period
    (as the simulated drive holds it), the plant's output taken ``fine`` times a period of the rate, settled for
    30 s, and its coefficients ``c_k = q_k - i p_k`` over a whole number of samples (a few periods where the
    rate/frequency ratio is a fraction): with ``fine`` x more samples a period, what folds onto the harmonics is
    negligible. The same held samples at the rate alone give what a bench sees, folds and all."""
    from fractions import Fraction

    from bodebench.sim.models import plant_from_config

    plant = plant_from_config("coulomb", mass=2.533e-4, stiffness=1.0, friction=0.008)
    state = plant.initial_state()
    ratio = Fraction(rate_hz).limit_denominator() / Fraction(frequency_hz).limit_denominator()
    samples = ratio.numerator  # ratio.denominator periods are this many samples
    step = 1.0 / rate_hz
    k = 0
    while True:
        held = 0.01 * np.sin(2 * np.pi * frequency_hz * step * np.arange(k, k + samples))
        y = plant.run_held(state, np.repeat(held, fine), step / fine)[:, 0]
        k += samples
        if k * step >= 30.0:
            break
    t = step * ((k - samples) + np.arange(1, samples * fine + 1) / fine)  # each output at the end of its sub-step
    return np.array([2.0 / len(y) * np.sum(y * np.exp(-2j * np.pi * h * frequency_hz * t)) for h in harmonics])


@pytest.mark.slow
@pytest.mark.parametrize("rate_hz, frequencies_hz", [(2000.0, [20.0, 30.0, 50.0]), (1000.0, [20.0, 25.0])])
def test_the_shipped_friction_link_on_awkward_grids_keeps_the_promise_against_a_fine_grid(
        rate_hz: float, frequencies_hz: list[float]) -> None:
    """``configs/sim_can.toml`` at 40 to 100 samples a period (66 2/3 at 30 Hz), where the friction link's high
    harmonics fold onto 1 and 3 every period alike, against the plant's response taken on a grid 32 x finer: with
    the default ``folds = "bound"`` every point's interval covers it and every converged point is within its own
    tolerance (eps of max(|Z_k|, 1e-3 |Z_1|)); ``folds = "keep"`` states intervals that miss it by more than the
    tolerance somewhere (harmonic 3 at 40 samples a period: why bound is the default)."""
    from bodebench.bench.connection import plan_link
    from bodebench.bench.session import BenchSession

    raw = tomllib.loads((Path(__file__).resolve().parents[1] / "configs" / "sim_can.toml").read_text())
    raw["excitation"]["frequencies_hz"] = frequencies_hz
    raw["bench"]["rate_hz"] = rate_hz
    harmonics = raw["analysis"]["harmonics"]
    truth = {f: _friction_link_on_a_fine_grid(f, rate_hz, harmonics) for f in frequencies_hz}
    worst_kept = 0.0
    for folds in (None, "keep"):
        if folds is not None:
            raw["analysis"]["folds"] = folds
        case = parse_config(raw, "sim_can.toml").cases[0]
        assert case.analysis.fold_policy == (folds or "bound")
        session = BenchSession(case, plan_link(case, direct=True), None, None)
        session.run()
        points = [p for p in session.response.points if p.channel == "position"]
        assert len(points) == len(frequencies_hz) * len(harmonics)
        for p in points:
            exact = truth[p.frequency_hz]
            error = abs(complex(p.q, -p.p) - exact[harmonics.index(p.harmonic)])
            tolerance = p.tolerance_percent / 100 * max(abs(exact[harmonics.index(p.harmonic)]),
                                                        RESOLUTION * abs(exact[0]))
            if folds is None:
                assert error <= p.uncertainty, (p, error, p.uncertainty)
                assert not p.converged or error <= tolerance, (p, error / tolerance)
            else:
                worst_kept = max(worst_kept, error / tolerance)
    if rate_hz == 2000.0:
        assert worst_kept > 1.0  # harmonic 3 at 50 Hz, 40 samples a period


def _spectrum_signal(sizes: np.ndarray, phases: np.ndarray, f: float, t0: float):
    """sum over j >= 1 of sizes[j] sin(2 pi j f (t - t0) + phases[j])."""
    j = np.arange(sizes.size)

    def signal(t: np.ndarray) -> np.ndarray:
        return np.sin(2 * np.pi * f * np.outer(t - t0, j) + phases) @ sizes
    return signal


def test_the_phase_average_is_the_waveform_on_a_whole_grid_and_refuses_a_slipping_one() -> None:
    rng = np.random.default_rng(5)
    f, n, t0 = 3.7, 40, 0.0123
    sizes = np.zeros(16)
    sizes[1:] = rng.uniform(0.1, 1.0, 15)
    phases = rng.uniform(0, 2 * np.pi, 16)
    signal = _spectrum_signal(sizes, phases, f, t0)
    transient = lambda t: 5.0 * np.exp(-(t - t0) * f / 2.0) * np.sin(2 * np.pi * 7.3 * f * (t - t0))  # noqa: E731
    average = PhaseAverage(f, t0, float(n), 1, 1000)
    t = t0 + (np.arange(200 * n) + 0.37) / (n * f)  # off the phase zero by 0.37 of a sample
    for chunk in np.array_split(np.arange(t.size), 37):
        average.add(t[chunk], (signal(t[chunk]) + transient(t[chunk]))[:, None])
    waveform = average.recent(200)
    assert waveform is not None
    # the bins hold the samples at phases (i + 0.37) / n: the waveform there, the transient long gone from the last
    # quarter
    expected = signal(t0 + (np.arange(n) + 0.37) / (n * f))
    assert np.max(np.abs(waveform[:, 0] - expected)) < 1e-9 * np.max(np.abs(expected))
    slipping = PhaseAverage(f, t0, 40.3, 1, 1000)
    t = t0 + np.arange(200 * 40) / (40.3 * f)
    slipping.add(t, signal(t)[:, None])
    assert slipping.recent(190) is None


@pytest.mark.parametrize("decay", [2, 3])
def test_the_waveform_fold_bound_covers_the_exact_folds_and_is_closer_than_the_solved_harmonics(decay: int) -> None:
    """A spectrum falling as 1/j**decay (decay 2: an output with corners; 3: one whose acceleration jumps, the
    friction link's) to j = 4000, on whole grids of 24 to 400 samples a period: what folds onto harmonics 1 to 3
    is the sum of the harmonics m N -+ k, exactly; the waveform's bound is at least that, and where the spectrum falls
    faster than 1/j**2 it is closer than the bound from the solved harmonics 4..8 (both through fold_bound)."""
    rng = np.random.default_rng(decay)
    top = 4000
    j = np.arange(top + 1)
    sizes = np.zeros(top + 1)
    sizes[1:] = (1.0 + rng.uniform(0, 1, top)) / j[1:] ** decay
    phases = rng.uniform(0, 2 * np.pi, top + 1)
    z = sizes * np.exp(1j * (phases - np.pi / 2))  # c_j, as 2 X_j / N of the DFT reads sizes_j sin(j theta + phases_j)
    for n in (24, 40, 67, 100, 400):
        theta = 2 * np.pi * np.arange(n) / n
        waveform = np.sin(np.outer(theta, j) + phases) @ sizes
        for k in (1, 2, 3):
            exact = abs(sum(z[m] if m % n == k else np.conj(z[m]) for m in range(4, top + 1) if m % n in (k, n - k)))
            closer = waveform_fold_bound(waveform, (1, 2, 3), float(n), k, 100)
            solved = fold_bound(z[4:9], range(4, 9), float(n), k, 100)
            assert closer >= exact, (n, k, closer, exact)
            if decay == 3 and n >= 100:
                assert closer < 0.5 * solved, (n, k, closer, solved)


def test_in_two_channel_mode_the_fold_bound_is_taken_relative_to_the_reference_as_the_coefficients_are() -> None:
    """A clipped sine on a whole grid (50 samples a period), once alone and once over a reference of amplitude 2 (the
    echoed setpoint, input amplitude 1): the coefficients are halved in two-channel mode, and so is each fold bound,
    the one read from the waveform averaged phase by phase included."""
    f, n_per = 3.1, 50
    t = (np.arange(200 * n_per) - 0.7) / (n_per * f)  # t0 between two samples
    y = _clipped_sine(t, f)
    analysis = AnalysisConfig(harmonics=(1, 3), tolerance_percent=0.01)
    alone = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0, samples_per_period=n_per)
    alone.feed(t, y[:, None])
    paired = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0, reference="echo", samples_per_period=n_per)
    paired.feed(t, np.column_stack((y, 2.0 * np.sin(2 * np.pi * f * t))))
    assert alone._phase is not None and alone._phase.recent(alone.periods) is not None  # the waveform is read
    bounds = alone.fold_bounds()
    assert (bounds > 0).all()
    assert paired.fold_bounds() == pytest.approx(0.5 * bounds, rel=1e-9)
    for one, two in zip(alone.points(), paired.points(), strict=True):
        assert complex(two.p, two.q) == pytest.approx(0.5 * complex(one.p, one.q), rel=1e-9)


@pytest.mark.parametrize("jitter", [0.0, 0.1])
def test_the_residual_at_a_line_is_its_amplitude_whatever_the_solved_harmonics_drift_and_offset(jitter: float) -> None:
    """A line at 50 Hz of 0.31 % of a response with harmonics 1, 2 and 7, an offset and a drift, measured at
    0.7814 Hz on a grid that fits no period (and jittered by 10 % of a sample): what each period's solved harmonics
    leave at the line, summed over the periods, gives its amplitude to 1e-4 of itself (1e-3 jittered: the sums weigh
    each sample by the interval before it); without the line, nothing
    (1e-12 of the response): the harmonics and the drift the basis spans leave nothing there."""
    from bodebench.core.fourier import ExactPeriodIntegrator

    f, rate, d, h = 0.7814, 331.7, 50.0, 0.0031
    rng = np.random.default_rng(5)
    n = int(60 * rate / f)
    t = (np.arange(n) + rng.uniform(-jitter, jitter, n)) / rate - 0.5 / rate
    base = (np.sin(2 * np.pi * f * t + 0.3) + 0.2 * np.cos(4 * np.pi * f * t) + 0.05 * np.sin(14 * np.pi * f * t)
            + 0.3 + 0.01 * t)
    for amplitude in (h, 0.0):
        y = base + amplitude * np.sin(2 * np.pi * d * t + 1.0)
        integrator = ExactPeriodIntegrator(f, (1, 2, 3), 1, 0.0, fit_order=8, lines_hz=(d,))
        kept = []
        for start in range(0, n, 997):
            _, _, whole = integrator.feed_marked(t[start:start + 997], y[start:start + 997, None])
            kept.append(integrator.lines[whole, 0, 0])
        residuals = np.concatenate(kept)
        assert residuals.size >= 55
        found = 2 * f * abs(residuals[5:].sum()) / residuals[5:].size
        assert found == pytest.approx(amplitude, rel=1e-3 if jitter else 1e-4, abs=1e-12)


def test_the_lines_bounded_are_those_the_samples_see_beyond_the_solved_harmonics() -> None:
    """At 200 Hz 150 Hz is seen at 50 Hz and 100 Hz at 100 Hz; at 2.1 Hz with harmonics solved up to 8 both lie near
    harmonics 24 and 48, and at 10 Hz 50 Hz is harmonic 5, solved: only what lies above is bounded."""
    assert lines_beyond_fit((50.0, 100.0, 150.0), 2.1, 200.0 / 2.1, 8) == (50.0, 100.0)
    assert lines_beyond_fit((50.0, 100.0, 150.0), 10.0, 20.0, 8) == (100.0,)
    assert lines_beyond_fit((50.0,), 2.0, 0.0, 8) == (50.0,)  # a rate unknown: the line as it is
    assert lines_beyond_fit((400.0,), 2.0, 200.0, 8) == ()  # on a multiple of the rate: a constant to the samples


@pytest.mark.parametrize("delta", [0.005, 0.01, 0.03, -0.02])
def test_the_leak_bound_covers_the_leak_of_a_standing_line_into_every_measured_harmonic(delta: float) -> None:
    """A pure line at (64 + delta) f on a whole grid (423 samples a period), through the bench's integrator, over
    three turns of the line against the harmonics: the average of every number of periods of each measured harmonic
    before the line has turned LINE_TURNS times is at most the bound, the bound of one period at most 3 x the largest
    leak of one period over the line's phases (the bound takes the worst phase), and after those turns the average
    keeps less than a fifth of the bound of one period (the spread of the periods shows it)."""
    from bodebench.core.fourier import ExactPeriodIntegrator

    f, steps = 1.0, 423
    x = 64 + delta
    worst = {k: 0.0 for k in (1, 2, 3)}
    for phase in np.linspace(0.0, np.pi, 4, endpoint=False):
        t = np.arange(0, int(3.0 / abs(delta)) * steps + 1) / (steps * f)
        y = np.sin(2 * np.pi * x * f * t + phase)
        integrator = ExactPeriodIntegrator(f, (1, 2, 3), 1, 0.0, fit_order=8)
        p, q = integrator.feed(t, y[:, None])
        z = p[:, 0] + 1j * q[:, 0]
        means = np.cumsum(z, axis=0) / np.arange(1, z.shape[0] + 1)[:, None]
        for n in range(1, z.shape[0] + 1):
            for i, k in enumerate((1, 2, 3)):
                leak = abs(means[n - 1, i])
                if n * abs(x - round(x)) < LINE_TURNS:
                    assert leak <= line_leak(1.0, x, k, n) * (1 + 1e-9) + 1e-15, (n, k, leak)
                else:
                    assert line_leak(1.0, x, k, n) == 0.0 and leak < 0.2 * line_leak(1.0, x, k, 1), (n, k, leak)
                if n == 1:
                    worst[k] = max(worst[k], leak)
    for k in (1, 2, 3):
        assert line_leak(1.0, x, k, 1) <= 3 * worst[k]


HUM_TRUTH = {1: 0.8 - 0.3j, 2: 0.02 + 0.01j, 3: 0.006 + 0.003j}
"""Harmonics 1..3 of the response the hum tests measure (P + iQ swapped: Q sin + P cos, output units)."""


def _hum_truth(f: float, t: np.ndarray) -> np.ndarray:
    """The response HUM_TRUTH at f (Hz) at times t (s)."""
    return sum(z.imag * np.sin(2 * np.pi * k * f * t) + z.real * np.cos(2 * np.pi * k * f * t)
               for k, z in HUM_TRUTH.items())


def _fed(sampler: Autointegrator, t: np.ndarray, columns: np.ndarray) -> list[ResponsePoint]:
    """The points of ``sampler`` fed ``columns`` (sample, column) at times t (s), 4096 samples a call, until done."""
    for start in range(0, t.size, 4096):
        if sampler.done:
            break
        sampler.feed(t[start:start + 4096], columns[start:start + 4096])
    return sampler.points()


def _hum_at(line_harmonics: float, samples: float, hum: float, eps: float, max_periods: int,
            turning: tuple[float, ...] | None = (), harmonics: tuple[int, ...] = (1, 2, 3), reference: str = "",
            control_folds: str = "bound") -> dict[bool, dict[int, ResponsePoint]]:
    """Each of ``harmonics``' points, without and with the mains lines (keys False, True), of HUM_TRUTH plus a
    transient that dies in a few periods and mains hum of amplitude ``hum`` at ``line_harmonics`` times f, sampled
    at ``samples`` a period from just before t = 0; ``turning``: the lines the sampler is to read from a solved
    harmonic (None: not checked). ``reference``: two-channel mode over a reference column carrying the input, a unit
    sine, and the hum on "output" or on the "reference" column. ``control_folds``: ``[analysis] folds`` of the run
    without the lines."""
    f = 50.0 / line_harmonics
    rate = samples * f
    t = np.arange(0, int((max_periods + 10) * samples)) / rate - 0.5 / rate
    y = _hum_truth(f, t)
    mains = hum * np.sin(2 * np.pi * 50.0 * t + 2.0)
    y = y + np.exp(-np.maximum(t, 0.0) * f / 3) * np.cos(2 * np.pi * 2.3 * f * t)
    if reference:
        columns = np.stack((y + mains * (reference == "output"),
                            np.sin(2 * np.pi * f * t) + mains * (reference == "reference")), axis=1)
    else:
        columns = (y + mains)[:, None]
    found = {}
    for lines in ((), disturbance_lines([50.0])):
        analysis = AnalysisConfig(harmonics=harmonics, tolerance_percent=eps, max_periods=max_periods,
                                  folds="bound" if lines else control_folds)
        sampler = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0, samples_per_period=samples,
                                 disturbance_lines=lines, reference="r" if reference else None)
        assert turning is None or sampler.turning_lines == (turning if lines else ())
        found[bool(lines)] = {p.harmonic: p for p in _fed(sampler, t, columns)}
    return found


def test_hum_standing_still_against_an_unmeasured_harmonic_is_bounded_not_converged_off_its_tolerance() -> None:
    """Mains at 63.99 times f (0.31 % of the fundamental) on a whole grid of 423 samples a period, a response with
    harmonic 3 at 0.6 % of its fundamental and a transient that dies in a few periods, eps 0.01 %: without the lines
    (and without the fold bound, which on this whole grid reads the hum from the averaged waveform too) the point
    says harmonic 3 converged, more than its tolerance off the truth and outside its interval (the leak stands still
    over the periods it took); with them every point's interval covers the truth, and those converged are within
    their tolerance."""
    found = _hum_at(63.99, 423, 0.0031, 0.01, 400, control_folds="keep")
    third = found[False][3]
    error = abs(complex(third.q, third.p) - HUM_TRUTH[3])
    assert third.converged and error > 1e-4 * abs(HUM_TRUTH[3]) and error > third.uncertainty
    for k, point in found[True].items():
        error = abs(complex(point.q, point.p) - HUM_TRUTH[k])
        assert error <= point.uncertainty, (k, error, point.uncertainty, point.status)
        if point.converged:
            assert error <= 1e-4 * max(abs(HUM_TRUTH[k]), RESOLUTION * abs(HUM_TRUTH[1]))


def test_the_lines_read_from_a_solved_harmonic_are_those_nearest_one_not_measured() -> None:
    """At 10 Hz with harmonics 1..3 measured and 1..8 solved, 50 Hz lies on harmonic 5 and 100 Hz on 10 (beyond);
    at 20 Hz 150 Hz folds (at 200 Hz) to 50 Hz, harmonic 2.5: nearest 2 (measured, rounded half to even) and is not
    read there; 60 Hz at 9.99 Hz is harmonic 6.006; with harmonics 1 and 3 measured, 50 Hz at 24.95 Hz lies near
    harmonic 2, solved between them."""
    assert lines_on_fit((50.0, 100.0, 150.0), 10.0, 1000.0, (1, 2, 3), 8) == (50.0,)
    assert lines_on_fit((150.0,), 20.0, 10.0, (1, 2, 3), 8) == ()
    assert lines_on_fit((60.0, 120.0, 180.0), 9.99, 300.0, (1, 2, 3), 8) == (60.0,)
    assert lines_on_fit((50.0,), 10.0, 1000.0, (1, 2, 3, 4, 5), 5) == ()  # nothing solved but the measured
    assert lines_on_fit((50.0, 100.0, 150.0), 24.95, 1000.0, (1, 3), 8) == (50.0, 100.0, 150.0)  # near 2, 4, 6
    assert lines_on_harmonics((50.0, 100.0, 150.0), 24.95, 1000.0, (1, 2, 3)) == (50.0,)  # on measured harmonic 2


@pytest.mark.parametrize("j, delta, measured", [(5, 0.004, (1, 2, 3)), (4, -0.0019, (1, 2, 3)), (8, 0.03, (1, 2, 3)),
                                                (6, -0.012, (1, 2, 3)), (2, 0.006, (1, 3))])
def test_a_line_near_a_solved_harmonic_is_read_from_how_that_harmonic_turns_and_its_leak_bounded(
        j: int, delta: float, measured: tuple[int, ...]) -> None:
    """A line of amplitude 0.02 at (j + delta) f beside harmonics 1..3, an offset and a drift, on a grid of 97.3
    samples a period, through the bench's integrator (harmonics solved up to 8, ``measured`` measured: j above them
    or between them): the amplitude read from harmonic j's
    coefficients is the line's to 2 % (with 1 % white noise on the samples, within 25 % and never below), and the
    mean of every number of periods n of each measured harmonic, and of their last three quarters and last half (as
    the default rule's settled mean takes them), is off the truth by at most :func:`line_leak` over n / 2 periods of
    that amplitude read over the later half of the n periods."""
    from bodebench.core.fourier import ExactPeriodIntegrator

    f, per, h = 1.0, 97.3, 0.02
    x = j + delta
    truth = {1: 0.8 - 0.3j, 2: 0.02 + 0.01j, 3: 0.006 + 0.003j}
    periods = min(400, int(2.5 / abs(delta)))
    t = np.arange(int(periods * per)) / (per * f) - 0.37 / (per * f)
    clean = sum(z.real * np.sin(2 * np.pi * k * f * t) + z.imag * np.cos(2 * np.pi * k * f * t)
                for k, z in truth.items()) + 0.1 + 0.002 * t + h * np.sin(2 * np.pi * x * f * t + 0.7)
    for noise in (0.0, 0.01):
        y = clean + noise * np.random.default_rng(j).standard_normal(t.size)
        integrator = ExactPeriodIntegrator(f, measured, 1, 0.0, fit_order=8)
        p, q = integrator.feed(t, y[:, None])
        z = p[:, 0] + 1j * q[:, 0]
        high = integrator.unmeasured[:, 0, integrator.unmeasured_harmonics.index(j)]
        read = turning_amplitude(high[-(high.size // 2):], x, spread=0.0)
        if noise:
            assert h <= turning_amplitude(high[-(high.size // 2):], x) <= 1.25 * h
            continue
        assert read == pytest.approx(h, rel=0.02)
        sums = np.concatenate((np.zeros((1, z.shape[1])), np.cumsum(z, axis=0)))
        for n in range(6, z.shape[0] + 1):  # the later half of 6 periods or more: 3 or more, as any verdict takes
            amplitude = turning_amplitude(high[n // 2:n], x)
            fewest = n // 2  # the fewest periods a rule's value averages, as the sampler bounds it
            for first in (0, n // 4, n // 2):  # the mean of all n periods, of the last three quarters, the last half
                mean = (sums[n] - sums[first]) / (n - first)
                for i, k in enumerate(measured):
                    error = abs(mean[i] - truth[k])
                    if fewest * abs(delta) < LINE_TURNS:
                        assert error <= line_leak(amplitude, x, k, fewest) * (1 + 1e-6) + 1e-12, (n, first, k, error)


def test_hum_near_an_unmeasured_solved_harmonic_is_bounded_and_an_early_verdict_judged_again() -> None:
    """Mains at (4 - 0.005) times f (1.6 % of the fundamental) on a grid of 61.3 samples a period, eps 0.1 %, the
    response's harmonic 2 at 2.8 % of its fundamental: the solve takes the hum into harmonic 4, which turns with it
    so slowly that its leak into harmonic 2 stands still over the periods a first verdict takes. Without the lines
    harmonic 2 says converged after 17 periods, more than twice its tolerance off and outside its interval; with them
    every interval covers the truth, a series that converges is within its tolerance, and harmonic 2, judged again
    each period after that first verdict, converges once the line has turned enough."""
    found = _hum_at(4 - 0.005, 61.3, 0.016, 0.1, 2000, turning=(50.0, 100.0))  # 100 Hz near harmonic 8
    alone, bounded = found[False][2], found[True][2]
    error = abs(complex(alone.q, alone.p) - HUM_TRUTH[2])
    assert alone.converged and error > 2e-3 * abs(HUM_TRUTH[2]) and error > alone.uncertainty, error
    assert bounded.converged and bounded.periods > 10 * alone.periods
    for k, point in found[True].items():
        error = abs(complex(point.q, point.p) - HUM_TRUTH[k])
        assert error <= point.uncertainty, (k, error, point.uncertainty, point.status)
        if point.converged:
            assert error <= 1e-3 * abs(HUM_TRUTH[k]), (k, error)


def test_hum_just_off_a_measured_harmonic_is_read_there_and_its_leak_into_the_others_bounded() -> None:
    """Mains at 2.003 times f (3 % of the fundamental) on a grid of 61.3 samples a period, eps 0.01 %: the line lies
    on measured harmonic 2 (whose own point it disturbs) and leaks into harmonic 1 a near-constant over the 17
    periods a first verdict takes. Without the lines harmonic 1 says converged more than its tolerance off and
    outside its interval; with them the line is read from how harmonic 2 turns, and harmonic 1 converges within its
    tolerance, its interval covering the truth, once the line has turned enough."""
    found = _hum_at(2.003, 61.3, 0.03, 0.01, 2000, turning=(100.0, 150.0))  # 100 and 150 Hz near 4 and 6
    alone, bounded = found[False][1], found[True][1]
    tolerance = 1e-4 * abs(HUM_TRUTH[1])
    error = abs(complex(alone.q, alone.p) - HUM_TRUTH[1])
    assert alone.converged and error > tolerance and error > alone.uncertainty, error
    error = abs(complex(bounded.q, bounded.p) - HUM_TRUTH[1])
    assert bounded.converged and error <= min(tolerance, bounded.uncertainty) and bounded.periods > 10 * alone.periods


def test_hum_on_the_reference_column_moves_every_ratio_and_is_bounded() -> None:
    """Two-channel mode, mains at 6.02 times f (1 % of the input) on the reference column only, 97.3 samples a
    period, eps 0.01 %: the solve takes the line into the reference's harmonic 6, whence it leaks into the
    reference's fundamental, the divisor of every ratio, a near-constant over the periods a first verdict takes.
    Without the lines a harmonic says converged more than its tolerance off and outside its interval; with them the
    line is read from how the reference's harmonic 6 turns, its leak moves every ratio's bound by its share of the
    divisor, every interval covers the truth and every converged harmonic is within its tolerance."""
    found = _hum_at(6.02, 97.3, 0.01, 0.01, 1500, turning=(50.0,), reference="reference")

    def off(point: ResponsePoint) -> tuple[float, float]:
        """The point's error and its tolerance (output units)."""
        k = point.harmonic
        return abs(complex(point.q, point.p) - HUM_TRUTH[k]), 1e-4 * max(abs(HUM_TRUTH[k]),
                                                                          RESOLUTION * abs(HUM_TRUTH[1]))

    assert any(p.converged and off(p)[0] > max(off(p)[1], p.uncertainty) for p in found[False].values())
    for point in found[True].values():
        error, tolerance = off(point)
        assert error <= point.uncertainty, (point.harmonic, error, point.uncertainty, point.status)
        if point.converged:
            assert error <= tolerance, (point.harmonic, error)
    assert sum(p.converged for p in found[True].values()) >= 2


def test_a_line_near_a_fundamental_solved_only_for_the_divisor_is_read_there() -> None:
    """Two-channel mode measuring harmonic 3 alone, mains at 1.003 times f (1 % of the fundamental) on the output:
    the fundamental is solved for the divisor, not measured, and the line turns it, leaking into harmonic 3. Without
    the lines harmonic 3 says converged more than its tolerance off and outside its interval; with them the line is
    read from the fundamental like from any solved harmonic, and harmonic 3 ends within its interval (converged
    within its tolerance, or not converged)."""
    found = _hum_at(1.003, 97.3, 0.01, 0.1, 600, turning=(50.0, 100.0), harmonics=(3,), reference="output")
    tolerance = 1e-3 * abs(HUM_TRUTH[3])
    alone, bounded = found[False][3], found[True][3]
    error = abs(complex(alone.q, alone.p) - HUM_TRUTH[3])
    assert alone.converged and error > max(tolerance, alone.uncertainty), error
    error = abs(complex(bounded.q, bounded.p) - HUM_TRUTH[3])
    assert error <= bounded.uncertainty, (error, bounded.uncertainty, bounded.status)
    assert error <= tolerance or not bounded.converged, error


def test_the_drives_echo_of_its_setpoint_is_read_for_no_line() -> None:
    """The drive's echo of the setpoint is a number, with no hum on it: a sampler told so (``reference_lines =
    carries_lines(SETPOINT_ECHO)``, as the bench session's) reads no line on it. At 1.0005 times under mains, where
    the reference's fundamental cannot tell a line from itself, a sampler that reads its noise as one takes several
    times the periods; both end within their tolerance of the truth."""
    from bodebench.drivers.codec import SETPOINT_ECHO, carries_lines

    assert not carries_lines(SETPOINT_ECHO) and carries_lines("position")
    f, samples, eps = 50.0 / 1.0005, 40.3, 0.01
    rate = samples * f
    t = np.arange(0, int(3010 * samples)) / rate - 0.5 / rate
    y = _hum_truth(f, t)
    echo = np.round(np.sin(2 * np.pi * f * t) * 32767) / 32767  # a 16-bit setpoint
    columns = np.stack((y, echo), axis=1)
    analysis = AnalysisConfig(harmonics=(1, 2, 3), tolerance_percent=eps, max_periods=3000)
    periods = {}
    for reads in (carries_lines(SETPOINT_ECHO), True):
        sampler = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0, samples_per_period=samples,
                                 disturbance_lines=disturbance_lines([50.0]), reference="echo",
                                 reference_lines=reads)
        points = _fed(sampler, t, columns)
        for point in points:
            error = abs(complex(point.q, point.p) - HUM_TRUTH[point.harmonic])
            assert point.converged and error <= 1e-4 * abs(HUM_TRUTH[point.harmonic]), (reads, point.harmonic)
        periods[reads] = max(p.periods for p in points)
    assert periods[True] > 2 * periods[False], periods


@pytest.mark.parametrize("dead_periods", [12, 40])
def test_periods_of_a_silent_reference_are_read_for_no_line(dead_periods: int) -> None:
    """Two-channel mode with mains lines, the reference silent (zero) for its first periods, then a sine: the
    periods it was silent in are discarded (they divide by nothing) and kept out of what the lines are read from, so
    the point is measured from the later periods, or refused for its discarded share, as without the lines."""
    from bodebench.core.autointegration import GapsError

    f, samples = 50.0 / 2.01, 40.3
    rate = samples * f
    t = np.arange(0, int(400 * samples)) / rate - 0.5 / rate
    y = _hum_truth(f, t)
    reference = np.where(t * f < dead_periods, 0.0, np.sin(2 * np.pi * f * t))
    y = np.where(t * f < dead_periods, 0.0, y)
    columns = np.stack((y, reference), axis=1)
    analysis = AnalysisConfig(harmonics=(1, 2, 3), tolerance_percent=0.1, max_periods=300)
    outcomes = []
    for lines in ((), disturbance_lines([50.0])):
        sampler = Autointegrator(f, 1.0, ("y",), analysis, t0=0.0, samples_per_period=samples,
                                 disturbance_lines=lines, reference="r")
        try:
            points = _fed(sampler, t, columns)
        except GapsError as refused:
            outcomes.append(f"refused: {refused}")
            continue
        for point in points:
            error = abs(complex(point.q, point.p) - HUM_TRUTH[point.harmonic])
            assert point.converged and error <= 1e-3 * abs(HUM_TRUTH[point.harmonic]), (lines, point.harmonic)
        outcomes.append("measured")
    assert outcomes[0] == outcomes[1]
    assert (outcomes[0] == "measured") == (dead_periods == 12), outcomes


def test_the_grid_gain_of_a_standing_line_bounds_every_periods_leak_and_is_the_continuous_one_on_a_fine_grid() -> None:
    """``line_gains``: on a fine grid (200 or 400.7 samples a period) the most a unit line at 9.05 f puts into
    harmonics 1..3 a period is the continuous-time leak ``sin(pi delta) / pi (1 / |x - k| + 1 / (x + k))`` to 2 %,
    and a line exactly on harmonic 9 of a whole grid puts in nothing; on coarse grids (20.3, 40.76 samples) the solve
    lets through more than ten times the continuous leak of a line 0.0005 off harmonic 9. Each period's coefficient
    of a line fed at four phases, through the bench's integrator on a grid of its own phase, stays within the gain."""
    from bodebench.core.fourier import ExactPeriodIntegrator, line_gains

    def continuous(x: float, k: int) -> float:
        delta = x - round(x)
        return abs(math.sin(math.pi * delta)) / math.pi * (1 / abs(x - k) + 1 / (x + k))

    for samples in (200.0, 400.7):
        gains = line_gains(1.0, (1, 2, 3), 8, samples, [9.05, 9.0])
        for i, k in enumerate((1, 2, 3)):
            assert gains[i, 0] == pytest.approx(continuous(9.05, k), rel=0.02)
        if samples == 200.0:
            assert np.all(gains[:, 1] < 1e-12)
    for samples in (20.3, 40.762):
        fit = min(8, int(samples // 4))
        gains = line_gains(1.0, (1, 2, 3), fit, samples, [8.9995])
        assert np.all(gains[:, 0] > 10 * np.array([continuous(8.9995, k) for k in (1, 2, 3)]))
        t = (np.arange(int(60 * samples)) - 0.21) / samples
        for phase in (0.0, 0.9, 2.1, 4.0):
            integrator = ExactPeriodIntegrator(1.0, (1, 2, 3), 1, 0.0, fit_order=fit)
            p, q = integrator.feed(t, np.cos(2 * np.pi * 8.9995 * t + phase)[:, None])
            assert np.all(np.hypot(p[:, 0], q[:, 0]) <= gains[:, 0] * (1 + 1e-9))


def test_a_standing_line_on_a_coarse_grid_is_bounded_by_what_the_solve_lets_through() -> None:
    """Mains at 8.9995 times f (5 % of the fundamental) on a grid of 40.76 samples a period, solved up to harmonic 8:
    the line stands almost still beyond the solved harmonics, and the per-period solve on so coarse a grid lets
    through about twenty times what the continuous-time leak says; the bound takes the grid's own gain, so every
    interval holds the truth and every converged harmonic is within its tolerance."""
    found = _hum_at(8.9995, 40.762, 0.05, 0.1, 1500)
    for point in found[True].values():
        error = abs(complex(point.q, point.p) - HUM_TRUTH[point.harmonic])
        assert error <= point.uncertainty, (point.harmonic, error, point.uncertainty, point.status)
        if point.converged:
            assert error <= 1e-3 * max(abs(HUM_TRUTH[point.harmonic]), RESOLUTION * abs(HUM_TRUTH[1]))


def test_a_line_the_rate_folds_keeps_its_grid_bound() -> None:
    """Mains at 12 times f (5 % of the fundamental) on 20.3 samples a period: the samples see the line folded, at
    8.3 f, where it seems to turn 0.3 cycles a period, but the line stands still against the period and the grid's
    slip from period to period carries its leak; the grid bound stays, so every interval holds the truth and every
    converged harmonic is within its tolerance."""
    found = _hum_at(12.0, 20.3, 0.05, 0.01, 1500, turning=None)  # 100 and 150 Hz fold near harmonics 4 and 5
    for point in found[True].values():
        error = abs(complex(point.q, point.p) - HUM_TRUTH[point.harmonic])
        assert error <= point.uncertainty, (point.harmonic, error, point.uncertainty, point.status)
        if point.converged:
            assert error <= 1e-4 * max(abs(HUM_TRUTH[point.harmonic]), RESOLUTION * abs(HUM_TRUTH[1]))
