"""Physics tests of the simulated plants (sim/plants.py).

Every expected value here comes from a closed form (forced response from rest, free decay of the
friction link, statics of the stuck state) or from an independent discretisation (scipy's
zero-order-hold), never from a run of the code under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from bodebench.sim.plants import CoulombOscillator, FirstOrderLag, LinearOscillator, Plant

# The 2013 test plant (docs/METHOD.md section 2): resonance near 10 Hz.
MASS = 2.533e-4
STIFFNESS = 1.0
AMPLITUDE = 0.01
F_N = math.sqrt(STIFFNESS / MASS) / (2.0 * math.pi)


def assert_columns_close(actual: np.ndarray, expected: np.ndarray, rel: float) -> None:
    """Every column of actual within rel * (largest |value| of that column of expected)."""
    assert actual.shape == expected.shape
    for col in range(expected.shape[1]):
        scale = float(np.max(np.abs(expected[:, col])))
        err = float(np.max(np.abs(actual[:, col] - expected[:, col])))
        assert err <= rel * scale, f"column {col}: max error {err:.3e} > {rel:g} * {scale:.3e}"


def run_from_rest(plant: Plant, frequency_hz: float, steps_per_period: int, periods: int,
                  amplitude: float = AMPLITUDE) -> tuple[np.ndarray, np.ndarray]:
    """Sample times (s) and outputs of a run from rest under amplitude*sin(2 pi f t)."""
    h = 1.0 / (steps_per_period * frequency_hz)
    n = steps_per_period * periods
    out = plant.run_sine(plant.initial_state(), 0.0, h, n, amplitude, frequency_hz)
    return h * np.arange(1, n + 1), out


# ------------------------------------------------------------------ closed forms of the linear plants


def oscillator_from_rest(mass: float, stiffness: float, zeta: float, amplitude: float, frequency_hz: float,
                         t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact Y(t), V(t) of m Y'' + c Y' + k Y = A sin(w t), Y(0) = V(0) = 0, c = 2 zeta sqrt(k m), zeta < 1.

    Particular solution Im(A G e^{jwt}) with G = 1/(k - m w^2 + j c w), plus the damped free oscillation
    that cancels its initial position and velocity. The undamped resonant case has its own closed form.
    """
    wn = math.sqrt(stiffness / mass)
    w = 2.0 * math.pi * frequency_hz
    if zeta == 0.0 and w == wn:
        y = amplitude / (2.0 * stiffness) * (np.sin(w * t) - w * t * np.cos(w * t))
        v = amplitude * w * w / (2.0 * stiffness) * t * np.sin(w * t)
        return y, v
    c = 2.0 * zeta * math.sqrt(stiffness * mass)
    ag = amplitude / complex(stiffness - mass * w * w, c * w)
    rot = np.exp(1j * w * t)
    y_p = (ag * rot).imag
    v_p = (1j * w * ag * rot).imag
    sigma = zeta * wn
    wd = wn * math.sqrt(1.0 - zeta * zeta)
    c1 = -ag.imag
    c2 = (sigma * c1 - w * ag.real) / wd
    decay = np.exp(-sigma * t)
    y_h = decay * (c1 * np.cos(wd * t) + c2 * np.sin(wd * t))
    v_h = decay * ((-sigma * c1 + wd * c2) * np.cos(wd * t) + (-sigma * c2 - wd * c1) * np.sin(wd * t))
    return y_p + y_h, v_p + v_h


def lag_from_rest(time_constant: float, gain: float, amplitude: float, frequency_hz: float,
                  t: np.ndarray) -> np.ndarray:
    """Exact y(t) of T y' + y = K A sin(w t), y(0) = 0."""
    wt = 2.0 * math.pi * frequency_hz * time_constant
    w = 2.0 * math.pi * frequency_hz
    return gain * amplitude / (1.0 + wt * wt) * (np.sin(w * t) - wt * np.cos(w * t) + wt * np.exp(-t / time_constant))


