"""Physics of the second-order link with Coulomb friction, measured through the instrument.

The expected values come from physics, not from runs of the code under test: the energy balance of a
periodic motion, half-wave symmetry, the exact stop-free periodic solution (derived below, after Den
Hartog 1931), the free oscillation that survives at f = f_n / 2, the growth rate at resonance and the
convergence order of the trapezoidal rule.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest
from scipy.integrate import quad

from bodebench.bench.offline import measure_frequency
from bodebench.core.fourier import PeriodIntegrator
from bodebench.core.rules import CRITERIA
from bodebench.io.config import CaseConfig, parse_config
from bodebench.sim.plants import CoulombOscillator

# The 2013 test plant (docs/METHOD.md section 2).
MASS = 2.533e-4
STIFFNESS = 1.0
AMPLITUDE = 0.01  # A_F
F_N = math.sqrt(STIFFNESS / MASS) / (2.0 * math.pi)
X_ST = AMPLITUDE / STIFFNESS  # static deflection under the force amplitude

KF = 400  # steps per period of the direct runs
SETTLE = 300  # periods before the analysed one; every case below has settled to round-off by then
FINE = 256  # sub-steps per step of the fine pass that locates the turning points


# ------------------------------------------------------------------ exact stop-free periodic solution


@dataclasses.dataclass(frozen=True)
class PeriodicSolution:
    """Stop-free, half-wave-symmetric periodic motion, in units of the static deflection X_ST.

    y_max: peak displacement (Den Hartog's amplitude); z1: first-harmonic coefficient P + jQ of Y
    (phase convention Y1 = |z1| sin(wt + arg z1)).
    """

    y_max: float
    z1: complex


def stop_free_solution(fbar: float, ratio: float) -> PeriodicSolution | None:
    """The exact periodic motion with one reversal per half period and no stops, or None where none exists.

    Units: m = k = 1 (w_n = 1), force amplitude 1, friction fbar, w = ratio. Let the motion reverse
    upward at phase theta0 = w t0 with Y = -Y_max. While V > 0:

        Y(t) = -fbar + a sin(wt) + C1 cos(t - t0) + C2 sin(t - t0),   a = 1 / (1 - w^2).

    Half-wave symmetry requires V(t0) = 0, Y(t0) = -Y_max, Y(t0 + T/2) = +Y_max, V(t0 + T/2) = 0,
    with w_n T/2 = pi/ratio; with c = cos(pi/ratio), s = sin(pi/ratio) these give
    C2 = -a w cos(theta0), C1 = C2 (1 + c)/s, cos(theta0) = -fbar (1 - w^2) s / (w (1 + c))
    and Y_max = -a sin(theta0), i.e. Y_max = sqrt(V0^2 - fbar^2 U0^2), V0 = 1/(1 - w^2),
    U0 = s / (w (1 + c)) (Den Hartog's amplitude). The solution is physical only when V > 0 over the
    whole half period and the net force at the reversal exceeds the friction (no stop).
    """
    w = ratio
    a = 1.0 / (1.0 - w * w)
    c, s = math.cos(math.pi / w), math.sin(math.pi / w)
    cos0 = -fbar * (1.0 - w * w) * s / (w * (1.0 + c))
    if abs(cos0) >= 1.0:
        return None
    sin0 = -math.copysign(math.sqrt(1.0 - cos0 * cos0), a)  # chosen so that Y_max > 0
    y_max = -a * sin0
    c2 = -a * w * cos0
    c1 = c2 * (1.0 + c) / s
    t0 = math.atan2(sin0, cos0) / w
    half = math.pi / w

    def y(t: float) -> float:
        return -fbar + a * math.sin(w * t) + c1 * math.cos(t - t0) + c2 * math.sin(t - t0)

    tt = t0 + np.linspace(0.0, half, 4001)
    v = a * w * np.cos(w * tt) - c1 * np.sin(tt - t0) + c2 * np.cos(tt - t0)
    # the four conditions hold (checks the algebra above)
    assert abs(y(t0) + y_max) < 1e-12 * y_max and abs(y(t0 + half) - y_max) < 1e-12 * y_max
    assert abs(v[0]) < 1e-12 * y_max and abs(v[-1]) < 1e-12 * y_max
    if np.any(v[1:-1] <= 0.0):
        return None
    if math.sin(w * t0) + y_max <= fbar:  # net force U - kY at the reversal: the link would stop
        return None
    # first harmonic: by half-wave symmetry, twice the integral over the upward half
    period = 2.0 * half
    tol = 1e-14 * y_max * half
    p = 4.0 / period * quad(lambda t: y(t) * math.sin(w * t), t0, t0 + half, epsabs=tol, epsrel=1e-13)[0]
    q = 4.0 / period * quad(lambda t: y(t) * math.cos(w * t), t0, t0 + half, epsabs=tol, epsrel=1e-13)[0]
    return PeriodicSolution(y_max, complex(p, q))


def test_stop_free_solution_reduces_to_the_linear_response_without_friction() -> None:
    for ratio in (0.3, 0.6, 1.5, 3.0):
        sol = stop_free_solution(0.0, ratio)
        assert sol is not None
        assert sol.y_max == pytest.approx(1.0 / abs(1.0 - ratio * ratio), rel=1e-12)
        assert sol.z1 == pytest.approx(1.0 / (1.0 - ratio * ratio), rel=1e-10)


# ------------------------------------------------------------------ a settled run, measured directly


@dataclasses.dataclass(frozen=True)
class SteadyRun:
    z: np.ndarray  # (periods, 4): per-period coefficients of harmonics 1..4 of Y
    y: np.ndarray  # Y at the samples of the last period
    v: np.ndarray  # V at the same samples
    y_fine: np.ndarray  # Y over one more period at KF * FINE samples


@functools.cache
def steady_run(fbar: float, ratio: float, periods: int = SETTLE + 1) -> SteadyRun:
    """Run the link from rest at f = ratio * f_n for ``periods`` periods (KF steps each), then one finer period."""
    f = ratio * F_N
    h = 1.0 / (KF * f)
    plant = CoulombOscillator(MASS, STIFFNESS, fbar * AMPLITUDE)
    state = plant.initial_state()
    n = KF * periods
    out = plant.run_sine(state, 0.0, h, n, AMPLITUDE, f)
    t = h * np.arange(0, n + 1)
    y = np.concatenate([[0.0], out[:, 0]])
    p, q = PeriodIntegrator(f, (1, 2, 3, 4), 1).feed(t, y)
    fine = plant.run_sine(state, n * h, h / FINE, KF * FINE, AMPLITUDE, f)
    return SteadyRun(p[:, 0, :] + 1j * q[:, 0, :], out[-KF:, 0], out[-KF:, 1], fine[:, 0])


def assert_settled(run: SteadyRun) -> None:
    """Precondition of the steady-state tests: the last two periods agree to round-off."""
    z1 = run.z[:, 0]
    assert abs(z1[-1] - z1[-2]) <= 1e-10 * abs(z1[-1])


def sign_changes(v: np.ndarray) -> int:
    moving = v[v != 0.0]
    return int(np.count_nonzero(np.diff(np.sign(moving))))


ENERGY_CASES = [(fbar, ratio) for fbar in (0.5, 0.8, 0.95) for ratio in (0.3, 0.6, 1.5, 3.0)]


@pytest.mark.parametrize("fbar,ratio", ENERGY_CASES)
def test_energy_balance_per_period(fbar: float, ratio: float) -> None:
    """Input work over a period, pi A |Y1| sin(-phi) = -pi A Q1, equals the friction's dissipation
    F * (distance travelled) = 2 F (Y_max - Y_min) when the motion reverses twice per period."""
    run = steady_run(fbar, ratio)
    assert_settled(run)
    assert sign_changes(run.v) in (1, 2)  # one period: two reversals, one possibly across the window edge
    friction = fbar * AMPLITUDE
    # stops happen exactly where no stop-free periodic solution exists
    assert np.any(run.v == 0.0) == (stop_free_solution(fbar, ratio) is None)
    q1 = run.z[-1, 0].imag
    work_in = -math.pi * AMPLITUDE * q1
    # turning points: exact stuck positions, or reversals located on the fine grid (error ~(w h / FINE)^2 / 2)
    dissipated = 2.0 * friction * (run.y_fine.max() - run.y_fine.min())
    # the product Y sin(wt) has a kink in its second derivative at every stop and reversal, so the
    # trapezoid's error at K_f = 400 is of order (2 pi / K_f)^3 ~ 1e-7 of Q1: 1e-6 bounds it
    assert work_in == pytest.approx(dissipated, rel=1e-6)


HALF_WAVE_CASES = [(fbar, ratio) for fbar in (0.1, 0.5, 0.8, 0.95) for ratio in (0.3, 0.6, 1.5, 3.0)]


@pytest.mark.parametrize("fbar,ratio", HALF_WAVE_CASES)
def test_half_wave_symmetry(fbar: float, ratio: float) -> None:
    """Odd forcing, odd friction law: the settled motion obeys Y(t + T/2) = -Y(t), so it has no even harmonics."""
    run = steady_run(fbar, ratio)
    assert_settled(run)
    half = KF // 2
    scale = float(np.max(np.abs(run.y)))
    assert float(np.max(np.abs(run.y[half:] + run.y[:half]))) <= 1e-9 * scale
    assert float(np.max(np.abs(run.v[half:] + run.v[:half]))) <= 1e-9 * float(np.max(np.abs(run.v)))
    z1 = abs(run.z[-1, 0])
    assert abs(run.z[-1, 1]) <= 1e-9 * z1
    assert abs(run.z[-1, 3]) <= 1e-9 * z1
    assert abs(run.z[-1, 2]) > 1e-6 * z1  # the odd harmonics of the friction's square wave are there


def test_free_oscillation_survives_at_half_the_natural_frequency() -> None:
    """At f = f_n/2 the friction force (a square wave at f, odd harmonics only) does no work on a motion at
    f_n = 2f, so a free oscillation left by the start-up never decays: the even part of Y is a pure f_n
    sinusoid with P2 = 0 (it turns with the odd part, at wt = -pi/2), and the odd part is the symmetric
    periodic solution, whose first harmonic does not depend on the free oscillation's amplitude."""
    fbar = 0.1
    run = steady_run(fbar, 0.5, periods=1000)
    z1, z2, z4 = run.z[:, 0], run.z[:, 1], run.z[:, 3]
    assert abs(z2[-1]) > 1e-2 * abs(z1[-1])  # a large free oscillation at f_n ...
    assert abs(z2[-1] - z2[100]) <= 1e-9 * abs(z2[-1])  # ... that does not decay at all
    assert abs(z2[-1].real) <= 1e-9 * abs(z2[-1])
    assert abs(z4[-1]) <= 1e-9 * abs(z1[-1])
    # odd part, w = 1/2 (units m = k = A = 1): upward from t0 = -T/4 (wt0 = -pi/2):
    # Y = -fbar + a sin(wt) + fbar cos(t - t0) (w_n = 1), a = 1/(1 - 1/4), extended half-wave antisymmetric
    w, a = 0.5, 4.0 / 3.0
    t0, half = -math.pi / 2.0 / w, math.pi / w

    def odd(t: float) -> float:
        return -fbar + a * math.sin(w * t) + fbar * math.cos(t - t0)

    p = 2.0 / half * quad(lambda t: odd(t) * math.sin(w * t), t0, t0 + half, epsabs=0.0, epsrel=1e-13)[0]
    q = 2.0 / half * quad(lambda t: odd(t) * math.cos(w * t), t0, t0 + half, epsabs=0.0, epsrel=1e-13)[0]
    assert z1[-1] / X_ST == pytest.approx(complex(p, q), rel=1e-8)
    # just off f_n/2 the same start-up transient dies out
    for ratio in (0.48, 0.52):
        near = steady_run(fbar, ratio, periods=1000)
        assert abs(near.z[-1, 1]) <= 1e-10 * abs(near.z[-1, 0])


# ------------------------------------------------------------------ through the sweep machinery


def friction_case(fbar: float, frequency_hz: float, **analysis: object) -> CaseConfig:
    data = {
        "plant": {"model": "coulomb", "mass": MASS, "stiffness": STIFFNESS, "friction": fbar * AMPLITUDE},
        "excitation": {"amplitude": AMPLITUDE, "frequencies_hz": [frequency_hz]},
        "analysis": {"harmonics": [1], **analysis},
    }
    return parse_config(data).cases[0]


DEN_HARTOG_CASES = [(fbar, ratio) for fbar in (0.1, 0.5) for ratio in (0.6, 1.5, 3.0)]


@pytest.mark.parametrize("fbar,ratio", DEN_HARTOG_CASES)
def test_first_harmonic_matches_the_exact_stop_free_solution(fbar: float, ratio: float) -> None:
    """Gain and phase of the measured first harmonic against the exact periodic solution's fundamental.

    Note: the describing-function phase -asin(4 Fbar / pi) (below f_n) is the limit at f -> f_n only;
    the exact phase obeys sin(-phi) = 4 Fbar Y_max / (pi |Y1|) and differs from it by up to a few degrees
    here (Y_max != |Y1| away from resonance), so the exact solution is the reference.
    """
    sol = stop_free_solution(fbar, ratio)
    assert sol is not None
    # energy balance of the exact solution itself
    assert math.sin(-math.atan2(sol.z1.imag, sol.z1.real)) == pytest.approx(
        4.0 * fbar * sol.y_max / (math.pi * abs(sol.z1)), rel=1e-10)
    f = ratio * F_N
    case = friction_case(fbar, f, tolerance_percent=1e-5, steps_per_period=KF, max_periods=3000)
    (point,) = measure_frequency(case, f)
    assert point.converged
    expected_phase = math.degrees(math.atan2(sol.z1.imag, sol.z1.real)) % -360.0
    # trapezoid error at K_f = 400 and the rule's tolerance (1e-7) are both far below these bounds
    assert point.gain == pytest.approx(abs(sol.z1) / STIFFNESS, rel=1e-6)
    assert point.phase_deg == pytest.approx(expected_phase, abs=1e-4)


def test_step_refinement_converges_at_a_sticking_point() -> None:
    """Fbar = 0.8, f = 3 Hz: stick-slip. The samples are exact, so K_f only changes the trapezoid's error,
    which comes from the kinks of the motion and falls at least ~4x per doubling of K_f."""
    base = friction_case(0.8, 3.0, criterion="fixed", settle_periods=40, average_periods=4)
    z = []
    for kf in (50, 100, 200, 400, 800):
        case = dataclasses.replace(base, analysis=dataclasses.replace(base.analysis, steps_per_period=kf))
        (point,) = measure_frequency(case, 3.0)
        assert point.status == "fixed"
        z.append(complex(point.p, point.q))
    diffs = [abs(b - a) / abs(b) for a, b in zip(z, z[1:], strict=False)]
    for coarse, fine in zip(diffs, diffs[1:], strict=False):
        assert fine <= coarse / 3.5, f"differences {diffs} do not shrink like h^2"
    assert diffs[-1] < 1e-6
    gain = [abs(x) / AMPLITUDE for x in z]
    phase = [math.atan2(x.imag, x.real) for x in z]
    assert abs(gain[-1] - gain[-2]) < 1e-6 * gain[-1]
    assert abs(phase[-1] - phase[-2]) < 1e-6


PRINTED = ("full", "none", "local", "combined1", "combined2", "combined3")
FIXED_PERIODS = {"first_period": 1, "sixth_of_six": 6, "fixed": 50 + 50}


@pytest.mark.parametrize("plant", [
    {"model": "linear", "mass": MASS, "stiffness": STIFFNESS, "damping_ratio": 0.0},
    {"model": "coulomb", "mass": MASS, "stiffness": STIFFNESS, "friction": 0.1 * AMPLITUDE},
], ids=["conservative", "fbar0.1"])
def test_every_criterion_ends_on_a_response_that_never_settles(plant: dict[str, object]) -> None:
    """At f_n the conservative link and the link with Fbar < pi/4 grow without bound (about linearly).
    Every rule must end, and say how: the relative change of a linearly growing coefficient between
    periods is ~1/n, far above eps = 0.01 % before the 2000-period cap, so the printed rules and the
    adaptive rule are capped (not converged); the fixed schemes stop by their own count."""
    max_periods = 2000
    for criterion in CRITERIA:
        data = {"plant": plant, "excitation": {"amplitude": AMPLITUDE, "frequencies_hz": [F_N]},
                "analysis": {"harmonics": [1], "criterion": criterion, "max_periods": max_periods,
                             "settle_periods": 50, "average_periods": 50}}
        (point,) = measure_frequency(parse_config(data).cases[0], F_N)
        assert point.converged == (point.status != "capped"), criterion
        assert (point.periods == max_periods) == (point.status == "capped"), criterion
        if criterion in FIXED_PERIODS:
            assert point.status == "fixed" and point.periods == FIXED_PERIODS[criterion], criterion
        else:
            assert criterion in PRINTED or criterion == "adaptive"
            assert point.status == "capped" and not point.converged, criterion


@pytest.mark.parametrize("fbar", [0.0, 0.1, 0.5])
def test_growth_at_resonance_follows_the_energy_balance(fbar: float) -> None:
    """At f = f_n with Fbar < pi/4 each period adds pi A Y of input work against 4 F Y of friction, so the
    first-harmonic amplitude grows by (pi - 4 Fbar) A / k per period, and the phase tends to -90 degrees."""
    kf, periods = 200, 1200
    h = 1.0 / (kf * F_N)
    plant = CoulombOscillator(MASS, STIFFNESS, fbar * AMPLITUDE)
    out = plant.run_sine(plant.initial_state(), 0.0, h, kf * periods, AMPLITUDE, F_N)
    t = h * np.arange(0, kf * periods + 1)
    p, q = PeriodIntegrator(F_N, (1,), 1).feed(t, np.concatenate([[0.0], out[:, 0]]))
    z = p[:, 0, 0] + 1j * q[:, 0, 0]
    growth = abs(z[-1]) - abs(z[-2])
    assert growth == pytest.approx((math.pi - 4.0 * fbar) * AMPLITUDE / STIFFNESS, rel=1e-6)
    assert math.degrees(math.atan2(z[-1].imag, z[-1].real)) == pytest.approx(-90.0, abs=0.05)
