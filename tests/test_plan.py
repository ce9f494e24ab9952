"""The frequency plan: a list or a log-spaced range of frequencies, the amplitude as a constant, a list or a
profile, settle periods per frequency; validated in one line naming the key."""

from __future__ import annotations

import math
import uuid
from pathlib import Path

import numpy as np
import pytest

from bodebench.bench.offline import sweep
from bodebench.io.config import ConfigError, load_config, parse_config

PLANT = {"model": "linear", "mass": 1.0, "stiffness": 40.0, "damping_ratio": 0.3}
ANALYSIS = {"tolerance_percent": 0.1, "steps_per_period": 64}


def case(excitation: dict, analysis: dict | None = None):  # noqa: ANN201 - a CaseConfig
    return parse_config({"plant": PLANT, "excitation": excitation, "analysis": analysis or ANALYSIS},
                        "plan.toml").cases[0]


def exact_gain(f: float) -> float:
    w = 2 * math.pi * f
    return 1 / abs(40.0 - w * w + 2j * 0.3 * math.sqrt(40.0) * w)


@pytest.mark.parametrize(("start", "stop", "per_decade"), [(1.0, 100.0, 10), (2.0, 50.0, 3), (0.1, 0.35, 20)])
def test_a_log_spaced_range(start: float, stop: float, per_decade: int) -> None:
    plan = case({"amplitude": 1.0, "frequencies": {"start_hz": start, "stop_hz": stop, "per_decade": per_decade}})
    f = np.array(plan.excitation.frequencies_hz)
    assert f[0] == start and f[-1] <= stop * (1 + 1e-6) and f[-1] * 10 ** (1 / per_decade) > stop
    assert np.diff(np.log10(f)) == pytest.approx(np.full(f.size - 1, 1 / per_decade), abs=1e-5)
    assert len(f) == math.floor(math.log10(stop / start) * per_decade + 1e-9) + 1
    assert plan.raw["excitation"]["frequencies_hz"] == list(f)  # saved with the results as measured


def test_amplitude_per_frequency_and_profile_reach_the_points() -> None:
    freqs = [0.3, 1.0, 3.0]
    listed = sweep(case({"frequencies_hz": freqs, "amplitudes": [0.5, 2.0, 4.0]}))
    by_f = {p.frequency_hz: p for p in listed}
    assert [by_f[f].amplitude for f in freqs] == [0.5, 2.0, 4.0]
    for f in freqs:  # linear: the gain does not depend on the amplitude
        assert by_f[f].gain == pytest.approx(exact_gain(f), rel=2e-3)
        assert by_f[f].magnitude == pytest.approx(exact_gain(f) * by_f[f].amplitude, rel=2e-3)
    profile = {"frequencies_hz": [0.5, 2.0], "amplitudes": [1.0, 8.0]}
    shaped = sweep(case({"frequencies_hz": freqs, "amplitude_profile": profile}))
    expected = np.exp(np.interp(np.log(freqs), np.log([0.5, 2.0]), np.log([1.0, 8.0])))  # clamped at the ends
    assert [p.amplitude for p in sorted(shaped, key=lambda p: p.frequency_hz)] == pytest.approx(expected)


def test_settle_periods_pass_before_the_first_integrated_period() -> None:
    """The paper's "first period" scheme reads one period: right after the start the transient is in it; after
    settle periods of a plant with zeta = 0.3 (decay exp(-2 pi zeta f_n / f) a period) it is gone. The settle
    periods are not counted in the point's periods."""
    first = {**ANALYSIS, "criterion": "first_period", "skip_periods": 0}
    freqs = [0.5, 2.0]
    cold = sweep(case({"amplitude": 1.0, "frequencies_hz": freqs}, first))
    warm = sweep(case({"amplitude": 1.0, "frequencies_hz": freqs, "settle_periods_per_frequency": [30, 120]},
                      first))
    for p in cold:
        assert abs(p.gain / exact_gain(p.frequency_hz) - 1) > 5e-3  # the transient spoils one period
    for p in warm:
        assert p.gain == pytest.approx(exact_gain(p.frequency_hz), rel=1e-3)
        assert p.periods == next(c.periods for c in cold if c.frequency_hz == p.frequency_hz)
    same = sweep(case({"amplitude": 1.0, "frequencies_hz": freqs, "settle_periods": 120}, first))
    assert all(p.gain == pytest.approx(exact_gain(p.frequency_hz), rel=1e-3) for p in same)