@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.7])
@pytest.mark.parametrize("ratio", [0.1, 0.93, 1.0, 1.07, 4.0])
def test_linear_oscillator_run_sine_matches_closed_form(zeta: float, ratio: float) -> None:
    f = ratio * F_N
    plant = LinearOscillator(MASS, STIFFNESS, zeta)
    t, out = run_from_rest(plant, f, 64, 40)
    y, v = oscillator_from_rest(MASS, STIFFNESS, zeta, AMPLITUDE, f, t)
    # exact discretisation: only round-off accumulates over the 2560 steps
    np.testing.assert_allclose(out[:, 0], y, rtol=0, atol=1e-11 * np.max(np.abs(y)))
    np.testing.assert_allclose(out[:, 1], v, rtol=0, atol=1e-11 * np.max(np.abs(v)))


def test_conservative_link_at_resonance_grows_linearly() -> None:
    """Undamped at exactly f_n: the envelope grows by pi A / k every period and never settles."""
    plant = LinearOscillator(MASS, STIFFNESS, 0.0)
    t, out = run_from_rest(plant, F_N, 200, 50)
    y, _ = oscillator_from_rest(MASS, STIFFNESS, 0.0, AMPLITUDE, F_N, t)
    np.testing.assert_allclose(out[:, 0], y, rtol=0, atol=1e-11 * np.max(np.abs(y)))
    # samples at whole periods: Y(nT) = -A/(2k) * 2 pi n exactly
    n = np.arange(1, 51)
    np.testing.assert_allclose(out[200 * n - 1, 0], -AMPLITUDE / (2.0 * STIFFNESS) * 2.0 * math.pi * n,
                               rtol=1e-10)


@pytest.mark.parametrize("frequency_hz", [0.5, 15.9, 300.0])
def test_first_order_lag_run_sine_matches_closed_form(frequency_hz: float) -> None:
    plant = FirstOrderLag(0.01, 2.5)
    t, out = run_from_rest(plant, frequency_hz, 50, 30, amplitude=0.3)
    y = lag_from_rest(0.01, 2.5, 0.3, frequency_hz, t)
    np.testing.assert_allclose(out[:, 0], y, rtol=0, atol=1e-11 * np.max(np.abs(y)))


def zoh_reference(a: np.ndarray, b: np.ndarray, h: float, setpoints: np.ndarray) -> np.ndarray:
    """States at the end of each held step, from scipy's zero-order-hold discretisation and dlsim."""
    n = a.shape[0]
    ad, bd, cd, dd, _ = signal.cont2discrete((a, b.reshape(n, 1), np.eye(n), np.zeros((n, 1))), h, method="zoh")
    # one extra input so that dlsim reports the state after the last real step
    u = np.concatenate([setpoints, [0.0]])
    _, _, x = signal.dlsim((ad, bd, cd, dd, h), u, x0=np.zeros(n))
    return x[1:]


@pytest.mark.parametrize("plant", [LinearOscillator(MASS, STIFFNESS, 0.05), LinearOscillator(MASS, STIFFNESS, 0.0),
                                   FirstOrderLag(0.01, 2.5)], ids=["oscillator", "conservative", "lag"])
def test_run_held_matches_scipy_zero_order_hold(plant: LinearOscillator | FirstOrderLag) -> None:
    rng = np.random.default_rng(7)
    setpoints = rng.uniform(-0.01, 0.01, 3000)
    h = 1e-3
    out = plant.run_held(plant.initial_state(), setpoints, h)
    x = zoh_reference(plant.a, plant.b, h, setpoints)
    expected = x @ plant.c.T
    scale = np.max(np.abs(expected), axis=0)
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-10 * float(np.max(scale)))


def test_run_held_continues_from_state_across_calls() -> None:
    plant = LinearOscillator(MASS, STIFFNESS, 0.05)
    setpoints = np.sin(np.arange(1000) * 0.01)
    whole = plant.run_held(plant.initial_state(), setpoints, 1e-3)
    state = plant.initial_state()
    parts = [plant.run_held(state, chunk, 1e-3) for chunk in np.split(setpoints, [1, 7, 300, 301, 650])]
    np.testing.assert_allclose(np.concatenate(parts), whole, rtol=0, atol=1e-14 * np.max(np.abs(whole)))


# ------------------------------------------------------------------ friction link without friction


