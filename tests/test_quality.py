"""Per-point total harmonic distortion and coherence: closed-form Fourier series through the real integrator and
stopping rule, a linear plant through the offline sweep, and the results files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bodebench.bench.offline import sweep
from bodebench.core.autointegration import Autointegrator
from bodebench.core.quality import coherence, coherence_periods, total_harmonic_distortion
from bodebench.core.response import FrequencyResponse
from bodebench.io.config import AnalysisConfig, parse_config
from bodebench.io.results import ResultsWriter, load_response, save_response

F = 5.0  # Hz
RATE = 2000.0  # samples per second


def integrate(shape, harmonics: tuple[int, ...], noise: float = 0.0, seed: int = 0, periods: int = 4000,
              **analysis: object) -> Autointegrator:
    """The point of output ``shape(theta)`` for the excitation sin(theta), theta = 2 pi F t, sampled at RATE."""
    settings = AnalysisConfig(harmonics=harmonics, tolerance_percent=0.1, max_periods=periods, **analysis)
    integrator = Autointegrator(F, 1.0, ["y"], settings)
    rng = np.random.default_rng(seed)
    t = np.arange(int(periods * RATE / F) + 2) / RATE
    y = shape(2 * math.pi * F * t) + noise * rng.standard_normal(t.size)
    block = int(50 * RATE / F)
    for start in range(0, t.size, block):
        integrator.feed(t[start:start + block], y[start:start + block, None])
        if integrator.done:
            break
    assert integrator.done
    return integrator


def test_thd_and_coherence_of_the_formulas() -> None:
    assert total_harmonic_distortion(2.0, [0.0, 1.2j, -1.6]) == pytest.approx(1.0)
    assert math.isnan(total_harmonic_distortion(1.0, []))
    assert math.isnan(total_harmonic_distortion(0.0, [1.0]))
    assert coherence([1 + 1j] * 5) == pytest.approx(1.0)
    assert coherence([1.0, -1.0]) == 0.0
    assert math.isnan(coherence([1.0]))
    # pure noise: |mean|^2 / mean |z|^2 is about 1/M for M periods
    rng = np.random.default_rng(1)
    values = [coherence(rng.standard_normal(400) + 1j * rng.standard_normal(400)) for _ in range(200)]
    assert np.mean(values) == pytest.approx(1 / 400, rel=0.2)
    assert coherence_periods(1, 101) == (51, 101) and coherence_periods(0, 7) == (3, 7)


def test_cubed_sine_has_a_thd_of_one_third() -> None:
    """sin^3 = (3 sin - sin 3 theta) / 4: THD = (1/4) / (3/4), the second harmonic zero; coherence 1."""
    (p1, p2, p3) = integrate(lambda th: np.sin(th) ** 3, (1, 2, 3)).points()
    assert p1.thd == pytest.approx(1 / 3, rel=1e-3)
    assert math.isnan(p2.thd) and math.isnan(p3.thd)  # stated on the harmonic-1 row only
    assert p1.coherence == pytest.approx(1.0, abs=1e-9) and p3.coherence == pytest.approx(1.0, abs=1e-9)


def test_clipped_square_wave_thd_from_its_fourier_series() -> None:
    """sign(sin theta) = (4 / pi) sum over odd k of sin(k theta) / k: from the harmonics measured (1 to 5),
    THD = sqrt(1/9 + 1/25). Sampled at 400 points a period, the jump between samples is interpolated: a few
    1e-3 of the harmonics, allowed here."""
    points = integrate(lambda th: np.sign(np.sin(th + 1e-3)), (1, 2, 3, 4, 5)).points()
    assert points[0].thd == pytest.approx(math.sqrt(1 / 9 + 1 / 25), rel=5e-3)


def test_noise_lowers_the_coherence_as_its_power_share_says() -> None:
    """sin + white noise of variance s^2, N samples a period: each period's coefficient carries noise of
    expected power 4 s^2 / N, so the coherence over M periods is about 1 / (1 + 4 s^2 / N) (plus 1/M bias)."""
    sigma = 2.0
    n = RATE / F
    expected = 1 / (1 + 4 * sigma**2 / n)
    point = integrate(np.sin, (1,), noise=sigma, seed=3, periods=3000, criterion="fixed", settle_periods=0,
                      average_periods=2000).points()[0]
    assert point.coherence == pytest.approx(expected, abs=0.01)
    assert point.coherence < 0.97


def test_a_linear_plant_has_no_distortion_and_full_coherence() -> None:
    config = parse_config({
        "plant": {"model": "linear", "mass": 1.0, "stiffness": 40.0, "damping_ratio": 0.3},
        "excitation": {"amplitude": 1.0, "frequencies_hz": [0.3, 1.0, 3.0]},
        "analysis": {"harmonics": [1, 2, 3], "tolerance_percent": 0.1, "steps_per_period": 64},
    }, "linear.toml")
    response = sweep(config.cases[0])
    first = response.select(harmonic=1)
    assert len(first) == 3
    for p in first:
        fundamental = p.magnitude
        assert p.thd < 1e-3, p
        assert p.thd == pytest.approx(total_harmonic_distortion(
            complex(p.p, p.q), [complex(o.p, o.q) for o in response.points
                                if o.frequency_hz == p.frequency_hz and o.harmonic > 1]), rel=1e-12)
        assert fundamental > 0
    for p in response:
        assert p.coherence > 0.999 or p.harmonic > 1  # the harmonics are zero: no steady part to cohere


def test_results_files_carry_thd_and_coherence_and_older_files_resume(tmp_path: Path) -> None:
    points = integrate(lambda th: np.sin(th) ** 3, (1, 3)).points()
    response = FrequencyResponse(points, config={"a": 1}, case="c")
    save_response(response, tmp_path / "new")
    loaded = load_response(tmp_path / "new")
    assert [repr((p.thd, p.coherence)) for p in loaded] == [repr((p.thd, p.coherence)) for p in points]
    # a version-2 file (no thd, coherence): loads, and a resumed sweep rewrites it in the current format
    old = tmp_path / "old"
    save_response(response, old)
    csv = old / "response.csv"
    csv.write_text("".join(",".join(line.split(",")[:19]) + "\n" for line in csv.read_text().splitlines()
                           if not line.startswith("#")))
    assert all(math.isnan(p.thd) and math.isnan(p.coherence) for p in load_response(old))
    writer = ResultsWriter(old, "c", {"a": 1}, resume=True)
    writer.append(points)
    again = load_response(old)
    header = next(line for line in csv.read_text().splitlines() if not line.startswith("#"))
    assert len(again) == 4 and header.endswith(",thd,coherence,periods_discarded,drift_per_s,tolerance_percent")
    assert again.points[2].thd == points[0].thd