@pytest.mark.parametrize(("excitation", "message"), [
    ({"amplitude": 1.0}, "plan.toml: excitation.frequencies_hz: missing (give frequencies_hz = [...] or "
                         "frequencies = {start_hz, stop_hz, per_decade})"),
    ({"amplitude": 1.0, "frequencies_hz": [1.0], "frequencies": {"start_hz": 1, "stop_hz": 10, "per_decade": 2}},
     "plan.toml: excitation.frequencies: give either this or excitation.frequencies_hz, not both"),
    ({"amplitude": 1.0, "frequencies": {"start_hz": 10, "stop_hz": 1, "per_decade": 2}},
     "plan.toml: excitation.frequencies.stop_hz: must be > excitation.frequencies.start_hz (10 Hz), got 1"),
    ({"amplitude": 1.0, "frequencies": {"start_hz": 1, "stop_hz": 10}},
     "plan.toml: excitation.frequencies.per_decade: missing"),
    ({"amplitude": 1.0, "frequencies": {"start_hz": 1.0, "stop_hz": 10.0, "per_decade": 1001}},
     "plan.toml: excitation.frequencies.per_decade: must be <= 1000, got 1001"),
    ({"frequencies_hz": [1.0, 2.0], "amplitudes": [1.0]},
     "plan.toml: excitation.amplitudes: 1 values for 2 frequencies"),
    ({"frequencies_hz": [1.0, 2.0], "amplitudes": [1.0, -2.0]},
     "plan.toml: excitation.amplitudes[1]: must be > 0, got -2.0"),
    ({"frequencies_hz": [1.0], "amplitude_profile": {"frequencies_hz": [2.0, 1.0],
                                                                      "amplitudes": [1.0, 1.0]}},
     "plan.toml: excitation.amplitude_profile.frequencies_hz: knots must ascend: [1] = 1 Hz after 2 Hz"),
    ({"frequencies_hz": [1.0], "amplitudes": [1.0],
      "amplitude_profile": {"frequencies_hz": [1.0], "amplitudes": [1.0]}},
     "plan.toml: excitation.amplitude_profile: give either this or excitation.amplitudes, not both"),
    ({"amplitude": 1.0, "frequencies_hz": [1.0], "settle_periods": 2, "settle_periods_per_frequency": [1]},
     "plan.toml: excitation.settle_periods_per_frequency: give either this or excitation.settle_periods, not "
     "both"),
    ({"amplitude": 1.0, "frequencies_hz": [1.0, 2.0], "amplitudes": [1.0, 2.0]},
     "plan.toml: excitation.amplitudes: give either this or excitation.amplitude, not both"),
    ({"frequencies_hz": [1.0, 2.0]},
     "plan.toml: excitation.amplitude: missing (give amplitude, amplitudes = [...] (one per frequency) or "
     "amplitude_profile = {frequencies_hz, amplitudes})"),
    ({"amplitude": 1.0, "frequencies_hz": [1.0], "settle_periods": -1},
     "plan.toml: excitation.settle_periods: must be >= 0, got -1"),
    ({"amplitude": 1.0, "frequencies": {"start_hz": 1.0, "stop_hz": 100.0, "per_decade": 10,
                                        "adaptive": {"max_points": 12}}},
     "plan.toml: excitation.frequencies.adaptive: max_points = 12 is fewer than the range's 21 frequencies"),
    ({"amplitude": 1.0, "frequencies": {"start_hz": 1.0, "stop_hz": 10.0, "per_decade": 2,
                                        "adaptive": {"figures": ["bandwidth", "peak"]}}},
     "plan.toml: excitation.frequencies.adaptive.figures[1]: must be one of \"bandwidth\", \"resonance\", "
     "\"phase_90\", \"phase_180\", \"phase_margin\", \"gain_margin\", got \"peak\""),
    ({"amplitudes": [1.0, 1.0], "frequencies": {"start_hz": 1.0, "stop_hz": 10.0, "per_decade": 1,
                                                "adaptive": {}}},
     "plan.toml: excitation.amplitudes: one value per frequency cannot follow an adaptive plan, whose frequencies "
     "are not known before the sweep (give amplitude or amplitude_profile, and settle_periods)"),
    ({"amplitude": 1.0, "frequencies": {"start_hz": 1.0, "stop_hz": 10.0, "per_decade": 1,
                                        "adaptive": {"frequency_percent": 0}}},
     "plan.toml: excitation.frequencies.adaptive.frequency_percent: must be > 0, got 0.0"),
    ({"amplitude": 1.0, "frequencies": {"start_hz": 1.0, "stop_hz": 10.0, "per_decade": 1,
                                        "adaptive": {"figures": [], "curve": False}}},
     "plan.toml: excitation.frequencies.adaptive: asks for no figure and no curve (figures = [], curve = false): "
     "nothing would add a frequency"),
])
def test_plan_errors_are_one_line_naming_the_key(excitation: dict, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        case(excitation)
    assert str(info.value) == message


def test_too_many_frequencies_in_a_range() -> None:
    with pytest.raises(ConfigError) as info:
        case({"amplitude": 1.0, "frequencies": {"start_hz": 1e-3, "stop_hz": 1e9, "per_decade": 1000}})
    assert str(info.value) == "plan.toml: excitation.frequencies.per_decade: 12001 frequencies, more than 10000"


BENCH = """
[plant]
model = "lag"
time_constant = 0.01
[excitation]
{plan}
[analysis]
tolerance_percent = 0.5
[bench]
transport = "can"
rate_hz = 1000
worker = "thread"
[can]
interface = "virtual"
channel = "{channel}"
[safety]
max_amplitude = 0.02
[simulator]
"""


def test_an_adaptive_plan_checks_the_amplitude_profile_between_its_frequencies(tmp_path: Path) -> None:
    """A profile's knot between two of the range's frequencies is where an added frequency's amplitude can be
    largest: the loader refuses a knot above safety.max_amplitude though every frequency of the range is below."""
    config = tmp_path / "bench.toml"
    plan = ("frequencies = { start_hz = 2, stop_hz = 20, per_decade = 1, adaptive = {} }\n"
            "amplitude_profile = { frequencies_hz = [2, 6, 20], amplitudes = [0.01, 0.03, 0.01] }")
    config.write_text(BENCH.format(plan=plan, channel="unused"))
    with pytest.raises(ConfigError) as info:
        load_config(config)
    assert str(info.value) == (f"{config}: excitation.amplitude_profile: 0.03 at 6 Hz exceeds safety.max_amplitude "
                               "(0.02)")


def test_the_bench_checks_every_planned_amplitude_and_sweeps_with_it(tmp_path: Path) -> None:
    config = tmp_path / "bench.toml"
    channel = f"plan-{uuid.uuid4().hex[:8]}"
    config.write_text(BENCH.format(plan="frequencies_hz = [5.0, 20.0]\namplitudes = [0.01, 0.03]",
                                   channel=channel))
    with pytest.raises(ConfigError) as info:
        load_config(config)
    assert str(info.value) == (f"{config}: excitation.amplitudes[1]: 0.03 at 20 Hz exceeds safety.max_amplitude "
                               "(0.02)")
    config.write_text(BENCH.format(plan="frequencies = {start_hz = 200, stop_hz = 400, per_decade = 10}\n"
                                        "amplitude = 0.01", channel=channel))
    with pytest.raises(ConfigError) as info:
        load_config(config)
    assert str(info.value).startswith(f"{config}: excitation.frequencies (frequency 0): 200 Hz: harmonic 1 needs")
    # the simulated drive in-process, through the bench session: each frequency at its own amplitude
    from bodebench.apps.cli import main

    config.write_text(BENCH.format(plan="frequencies_hz = [5.0, 20.0]\namplitudes = [0.004, 0.016]\n"
                                        "settle_periods = 3", channel=channel))
    assert main(["simulate", str(config), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    from bodebench.io.results import load_response

    points = {p.frequency_hz: p for p in load_response(tmp_path / "out")}
    assert points[5.0].amplitude == 0.004 and points[20.0].amplitude == 0.016
    for f, p in points.items():
        assert p.gain == pytest.approx(1 / abs(1 + 2j * math.pi * f * 0.01), rel=5e-3)