@pytest.mark.parametrize("zeta", [0.0, 0.1])
@pytest.mark.parametrize("ratio", [0.3, 1.0, 2.2])
def test_coulomb_without_friction_is_the_linear_oscillator(zeta: float, ratio: float) -> None:
    f = ratio * F_N
    _, lin = run_from_rest(LinearOscillator(MASS, STIFFNESS, zeta), f, 200, 20)
    _, dry = run_from_rest(CoulombOscillator(MASS, STIFFNESS, 0.0, zeta), f, 200, 20)
    assert_columns_close(dry, lin, 1e-12)


@pytest.mark.parametrize("zeta", [0.0, 0.1])
def test_coulomb_without_friction_run_held_is_the_linear_oscillator(zeta: float) -> None:
    rng = np.random.default_rng(3)
    setpoints = rng.uniform(-0.01, 0.01, 2000)
    lin = LinearOscillator(MASS, STIFFNESS, zeta)
    dry = CoulombOscillator(MASS, STIFFNESS, 0.0, zeta)
    a = lin.run_held(lin.initial_state(), setpoints, 1e-3)
    b = dry.run_held(dry.initial_state(), setpoints, 1e-3)
    assert_columns_close(b, a, 1e-12)


# ------------------------------------------------------------------ sticking


@pytest.mark.parametrize("fbar", [0.8, 0.95])
@pytest.mark.parametrize("ratio", [0.3, 0.6, 1.5])
def test_sticking_is_exact_and_does_not_chatter(fbar: float, ratio: float) -> None:
    """Steady stick-slip: stuck samples have V == 0.0 and one fixed position inside the friction band,
    break-away happens exactly where the closed-form net force leaves the band, and the velocity
    changes sign exactly twice per period."""
    kf, settle, analysed = 400, 80, 20
    f = ratio * F_N
    friction = fbar * AMPLITUDE
    w = 2.0 * math.pi * f
    t, out = run_from_rest(CoulombOscillator(MASS, STIFFNESS, friction), f, kf, settle + analysed)
    t, y, v = t[settle * kf:], out[settle * kf:, 0], out[settle * kf:, 1]
    u = AMPLITUDE * np.sin(w * t)  # the input at the sample instants, exactly

    stuck = v == 0.0
    assert stuck.any(), "Fbar >= 0.8 here must produce stuck phases"
    # maximal runs of stuck samples; runs cut by the window's edges are left out
    change = np.diff(np.concatenate([[0], stuck.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(change == 1), np.flatnonzero(change == -1) - 1
    complete = (starts > 0) & (ends < stuck.size - 1)
    starts, ends = starts[complete], ends[complete]
    # one stop at each end of the stroke: two stuck phases per period
    assert 2 * analysed - 2 <= starts.size <= 2 * analysed
    slack = 1e-12 * AMPLITUDE
    for i0, i1 in zip(starts, ends, strict=False):
        ys = y[i0]
        assert np.all(y[i0:i1 + 1] == ys), "position must not move while stuck"
        assert np.all(np.abs(u[i0:i1 + 1] - STIFFNESS * ys) <= friction + slack)
        # the next sample lies past the break-away instant: the net force on the held position is out of band
        assert abs(AMPLITUDE * math.sin(w * t[i1 + 1]) - STIFFNESS * ys) > friction - slack
        assert v[i1 + 1] != 0.0
    # the stuck positions alternate between +Y_s and -Y_s (half-wave symmetric stops)
    stops = y[starts]
    assert np.all(np.sign(stops[1:]) == -np.sign(stops[:-1]))

    moving = v[v != 0.0]
    changes = int(np.count_nonzero(np.diff(np.sign(moving))))
    assert 2 * analysed - 1 <= changes <= 2 * analysed


@pytest.mark.parametrize("u_held,expected_stop", [(0.004, None), (-0.01, None), (0.015, 0.01), (-0.025, -0.03)])
def test_held_force_breakaway_and_stop(u_held: float, expected_stop: float | None) -> None:
    """Constant force u from rest with friction F = 0.01, k = 1: inside the band nothing moves; above it the
    mass swings to 2(u - F)/k in half a natural period and stays there for good when |u - 2(u - F)| <= F."""
    friction = 0.01
    plant = CoulombOscillator(MASS, STIFFNESS, friction)
    half_period = math.pi * math.sqrt(MASS / STIFFNESS)
    n_half = 500
    h = half_period / n_half
    out = plant.run_held(plant.initial_state(), np.full(4 * n_half, u_held), h)
    if expected_stop is None:
        assert np.all(out == 0.0)
        return
    s = math.copysign(1.0, u_held)
    tt = h * np.arange(1, n_half + 1)
    wn = math.sqrt(STIFFNESS / MASS)
    swing = (u_held - s * friction) / STIFFNESS * (1.0 - np.cos(wn * tt))
    np.testing.assert_allclose(out[:n_half, 0], swing, rtol=0, atol=1e-12)
    assert np.all(np.sign(out[:n_half - 1, 1]) == s)
    assert out[n_half - 1, 0] == pytest.approx(expected_stop, rel=1e-10)
    rest = out[n_half:]
    assert np.all(rest[:, 1] == 0.0)
    assert np.all(rest[:, 0] == rest[0, 0])


# ------------------------------------------------------------------ free decay


def test_free_decay_loses_four_f_over_k_per_cycle_and_stops_for_good() -> None:
    """Free motion from Y0 at rest: each half cycle lasts pi sqrt(m/k) and ends 2F/k closer to zero
    (the swing about the offset +-F/k keeps its size); the link stops at the first turning point with
    |k Y| <= F and never moves again."""
    mass, stiffness, friction = 1.0, 4.0, 0.25  # 2F/k = 0.125, F/k = 0.0625
    y0 = 1.03
    drop = 2.0 * friction / stiffness
    turning = [y0]
    while abs(stiffness * turning[-1]) > friction:
        n = len(turning)
        turning.append((-1.0) ** n * (y0 - n * drop))
    n_turns = len(turning) - 1  # half cycles of motion
    assert n_turns == 8 and turning[-1] == pytest.approx(0.03)

    plant = CoulombOscillator(mass, stiffness, friction)
    state = plant.initial_state()
    state.x[:] = (y0, 0.0)
    n_half = 1000
    wn = math.sqrt(stiffness / mass)
    h = math.pi / wn / n_half
    out = plant.run_sine(state, 0.0, h, (n_turns + 3) * n_half, 0.0, 1.0)
    y, v = out[:, 0], out[:, 1]
    for n in range(1, n_turns + 1):
        j = n * n_half - 1  # sample at t = n * pi / wn
        assert y[j] == pytest.approx(turning[n], rel=0, abs=1e-9 * y0)
        assert abs(v[j]) <= 1e-9 * wn * y0
        inside = v[(n - 1) * n_half:n * n_half - 1]
        assert np.all(np.sign(inside) == (-1.0) ** n), f"half cycle {n} must move one way only"
    after = slice(n_turns * n_half, None)
    assert np.all(v[after] == 0.0)
    assert np.all(y[after] == y[n_turns * n_half])
    assert y[n_turns * n_half] == pytest.approx(turning[-1], rel=0, abs=1e-9 * y0)


# ------------------------------------------------------------------ chunking


@pytest.mark.parametrize("plant", [CoulombOscillator(MASS, STIFFNESS, 0.008), CoulombOscillator(MASS, STIFFNESS, 0.001),
                                   LinearOscillator(MASS, STIFFNESS, 0.05)], ids=["fbar0.8", "fbar0.1", "linear"])
def test_run_sine_does_not_depend_on_chunking(plant: Plant) -> None:
    f, kf, periods = 6.3, 200, 30
    h = 1.0 / (kf * f)
    n = kf * periods
    whole = plant.run_sine(plant.initial_state(), 0.0, h, n, AMPLITUDE, f)
    rng = np.random.default_rng(11)
    cuts = np.sort(rng.choice(np.arange(1, n), size=40, replace=False))
    state = plant.initial_state()
    parts = []
    for a, b in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [n]]), strict=False):
        parts.append(plant.run_sine(state, a * h, h, int(b - a), AMPLITUDE, f))
    chunked = np.concatenate(parts)
    assert_columns_close(chunked, whole, 1e-12)
