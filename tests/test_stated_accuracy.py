"""A point that says converged holds its eps; noise, jitter and quantization on the simulated drive; intervals.

Expected values come from outside the rule: the linear oscillator's exact transfer function, the friction link's
long fixed runs, the noise statistics the simulated drive is configured with.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from test_bench_e2e import config

from bodebench.bench.connection import plan_link, simulator_spec
from bodebench.bench.offline import measure_frequency
from bodebench.bench.session import BenchSession
from bodebench.drivers.ports import Frame
from bodebench.io.config import ConfigError, parse_config
from bodebench.sim.controller import FeedbackSensing
from bodebench.sim.plants import LinearOscillator

PAPER = {"mass": 2.533e-4, "stiffness": 1.0, "amplitude": 0.01}


def offline_case(plant: dict[str, Any], amplitude: float, f: float, **analysis: Any):
    return parse_config({"plant": plant, "excitation": {"amplitude": amplitude, "frequencies_hz": [f]},
                         "analysis": {"skip_periods": 1, **analysis}}).cases[0]


def relative_error(point, truth: complex) -> float:
    return abs(complex(point.p, point.q) - truth) / abs(truth)


def test_friction_link_at_ten_times_resonance_waits_out_its_slow_drift() -> None:
    """Fbar 0.95 at 100 Hz drifts for ~850 periods by less than eps per period; a fixed run of 2000 + 200
    periods (checked against 4000 + 400) is the truth."""
    plant = {"model": "coulomb", "mass": PAPER["mass"], "stiffness": 1.0, "friction": 0.0095}
    truth_case = offline_case(plant, 0.01, 100.0, harmonics=[1, 3], criterion="fixed", settle_periods=2000,
                              average_periods=200)
    check_case = offline_case(plant, 0.01, 100.0, harmonics=[1, 3], criterion="fixed", settle_periods=4000,
                              average_periods=400)
    truth = {p.harmonic: complex(p.p, p.q) for p in measure_frequency(truth_case, 100.0)}
    check = {p.harmonic: complex(p.p, p.q) for p in measure_frequency(check_case, 100.0)}
    for k in (1, 3):
        assert abs(truth[k] - check[k]) <= 1e-3 * 1e-4 * abs(truth[k])  # the truth has settled far below eps
    points = measure_frequency(offline_case(plant, 0.01, 100.0, harmonics=[1, 3], tolerance_percent=0.01), 100.0)
    for p in points:
        assert p.status == "converged" and p.within_eps
        assert relative_error(p, truth[p.harmonic]) <= 1e-4
        assert abs(complex(p.p, p.q) - truth[p.harmonic]) <= p.uncertainty


@pytest.mark.parametrize("zeta,ratio,eps", [(0.003, 5.0, 0.01), (0.003, 4.0, 0.1), (0.001, 10.0, 0.01),
                                            (0.001, 0.995, 0.01), (0.01, 1.01, 0.1)])
def test_lightly_damped_oscillator_holds_eps_against_its_exact_response(zeta: float, ratio: float, eps: float) -> None:
    mass, stiffness, amplitude = 0.37, 5.3, 0.7
    fn = math.sqrt(stiffness / mass) / (2 * math.pi)
    f = ratio * fn
    exact = amplitude * complex(LinearOscillator(mass, stiffness, zeta).frequency_response(np.array([f]))[0, 0])
    case = offline_case({"model": "linear", "mass": mass, "stiffness": stiffness, "damping_ratio": zeta}, amplitude,
                        f, harmonics=[1, 2], tolerance_percent=eps)
    first, second = measure_frequency(case, f)
    assert first.status == "converged" and first.within_eps
    assert relative_error(first, exact) <= eps / 100
    assert abs(complex(first.p, first.q) - exact) <= first.uncertainty
    # the even harmonic of a linear plant is exactly zero: below resolution, no phase
    assert second.status == "below_resolution" and math.isnan(second.phase_deg)
    assert math.hypot(second.p, second.q) <= 2 * eps / 100 * 1e-3 * abs(exact)


def test_the_simulated_drive_adds_the_configured_noise_and_quantization() -> None:
    """The controller's feedback: a zero plant output reported with noise of the configured deviation, then
    rounded to the configured LSB; the same seed gives the same samples."""
    data = config(simulator={"noise": 2e-3, "quantization": 5e-4, "seed": 4})
    case = parse_config(data, "e2e.toml").cases[0]
    spec = simulator_spec(case)
    layout = case.on_bench.layout
    assert spec.sensing == FeedbackSensing(2e-3, 5e-4, 4)

    def samples(n: int) -> np.ndarray:
        controller = spec.controller()
        values = []
        for i in range(n):
            payload = layout.setpoint.encode({"setpoint": 0.0, "counter": i % 65536})
            for frame in controller.handle(Frame(layout.setpoint.id, payload, False, 0.0)):
                decoded = layout.feedback[0].decode(bytes(frame.data))
                values.append(decoded["position"])
        return np.array(values)

    y = samples(4000)
    lsb = 5e-4
    assert np.allclose(y / lsb, np.round(y / lsb), atol=1e-3)  # every value is a whole number of LSBs
    # quantized white noise: variance sigma^2 + lsb^2 / 12 (Sheppard), mean zero
    expected = math.sqrt(2e-3 ** 2 + lsb ** 2 / 12)
    assert np.std(y) == pytest.approx(expected, rel=0.06)
    assert abs(np.mean(y)) <= 4 * expected / math.sqrt(y.size)
    assert np.array_equal(y, samples(4000))


JITTER_ANALYSIS = {"harmonics": [1, 3], "tolerance_percent": 0.1, "max_periods": 400}
JITTER_BENCH = {"rate_hz": 2000, "clock": "lockstep", "timebase": "counter"}
LINEAR = {"model": "linear", "mass": 8.39e-5, "stiffness": 5.3, "damping_ratio": 0.05}  # f_n = 40 Hz


def jitter_config(jitter: float, **simulator: Any) -> dict[str, Any]:
    data = config(plant=LINEAR, analysis=JITTER_ANALYSIS, bench=JITTER_BENCH,
                  simulator={"jitter": jitter, "seed": 3, **simulator})
    data["excitation"] = {"amplitude": 0.01, "frequencies_hz": [40.0]}
    data["plant"] = dict(LINEAR)
    return data


def run_session(data: dict[str, Any], direct: bool):
    case = parse_config(data, "jitter.toml").cases[0]
    session = BenchSession(case, plan_link(case, direct=direct))
    session.run()
    return session.response


def jitter_loss(jitter: float, frequency_hz: float, rate_hz: float) -> float:
    """Relative loss of the fundamental to uniform jitter of +-a, a = jitter / rate: 1 - sin(w a)/(w a) where the
    sample is taken, and as much again on the setpoint held over a jittered step; at most (w a)^2 / 3."""
    wa = 2 * math.pi * frequency_hz * jitter / rate_hz
    return wa * wa / 3


@pytest.mark.slow
def test_sampling_jitter_costs_periods_not_the_sweep() -> None:
    """Jitter of 0.3 sample periods on a counter time base is noise on every sample (and, through the held
    setpoints, on the plant's input). Over seeds, the fundamental converges and its 95 % interval holds the
    jitter-free value (less the small attenuation jitter itself causes) about as often as it says; the third
    harmonic, exactly zero for this plant, ends below resolution or noise-limited early, its interval holding
    zero, instead of running for ever."""
    clean = {p.harmonic: p for p in run_session(jitter_config(0.0), direct=True).points}
    z_clean = complex(clean[1].p, clean[1].q)
    allowance = jitter_loss(0.3, 40.0, 2000.0) * abs(z_clean)
    held = zero_held = 0
    seeds = range(10)
    for seed in seeds:
        data = jitter_config(0.3)
        data["simulator"]["seed"] = seed
        points = {p.harmonic: p for p in run_session(data, direct=True).points}
        first, third = points[1], points[3]
        assert first.status == "converged" and first.periods < 400
        error = abs(complex(first.p, first.q) - z_clean)
        held += error <= first.uncertainty + allowance
        assert error <= 2 * first.uncertainty + allowance
        assert third.status in ("below_resolution", "noise_limited") and third.periods < 400
        zero_held += math.hypot(third.p, third.q) <= third.uncertainty
        if third.status == "noise_limited":
            assert third.periods_needed > 400
            # a disc that holds zero leaves the phase undefined
            assert math.isnan(third.phase_deg) == (third.uncertainty >= math.hypot(third.p, third.q))
    assert held >= 8 and zero_held >= 8


def test_sampling_jitter_on_the_virtual_bus_finishes_and_agrees() -> None:
    clean = run_session(jitter_config(0.0), direct=True).select(harmonic=1).points[0]
    z_clean = complex(clean.p, clean.q)
    points = {p.harmonic: p for p in run_session(jitter_config(0.3), direct=False).points}
    first = points[1]
    assert first.status == "converged"
    allowed = 2 * first.uncertainty + jitter_loss(0.3, 40.0, 2000.0) * abs(z_clean)
    assert abs(complex(first.p, first.q) - z_clean) <= allowed
    assert points[3].status in ("below_resolution", "noise_limited") and points[3].periods < 400


def test_simulate_on_a_bench_config_applies_the_drives_noise_and_refuses_wire_faults() -> None:
    clean = run_session(jitter_config(0.0), direct=True).select(harmonic=1).points[0]
    noisy = run_session(jitter_config(0.0, noise=2e-5, quantization=1e-6), direct=True).select(harmonic=1).points[0]
    assert (noisy.p, noisy.q) != (clean.p, clean.q)  # the noise reached the measurement
    assert noisy.status == "converged"
    assert abs(complex(noisy.p, noisy.q) - complex(clean.p, clean.q)) <= noisy.uncertainty
    data = jitter_config(0.0)
    data["simulator"]["faults"] = {"drop": 0.01}
    case = parse_config(data, "jitter.toml").cases[0]
    with pytest.raises(ConfigError, match="simulator.faults"):
        plan_link(case, direct=True)


def test_seeds_make_noisy_runs_reproducible() -> None:
    a = run_session(jitter_config(0.2, noise=2e-5), direct=True).points
    b = run_session(jitter_config(0.2, noise=2e-5), direct=True).points
    assert [(p.status, p.periods) for p in a] == [(p.status, p.periods) for p in b]
    for pa, pb in zip(a, b, strict=False):  # the same samples: the same coefficients, to the round-off of their sums
        assert complex(pa.p, pa.q) == pytest.approx(complex(pb.p, pb.q), rel=1e-12, abs=1e-18)
