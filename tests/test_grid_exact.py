"""ExactPeriodIntegrator: per-period coefficients exact on any sample times, for a constant, a linear drift and
harmonics 1 .. K.

Truth is the signal's own coefficients (it is built from them); grids are a bench's: a fixed rate whose period is not
a whole number of samples, t0 between samples, jittered instants, gaps. The trapezoidal rule alone misses on the same
grids by about (samples per period)^-3, the same way every period, which is what this integrator exists to remove.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bodebench.core.fourier import ExactPeriodIntegrator, PeriodIntegrator

RNG_SEEDS = range(40)


def signal(t: np.ndarray, f: float, t0: float, dc: float, z: dict[int, complex]) -> np.ndarray:
    """dc + sum over k of Re(z_k) sin(2 pi k f (t - t0)) + Im(z_k) cos(...): P_k = Re z_k, Q_k = Im z_k."""
    th = 2 * np.pi * f * (t - t0)
    return dc + sum(v.real * np.sin(k * th) + v.imag * np.cos(k * th) for k, v in z.items())


def bench_grid(rng: np.random.Generator, f: float, rate: float, periods: int, t0: float,
               jitter: float, gaps: int) -> np.ndarray:
    """Sample instants at ``rate`` from before t0 over ``periods`` periods, jittered by up to ``jitter`` of a step,
    with ``gaps`` holes of up to a fifth of a period cut out."""
    start = t0 - rng.uniform(0.0, 1.0) / rate
    t = start + np.arange(int((periods / f) * rate) + 2) / rate
    t[1:] += jitter * rng.uniform(-1.0, 1.0, t.size - 1) / rate
    keep = np.ones(t.size, dtype=bool)
    for _ in range(gaps):
        a = t0 + rng.uniform(0.5, periods - 1.0) / f
        keep &= ~((t > a) & (t < a + rng.uniform(0.0, 0.2) / f))
    return np.sort(t[keep])


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_a_constant_plus_the_harmonics_is_exact_on_any_grid(seed: int) -> None:
    rng = np.random.default_rng(seed)
    harmonics = tuple(sorted(rng.choice([1, 2, 3, 5], size=rng.integers(1, 4), replace=False).tolist()))
    k_max = max(harmonics)
    rate = float(10 ** rng.uniform(2, 4))  # 100 Hz to 10 kHz
    f = rate / (k_max * rng.uniform(8.0, 200.0))  # 8 to 200 samples a period of the highest harmonic
    t0 = rng.uniform(0.0, 1.0)
    t = bench_grid(rng, f, rate, 12, t0, jitter=rng.choice([0.0, 0.2]), gaps=int(rng.integers(0, 3)))
    z = {k: complex(*rng.normal(size=2)) for k in range(1, k_max + 1)}
    dc = rng.normal() * 100  # a position far from zero
    slope = rng.normal() * f * rng.choice([0.0, 0.01])  # a drift of up to about 1 % of the response a period
    y = np.column_stack([signal(t, f, t0, dc, z) + slope * t,
                         signal(t, f, t0, -dc, {k: 2j * v for k, v in z.items()})])
    integ = ExactPeriodIntegrator(f, harmonics, 2, t0)
    ps, qs, marks, drifts = [], [], [], []
    for part in np.array_split(np.arange(t.size), int(rng.integers(1, 9))):
        p, q, whole = integ.feed_marked(t[part], y[part])
        ps.append(p), qs.append(q), marks.append(whole), drifts.append(integ.drift[whole])
    p, q, whole = np.concatenate(ps), np.concatenate(qs), np.concatenate(marks)
    assert p.shape == (integ.periods_done, 2, len(harmonics)) and integ.periods_done >= 11
    scale = max(abs(v) for v in z.values()) + abs(dc)
    for j, k in enumerate(harmonics):
        for c, factor in enumerate((1.0, 2j)):
            error = np.abs(p[whole, c, j] + 1j * q[whole, c, j] - factor * z[k])
            assert error.max() <= 1e-10 * scale, (k, c, error.max())
    assert whole.sum() >= integ.periods_done - 6  # only periods a gap left with too few samples may be dropped
    drift = np.concatenate(drifts) * f  # channel units per second
    assert np.abs(drift[:, 0] - slope).max() <= 1e-9 * scale and np.abs(drift[:, 1]).max() <= 1e-9 * scale


@pytest.mark.parametrize("rate, f, trapezoid_error", [(200.0, 11.0, 1e-3), (200.0, 23.0, 9e-3), (2000.0, 60.0, 1.5e-4)])
def test_the_trapezoid_misses_on_a_bench_grid_and_the_moment_solve_does_not(rate: float, f: float,
                                                                         trapezoid_error: float) -> None:
    t = np.arange(-1, int(40 * rate / f)) / rate
    y = np.sin(2 * np.pi * f * t + 0.3)
    truth = complex(math.cos(0.3), math.sin(0.3))
    p, q = PeriodIntegrator(f, (1,), 1).feed(t, y)
    assert abs(np.mean(p + 1j * q) - truth) > 0.5 * trapezoid_error  # averaging does not remove it
    p, q = ExactPeriodIntegrator(f, (1,), 1).feed(t, y)
    assert np.abs(p + 1j * q - truth).max() < 1e-12


@pytest.mark.parametrize("steps", [8, 25, 200])
def test_on_a_whole_grid_it_is_the_trapezoid_even_for_harmonics_it_does_not_fit(steps: int) -> None:
    f, t0 = 3.0, 0.5
    t = t0 + np.arange(-2, 10 * steps + 1) / (steps * f)
    y = np.sign(np.sin(2 * np.pi * f * (t - t0) + 0.2)) + 0.1 * np.sin(2 * np.pi * 7 * f * t)  # rich in harmonics
    a = PeriodIntegrator(f, (1, 3), 1, t0).feed(t, y)
    b = ExactPeriodIntegrator(f, (1, 3), 1, t0).feed(t, y)
    for x, w in zip(a, b, strict=True):
        np.testing.assert_allclose(w, x, rtol=0, atol=1e-12)


def test_a_period_without_samples_inside_is_not_whole() -> None:
    f = 2.0
    t = np.arange(0, 6 * 64 + 1) / (64 * f)
    t = t[(t < 1.0) | (t > 1.6)]  # period 3 (u in [2, 3)) has no sample at all; 2 and 4 are cut short
    y = np.sin(2 * np.pi * f * t)
    p, q, whole = ExactPeriodIntegrator(f, (1, 3), 1).feed_marked(t, y)
    assert whole.tolist() == [True, True, False, True, True, True]
    assert np.abs(p[whole, 0, 0] - 1).max() < 1e-12 and np.abs(q[whole]).max() < 1e-12


def test_its_arguments_are_checked_as_the_trapezoids_are() -> None:
    with pytest.raises(ValueError, match="harmonics"):
        ExactPeriodIntegrator(1.0, (0, 1), 1)
    with pytest.raises(ValueError, match="shape"):
        ExactPeriodIntegrator(1.0, (1,), 2).feed(np.arange(3.0), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"t\[1\]"):
        ExactPeriodIntegrator(1.0, (1,), 1).feed(np.array([0.0, 0.0, 1.0]), np.zeros(3))


def test_a_drift_biases_the_trapezoid_by_its_known_amount_and_the_sampler_takes_it_off_and_reports_it() -> None:
    """The bench's case: 0.2 % of the response amplitude per second at 0.5 Hz (P_1 off by 2a / (w |Z|), 12.7 eps at
    0.01 %), a whole number of samples a period, so the drift is the only error."""
    from bodebench.core.autointegration import Autointegrator
    from bodebench.io.config import AnalysisConfig

    f, rate, amplitude, slope = 0.5, 1000.0, 1.0, 0.002
    t = np.arange(0, int(40 / f * rate) + 1) / rate
    y = amplitude * np.sin(2 * np.pi * f * t + 0.4) + slope * t
    p, q = PeriodIntegrator(f, (1,), 1).feed(t, y)
    bias = np.mean(p[:, 0, 0]) - amplitude * math.cos(0.4)
    assert bias == pytest.approx(-slope / (math.pi * f), rel=1e-3)
    sampler = Autointegrator(f, amplitude, ("y",), AnalysisConfig(harmonics=(1,), tolerance_percent=0.01), t0=0.0)
    sampler.feed(t, y[:, None])
    (point,) = sampler.points()
    assert point.converged
    assert abs(complex(point.p, point.q) - amplitude * complex(math.cos(0.4), math.sin(0.4))) < 1e-9
    assert point.drift_per_s == pytest.approx(slope, rel=1e-9)


@pytest.mark.parametrize("steps, offset", [(66, 0.37), (25, 0.5), (40, 0.9)])
def test_a_whole_grid_leaks_no_harmonic_above_the_fit_whatever_t0_is(steps: int, offset: float) -> None:
    """A uniform grid of a whole number of samples a period, t0 a fraction of a sample off it, and a response with
    every harmonic up to just below the Nyquist rate (a band-limited square-ish wave): period 1 starts on the first
    sample after t0, so no edge needs an interpolated sample and harmonics 1 .. 3 come out exact, as on the grid
    itself; the trapezoid with interpolated edges leaks the harmonics above into them, the same in every period."""
    f, rate = 5.0, 5.0 * steps
    t0 = 1.0 + offset / rate
    t = np.arange(int(t0 * rate) - 1, int(t0 * rate) + 60 * steps) / rate
    top = (steps - 1) // 2
    z = {k: complex(*np.random.default_rng(k).normal(size=2)) / k for k in range(1, top + 1)}
    y = signal(t, f, t0, 0.2, z)
    p, q = ExactPeriodIntegrator(f, (1, 2, 3), 1, t0).feed(t, y)
    for j, k in enumerate((1, 2, 3)):
        assert np.abs(p[:, 0, j] + 1j * q[:, 0, j] - z[k]).max() < 1e-11, k
    pt, qt = PeriodIntegrator(f, (1, 2, 3), 1, t0).feed(t, y)
    assert max(abs(np.mean(pt[:, 0, j] + 1j * qt[:, 0, j]) - z[k]) for j, k in enumerate((1, 2, 3))) > 1e-5
