"""Tests of the per-period trapezoidal Fourier integrator (instrument/core/fourier.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bodebench.core.fourier import GridPeriodIntegrator, PeriodIntegrator

# Test signal y = a sin(w x + phi) + b sin(2 w x + psi) + dc, x = t - t0, w = 2 pi f.
F = 7.3
T0 = 0.3
A, PHI = 1.5, 0.4
B, PSI = 0.7, -1.1
DC = 2.0
HARMONICS = (1, 2, 3)


def two_tone(t: np.ndarray, t0: float = T0) -> np.ndarray:
    x = t - t0
    return A * np.sin(2 * np.pi * F * x + PHI) + B * np.sin(4 * np.pi * F * x + PSI) + DC


# Analytic coefficients of two_tone for harmonics 1, 2, 3: sin(wx + phi) = cos(phi) sin(wx) + sin(phi) cos(wx).
EXACT_P = np.array([A * math.cos(PHI), B * math.cos(PSI), 0.0])
EXACT_Q = np.array([A * math.sin(PHI), B * math.sin(PSI), 0.0])


def reference(
    t: np.ndarray, y: np.ndarray, f: float, harmonics: tuple[int, ...], t0: float
) -> tuple[np.ndarray, np.ndarray]:
    """Straightforward per-segment loop: split each segment at period edges, trapezoid of the product.

    y has shape (n, C). Returns (P, Q) of shape (m, C, H) for every period that ends at or before t[-1].
    """
    n, n_c = y.shape
    n_h = len(harmonics)
    sums: dict[int, list[list[list[float]]]] = {}

    def values(tk: float, yk: np.ndarray, on_edge: bool) -> tuple[list[list[float]], list[list[float]]]:
        vs, vc = [], []
        for ch in range(n_c):
            row_s, row_c = [], []
            for k in harmonics:
                if on_edge:
                    sk, ck = 0.0, 1.0
                else:
                    arg = 2.0 * math.pi * k * f * (tk - t0)
                    sk, ck = math.sin(arg), math.cos(arg)
                row_s.append(float(yk[ch]) * sk)
                row_c.append(float(yk[ch]) * ck)
            vs.append(row_s)
            vc.append(row_c)
        return vs, vc

    for j in range(n - 1):
        ta, tb = float(t[j]), float(t[j + 1])
        knots = [(ta, *values(ta, y[j], False))]
        first_edge = math.floor((ta - t0) * f) + 1
        last_edge = math.floor((tb - t0) * f)
        for e in range(first_edge, last_edge + 1):
            te = t0 + e / f
            frac = (te - ta) / (tb - ta)
            ye = y[j] + frac * (y[j + 1] - y[j])
            knots.append((te, *values(te, ye, True)))
        knots.append((tb, *values(tb, y[j + 1], False)))
        for (tl, sl, cl), (tr, sr, cr) in zip(knots[:-1], knots[1:], strict=False):
            period = math.floor((0.5 * (tl + tr) - t0) * f) + 1  # 1-based period holding the piece
            if period < 1:
                continue
            acc = sums.setdefault(period, [[[0.0] * n_h for _ in range(n_c)] for _ in range(2)])
            for ch in range(n_c):
                for h in range(n_h):
                    acc[0][ch][h] += 2.0 * f * (tr - tl) / 2.0 * (sl[ch][h] + sr[ch][h])
                    acc[1][ch][h] += 2.0 * f * (tr - tl) / 2.0 * (cl[ch][h] + cr[ch][h])
    done = [i for i in sorted(sums) if t0 + i / f <= float(t[-1])]
    assert done == list(range(1, len(done) + 1))
    p = np.array([sums[i][0] for i in done]).reshape(len(done), n_c, n_h)
    q = np.array([sums[i][1] for i in done]).reshape(len(done), n_c, n_h)
    return p, q


def feed_chunks(
    integ: PeriodIntegrator, t: np.ndarray, y: np.ndarray, sizes: list[int]
) -> tuple[np.ndarray, np.ndarray]:
    out_p, out_q = [], []
    start = 0
    for size in sizes:
        p, q = integ.feed(t[start : start + size], y[start : start + size])
        out_p.append(p)
        out_q.append(q)
        start += size
    assert start == len(t)
    return np.concatenate(out_p), np.concatenate(out_q)


def random_sizes(rng: np.random.Generator, n: int) -> list[int]:
    sizes = []
    left = n
    while left > 0:
        size = int(min(left, rng.choice([0, 1, 1, 2, 3, 7, 50, 131])))
        sizes.append(size)
        left -= size
    return sizes


# ----------------------------------------------------------------- analytic coefficients


@pytest.mark.parametrize("t0", [0.0, T0, 1234.5678])
def test_aligned_uniform_grid_is_exact_for_trig_polynomials(t0: float) -> None:
    k_per = 64
    j = np.arange(5 * k_per + 2)  # one sample past the 5th period end so it closes even if rounded early
    t = t0 + j / (k_per * F)
    integ = PeriodIntegrator(F, HARMONICS, 1, t0)
    p, q = integ.feed(t, two_tone(t, t0))
    assert p.shape == q.shape == (5, 1, 3)
    assert integ.periods_done == 5
    np.testing.assert_allclose(p[:, 0, :], np.broadcast_to(EXACT_P, (5, 3)), rtol=0, atol=1e-11)
    np.testing.assert_allclose(q[:, 0, :], np.broadcast_to(EXACT_Q, (5, 3)), rtol=0, atol=1e-11)
    if t0 != 1234.5678:  # at t0 ~ 1e3 s the timestamps themselves carry ~1e-13 s rounding
        np.testing.assert_allclose(p[:, 0, :], np.broadcast_to(EXACT_P, (5, 3)), rtol=0, atol=1e-12)
        np.testing.assert_allclose(q[:, 0, :], np.broadcast_to(EXACT_Q, (5, 3)), rtol=0, atol=1e-12)


def test_dc_alone_gives_zero() -> None:
    k_per = 64
    t = np.arange(3 * k_per + 2) / (k_per * F)
    p, q = PeriodIntegrator(F, HARMONICS, 1).feed(t, np.full(t.shape, 5.0))
    np.testing.assert_allclose(p, 0.0, atol=1e-12)
    np.testing.assert_allclose(q, 0.0, atol=1e-12)


def test_harmonic_order_follows_the_argument() -> None:
    k_per = 64
    t = T0 + np.arange(2 * k_per + 2) / (k_per * F)
    y = two_tone(t)
    p1, q1 = PeriodIntegrator(F, (1, 2, 3), 1, T0).feed(t, y)
    p2, q2 = PeriodIntegrator(F, (3, 1, 2), 1, T0).feed(t, y)
    np.testing.assert_allclose(p2, p1[:, :, [2, 0, 1]], rtol=0, atol=1e-14)
    np.testing.assert_allclose(q2, q1[:, :, [2, 0, 1]], rtol=0, atol=1e-14)


def test_ramp_on_aligned_grid_matches_closed_form_and_converges_as_h_squared() -> None:
    # y = t - t0: exact P_k = -1/(pi k f), Q_k = 0. The trapezoid of the product has the Euler-Maclaurin
    # leading error (h^2/12) * 2f * (g'(end) - g'(start)) = pi k f h^2 / 3 since the integrand is not periodic.
    ks = np.array([1, 2])
    errors = []
    for k_per in (32, 64):
        t = T0 + np.arange(3 * k_per + 2) / (k_per * F)
        p, q = PeriodIntegrator(F, (1, 2), 1, T0).feed(t, t - T0)
        assert p.shape[0] == 3
        err = p[:, 0, :] + 1.0 / (np.pi * ks * F)
        h = 1.0 / (k_per * F)
        np.testing.assert_allclose(err, np.broadcast_to(np.pi * ks * F * h**2 / 3.0, err.shape), rtol=1e-2)
        np.testing.assert_allclose(q, 0.0, atol=1e-12)
        errors.append(np.abs(err).max())
    assert 3.9 < errors[0] / errors[1] < 4.1


def _max_error(p: np.ndarray, q: np.ndarray) -> float:
    return float(max(np.abs(p[:, 0, :] - EXACT_P).max(), np.abs(q[:, 0, :] - EXACT_Q).max()))


@pytest.mark.parametrize("samples_per_period, offset", [(100.0, 0.37), (100.5, 0.37), (64.0, 0.5)])
def test_edges_between_samples_converge(samples_per_period: float, offset: float) -> None:
    # Uniform grid with every edge off the samples at each rate. The integrand is periodic, so the interior
    # trapezoid error cancels and only the end pieces at the edges remain; each is O(h^3) (interpolation
    # error O(h^2) times piece length O(h)), so doubling the rate cuts the error by about 8.
    errors = []
    for factor in (1, 2, 4):
        k_per = samples_per_period * factor
        h = 1.0 / (k_per * F)
        t = T0 + (np.arange(-3, int(6 * k_per) + 3) + offset) * h
        p, q = PeriodIntegrator(F, HARMONICS, 1, T0).feed(t, two_tone(t))
        assert p.shape[0] == 6
        errors.append(_max_error(p, q))
    assert errors[0] < 1e-3
    for coarse, fine in zip(errors[:-1], errors[1:], strict=False):
        assert 6.0 < coarse / fine < 10.0


def test_jittered_samples_within_second_order_bound() -> None:
    # A priori bound on one period, hmax = largest sample spacing:
    #   2f * [ (1/f) * hmax^2/12 * max|(y s_k)''| + 2 * (hmax/2) * hmax^2/8 * max|y''| ]
    # (trapezoid error of each piece plus the interpolation error of the two edge samples).
    w = 2 * np.pi * F
    kmax = max(HARMONICS)
    y0, y1, y2 = A + B + DC, (A + 2 * B) * w, (A + 4 * B) * w**2
    max_g2 = y2 + 2 * y1 * kmax * w + y0 * (kmax * w) ** 2
    rng = np.random.default_rng(7)
    errors = []
    for k_per in (100, 200, 400):
        h = 1.0 / (k_per * F)
        j = np.arange(-3, 8 * k_per + 3)
        t = T0 + (j + 0.37 + rng.uniform(-0.3, 0.3, j.size)) * h
        p, q = PeriodIntegrator(F, HARMONICS, 1, T0).feed(t, two_tone(t))
        assert p.shape[0] == 8
        hmax = float(np.diff(t).max())
        bound = 2 * F * (hmax**2 / (12 * F) * max_g2 + hmax**3 / 8 * y2)
        err = _max_error(p, q)
        assert err <= bound
        errors.append(err)
    assert errors[-1] < 1e-4
    # Error shrinks at least as fast as the O(h^2) bound over a fourfold rate increase.
    assert errors[0] / errors[-1] > 16.0


def test_long_run_keeps_accuracy() -> None:
    # One sample at t0, then an aligned uniform stretch starting a million periods later: the
    # coefficients of the late periods still match the analytic values.
    k_per = 64
    start = 1_000_000
    t0 = 0.0
    j = np.arange(start * k_per, (start + 3) * k_per + 2)
    t = np.concatenate(([t0], t0 + j / (k_per * F)))
    integ = PeriodIntegrator(F, HARMONICS, 1, t0)
    p, q = integ.feed(t, two_tone(t, t0))
    assert integ.periods_done == start + 3
    np.testing.assert_allclose(p[start:, 0, :], np.broadcast_to(EXACT_P, (3, 3)), rtol=0, atol=1e-8)
    np.testing.assert_allclose(q[start:, 0, :], np.broadcast_to(EXACT_Q, (3, 3)), rtol=0, atol=1e-8)


# ----------------------------------------------------------------- against the reference loop


def test_ramp_on_coarse_nonuniform_grid_matches_reference() -> None:
    rng = np.random.default_rng(3)
    f, t0 = 2.0, 0.11
    t = np.sort(rng.uniform(t0 - 0.4, t0 + 2.2, 23))  # several samples before t0, about 9 per period
    y = t.copy()
    p, q = PeriodIntegrator(f, (1, 2, 5), 1, t0).feed(t, y)
    rp, rq = reference(t, y[:, None], f, (1, 2, 5), t0)
    assert p.shape == rp.shape == (4, 1, 3)
    np.testing.assert_allclose(p, rp, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q, rq, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_random_multichannel_stream_matches_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    f, t0 = 3.0, rng.uniform(-1, 1)
    n = 120
    t = t0 - 0.5 + np.cumsum(rng.exponential(1.0 / (12 * f), n))
    y = rng.normal(size=(n, 3))
    integ = PeriodIntegrator(f, (1, 2, 4), 3, t0)
    p, q = feed_chunks(integ, t, y, random_sizes(rng, n))
    rp, rq = reference(t, y, f, (1, 2, 4), t0)
    assert p.shape == rp.shape and p.shape[0] >= 3
    assert integ.periods_done == p.shape[0]
    np.testing.assert_allclose(p, rp, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q, rq, rtol=0, atol=1e-12)


def test_samples_on_edges_are_used_by_both_periods() -> None:
    # f = 1 Hz, t0 = 0, step 0.25 s: every 4th sample lies exactly on an edge (binary-exact times).
    t = np.arange(0, 13) * 0.25
    y = np.column_stack([np.cos(1.3 * t) + t, t**2])
    integ = PeriodIntegrator(1.0, (1, 2), 2)
    p, q = integ.feed(t, y)
    assert integ.periods_done == 3  # the last sample closes period 3 at once
    rp, rq = reference(t, y, 1.0, (1, 2), 0.0)
    np.testing.assert_allclose(p, rp, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q, rq, rtol=0, atol=1e-12)
    # Q of the first harmonic is the trapezoid of y * cos with weights h = 0.25: check by hand for period 2.
    ts = np.arange(4, 9) * 0.25
    g = y[4:9, 0] * np.cos(2 * np.pi * ts)
    by_hand = 2.0 * 0.25 * (g[0] / 2 + g[1:-1].sum() + g[-1] / 2)
    assert q[1, 0, 0] == pytest.approx(by_hand, abs=1e-13)


def test_segment_spanning_whole_periods() -> None:
    # A sample gap longer than several periods: each period wholly inside the gap has P = 0 and
    # Q = y(start) + y(end) of the linear interpolant (the reference functions are 0 and 1 at the edges).
    f, t0 = 10.0, 0.0
    t = np.array([-0.013, 0.02, 0.031, 0.547, 0.6, 0.66])
    y = np.array([1.0, -2.0, 0.5, 3.0, 4.0, -1.0])
    p, q = PeriodIntegrator(f, (1, 3), 1, t0).feed(t, y)
    rp, rq = reference(t, y[:, None], f, (1, 3), t0)
    assert p.shape == rp.shape == (6, 1, 2)
    np.testing.assert_allclose(p, rp, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q, rq, rtol=0, atol=1e-12)
    interp = np.interp([0.1, 0.2, 0.3, 0.4, 0.5], t, y)
    for i in range(1, 5):  # periods 2..5 (0-based rows 1..4) lie inside the gap 0.031 .. 0.547
        np.testing.assert_allclose(p[i, 0], 0.0, atol=1e-15)
        np.testing.assert_allclose(q[i, 0], interp[i - 1] + interp[i], rtol=1e-12)


# ----------------------------------------------------------------- invariances


@pytest.mark.parametrize("seed", range(3))
def test_chunking_does_not_change_results(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    k_per = 37.3
    h = 1.0 / (k_per * F)
    j = np.arange(-5, int(9 * k_per))
    t = T0 + (j + rng.uniform(-0.4, 0.4, j.size)) * h
    y = np.column_stack([two_tone(t), rng.normal(size=j.size)])
    whole = PeriodIntegrator(F, HARMONICS, 2, T0)
    p_all, q_all = whole.feed(t, y)
    ones = PeriodIntegrator(F, HARMONICS, 2, T0)
    p_one, q_one = feed_chunks(ones, t, y, [1] * len(t))
    mixed = PeriodIntegrator(F, HARMONICS, 2, T0)
    p_mix, q_mix = feed_chunks(mixed, t, y, random_sizes(rng, len(t)))
    assert p_all.shape[0] == 8
    assert whole.periods_done == ones.periods_done == mixed.periods_done == 8
    for p, q in ((p_one, q_one), (p_mix, q_mix)):
        assert p.shape == p_all.shape
        np.testing.assert_allclose(p, p_all, rtol=0, atol=1e-12)
        np.testing.assert_allclose(q, q_all, rtol=0, atol=1e-12)


def test_channels_together_match_channels_alone() -> None:
    rng = np.random.default_rng(11)
    n = 800
    t = T0 - 0.01 + np.cumsum(rng.uniform(0.5, 1.5, n)) / (60 * F)
    y = np.column_stack([two_tone(t), rng.normal(size=n), np.sin(3.3 * t), t])
    together = PeriodIntegrator(F, HARMONICS, 4, T0)
    p4, q4 = together.feed(t, y)
    assert p4.shape[0] >= 10
    for ch in range(4):
        p1, q1 = PeriodIntegrator(F, HARMONICS, 1, T0).feed(t, y[:, ch])
        np.testing.assert_allclose(p4[:, ch : ch + 1], p1, rtol=0, atol=1e-14)
        np.testing.assert_allclose(q4[:, ch : ch + 1], q1, rtol=0, atol=1e-14)


def test_empty_chunks_and_shapes() -> None:
    integ = PeriodIntegrator(F, (1, 2), 3, 0.0)
    p, q = integ.feed(np.array([]), np.zeros((0, 3)))
    assert p.shape == q.shape == (0, 3, 2)
    p, q = integ.feed(np.array([0.0]), np.zeros((1, 3)))
    assert p.shape == (0, 3, 2) and integ.periods_done == 0
    assert integ.harmonics == (1, 2) and integ.n_channels == 3 and integ.frequency_hz == F and integ.t0 == 0.0


# ----------------------------------------------------------------- bad input


def test_decreasing_time_names_the_index() -> None:
    integ = PeriodIntegrator(F, (1,), 1)
    t = np.array([0.0, 0.01, 0.02, 0.015, 0.03])
    with pytest.raises(ValueError, match=r"t\[3\]"):
        integ.feed(t, np.zeros(5))


def test_repeated_time_names_the_index() -> None:
    integ = PeriodIntegrator(F, (1,), 1)
    with pytest.raises(ValueError, match=r"t\[2\]"):
        integ.feed(np.array([0.0, 0.01, 0.01]), np.zeros(3))


def test_time_must_increase_across_calls() -> None:
    integ = PeriodIntegrator(F, (1,), 1)
    integ.feed(np.array([0.0, 0.01, 0.02]), np.zeros(3))
    with pytest.raises(ValueError, match=r"t\[0\].*previous call"):
        integ.feed(np.array([0.02, 0.03]), np.zeros(2))
    # The failed call left the state alone.
    p, _ = integ.feed(np.array([0.03, 1.0]), np.zeros(2))
    assert p.shape[0] == 7


def test_first_sample_after_t0_is_rejected() -> None:
    integ = PeriodIntegrator(F, (1,), 1, t0=1.0)
    with pytest.raises(ValueError, match="t0"):
        integ.feed(np.array([1.001, 1.002]), np.zeros(2))


@pytest.mark.parametrize(
    "t, y",
    [
        (np.zeros((3, 1)), np.zeros((3, 2))),  # t not 1-D
        (np.arange(3.0), np.zeros((3, 3))),  # wrong channel count
        (np.arange(3.0), np.zeros((4, 2))),  # wrong length
        (np.arange(3.0), np.zeros(3)),  # 1-D y with two channels
    ],
)
def test_wrong_shapes_are_rejected(t: np.ndarray, y: np.ndarray) -> None:
    with pytest.raises(ValueError, match="shape"):
        PeriodIntegrator(F, (1,), 2).feed(t, y)


def test_non_finite_input_is_rejected() -> None:
    with pytest.raises(ValueError, match=r"t\[1\]"):
        PeriodIntegrator(F, (1,), 1).feed(np.array([0.0, np.nan]), np.zeros(2))
    with pytest.raises(ValueError, match=r"y\[2\]"):
        PeriodIntegrator(F, (1,), 1).feed(np.array([0.0, 0.1, 0.2]), np.array([0.0, 1.0, np.inf]))


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"frequency_hz": 0.0}, "frequency_hz"),
        ({"frequency_hz": float("nan")}, "frequency_hz"),
        ({"harmonics": ()}, "harmonics"),
        ({"harmonics": (1, 0)}, "harmonics"),
        ({"harmonics": (1.5,)}, "harmonics"),
        ({"n_channels": 0}, "n_channels"),
        ({"t0": float("inf")}, "t0"),
    ],
)
def test_bad_constructor_arguments(kwargs: dict[str, object], word: str) -> None:
    args: dict[str, object] = {"frequency_hz": F, "harmonics": (1,), "n_channels": 1, "t0": 0.0}
    args.update(kwargs)
    with pytest.raises(ValueError, match=word):
        PeriodIntegrator(**args)  # type: ignore[arg-type]


# ----------------------------------------------------------------- the grid of a computation


def grid_stream(rng: np.random.Generator, steps: int, periods: int, t0_steps: int, channels: int
                ) -> tuple[float, np.ndarray, np.ndarray]:
    """t0 and the samples of a computation: every h = 1/(steps F) from t = 0, t0 a grid point."""
    h = 1.0 / (steps * F)
    # one sample past the last edge at least, so that the general integrator closes the period even if rounded early
    t = np.arange((t0_steps + periods) * steps + 2 + int(rng.integers(0, steps))) * h
    y = np.column_stack([two_tone(t, t0_steps * h)] + [rng.normal(size=t.size) + 50.0 * c
                                                         for c in range(1, channels)])
    return t0_steps * h, t, y


@pytest.mark.parametrize("seed", range(8))
def test_grid_integrator_matches_the_general_one(seed: int) -> None:
    rng = np.random.default_rng(300 + seed)
    steps = int(rng.choice([2, 3, 16, 200, 257]))
    harmonics = tuple(int(k) for k in rng.choice([1, 2, 3, 5], size=int(rng.integers(1, 4)), replace=False))
    channels = int(rng.integers(1, 4))
    t0, t, y = grid_stream(rng, steps, int(rng.integers(1, 9)), int(rng.integers(0, 4)), channels)
    general = PeriodIntegrator(F, harmonics, channels, t0)
    grid = GridPeriodIntegrator(F, harmonics, channels, steps, t0)
    p_ref, q_ref = general.feed(t, y)
    p, q = feed_chunks(grid, t, y, random_sizes(rng, len(t)))
    assert grid.periods_done == general.periods_done == p_ref.shape[0] > 0
    scale = max(1.0, float(np.abs(y).max()))
    np.testing.assert_allclose(p, p_ref, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(q, q_ref, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("offset", [0.0, 1e6])
def test_grid_integrator_is_exact_for_trig_polynomials_far_from_zero(offset: float) -> None:
    steps = 64
    t = np.arange(6 * steps + 1) / (steps * F)
    p, q = GridPeriodIntegrator(F, HARMONICS, 1, steps, t0=0.0).feed(t, two_tone(t, 0.0) + offset)
    assert p.shape == (6, 1, 3)
    # the samples themselves carry the offset's rounding, ~1e-10 at 1e6
    atol = 1e-13 + 1e-15 * offset
    np.testing.assert_allclose(p[:, 0, :], np.broadcast_to(EXACT_P, (6, 3)), rtol=0, atol=atol)
    np.testing.assert_allclose(q[:, 0, :], np.broadcast_to(EXACT_Q, (6, 3)), rtol=0, atol=atol)


def test_grid_integrator_takes_whole_periods_only_and_no_samples_before_t0() -> None:
    steps = 10
    h = 1.0 / (steps * F)
    t = np.arange(35) * h  # t0 at step 10: periods 1 and 2 end at steps 20 and 30
    y = np.where(t < 10 * h, 1e9, two_tone(t, 10 * h))
    grid = GridPeriodIntegrator(F, (1,), 1, steps, t0=10 * h)
    p, q, whole = grid.feed_marked(t, y)
    assert p.shape == (2, 1, 1) and whole.tolist() == [True, True]
    np.testing.assert_allclose(p[:, 0, 0], EXACT_P[0], rtol=0, atol=1e-12)
    p, _ = grid.feed(np.arange(35, 41) * h, two_tone(np.arange(35, 41) * h, 10 * h))
    assert p.shape[0] == 1 and grid.periods_done == 3


def test_grid_integrator_names_a_sample_off_the_grid_or_skipped() -> None:
    h = 1.0 / (20 * F)
    grid = GridPeriodIntegrator(F, (1,), 1, 20)
    t = np.arange(10) * h
    t[6] += 0.3 * h
    with pytest.raises(ValueError, match=r"t\[6\].*grid of 20 steps"):
        grid.feed(t, np.zeros(10))
    grid.feed(np.arange(5) * h, np.zeros(5))  # the failed call left the state alone
    with pytest.raises(ValueError, match="step 5 comes next"):
        grid.feed(np.arange(6, 9) * h, np.zeros(3))
    with pytest.raises(ValueError, match="steps_per_period"):
        GridPeriodIntegrator(F, (1,), 1, 1)
