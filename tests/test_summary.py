"""The summary figures of a response against closed-form answers and independent root solves.

Responses are sampled from exact transfer functions at 10 points per decade (a typical sweep density), on grids
shifted by fractions of a step so that the figures fall anywhere between two points. Stated accuracy at that
density, checked here: bandwidth within 1.5 %, the -90 deg crossing within 4 % (zeta >= 0.05), margins within
0.1 dB and 0.2 deg; each figure within its own stated interpolation estimate.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar

from bodebench.apps.cli import main
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.core.summary import ResponseSummary, summarize, summarize_response
from bodebench.io.config import ConfigError, parse_config

FN = 3.7  # natural frequency, Hz (off any decade grid)
OFFSETS = np.linspace(0.0, 1.0, 7, endpoint=False)

Transfer = Callable[[np.ndarray], np.ndarray]


def second_order(zeta: float, fn: float = FN) -> Transfer:
    wn = 2 * math.pi * fn

    def g(f: np.ndarray) -> np.ndarray:
        s = 2j * math.pi * np.asarray(f, dtype=float)
        return wn**2 / (s * s + 2 * zeta * wn * s + wn**2)

    return g


def grid(start: float, stop: float, offset: float, per_decade: int = 10) -> np.ndarray:
    return 10.0 ** np.arange(math.log10(start) + offset / per_decade, math.log10(stop), 1.0 / per_decade)


def exact_summary(g: Transfer, f: np.ndarray, kind: str = "system") -> ResponseSummary:
    values = g(f)
    gain_db = 20 * np.log10(np.abs(values))
    return summarize(f, gain_db, gain_db, gain_db, np.degrees(np.angle(values)), np.zeros(f.size), kind=kind)


def points(g: Transfer, f: np.ndarray, relative_uncertainty: float, channel: str = "position",
           amplitude: float = 0.5) -> list[ResponsePoint]:
    out = []
    for freq, value in zip(f, g(f), strict=True):
        c = value * amplitude
        out.append(ResponsePoint(float(freq), 1, channel, amplitude, c.real, c.imag, 100, True, "converged",
                                 uncertainty=relative_uncertainty * abs(c) * 1.2,
                                 uncertainty_1d=relative_uncertainty * abs(c)))
    return out


@pytest.mark.parametrize("zeta", [0.05, 0.1, 0.2, 0.3, 0.5, 1 / math.sqrt(2), 1.0, 2.0])
def test_bandwidth_of_a_second_order_low_pass(zeta: float) -> None:
    """f_b = f_n sqrt(1 - 2 zeta^2 + sqrt(4 zeta^4 - 4 zeta^2 + 2)), the half-power point, from a sweep starting
    three decades below f_n (where the reference gain is the static gain to 1e-5 dB)."""
    truth = FN * math.sqrt(1 - 2 * zeta**2 + math.sqrt(4 * zeta**4 - 4 * zeta**2 + 2))
    for offset in OFFSETS:
        bw = exact_summary(second_order(zeta), grid(FN * 1e-3, FN * 100, offset)).figure("bandwidth (-3 dB)")
        assert bw.found
        assert abs(bw.value - truth) <= bw.interpolation + 1e-9 * truth
        assert abs(bw.value - truth) <= 0.015 * truth
        assert bw.low == pytest.approx(bw.value, rel=1e-12) and bw.high == pytest.approx(bw.value, rel=1e-12)


@pytest.mark.parametrize("zeta", [0.1, 0.5, 1.0])
def test_bandwidth_is_relative_to_the_lowest_measured_gain(zeta: float) -> None:
    """A sweep starting at f_n / 3 (gain already off its static value): the crossing of |G(f_min)| / sqrt(2),
    found by a root solve on the exact curve."""
    g = second_order(zeta)
    for offset in OFFSETS:
        f = grid(FN / 3, FN * 100, offset)
        summary = exact_summary(g, f)
        g0 = abs(g(f[:1])[0])
        assert summary.reference_db == pytest.approx(20 * math.log10(g0), abs=1e-12)
        assert summary.reference_hz == f[0]
        start = f[0] if zeta > 0.5 else FN
        truth = brentq(lambda x, g0=g0: abs(g(np.array([x]))[0]) - g0 / math.sqrt(2), start, FN * 100)
        bw = summary.figure("bandwidth (-3 dB)")
        assert abs(bw.value - truth) <= bw.interpolation + 1e-9 * truth


@pytest.mark.parametrize("zeta", [0.05, 0.1, 0.2, 0.3, 0.5, 0.6])
def test_resonance_peak_of_a_second_order_system(zeta: float) -> None:
    """M_r = 1 / (2 zeta sqrt(1 - zeta^2)) at f_n sqrt(1 - 2 zeta^2): the local pole-pair form is exact for it,
    even where 10 points per decade straddle a peak narrower than their spacing."""
    m_r = 20 * math.log10(1 / (2 * zeta * math.sqrt(1 - zeta**2)))
    f_r = FN * math.sqrt(1 - 2 * zeta**2)
    for offset in OFFSETS:
        summary = exact_summary(second_order(zeta), grid(FN * 1e-3, FN * 100, offset))
        peak = summary.figure("resonance peak")
        assert peak.found
        assert peak.value + summary.reference_db == pytest.approx(m_r, abs=1e-6)
        assert peak.at_hz == pytest.approx(f_r, rel=1e-6)
        assert peak.at_low_hz <= f_r <= peak.at_high_hz
        assert peak.low - 1e-6 <= peak.value <= peak.high + 1e-6


@pytest.mark.parametrize("zeta", [0.1, 0.3])
def test_resonance_peak_of_a_pole_pair_with_a_lag(zeta: float) -> None:
    """A pole pair behind a first-order lag at 3 f_n: the local form is no longer exact; the truth (a bounded
    maximisation of the exact gain) lies within the stated interpolation estimate, at 20 points per decade."""
    pair = second_order(zeta)

    def g(f: np.ndarray) -> np.ndarray:
        return pair(f) / (1 + 1j * np.asarray(f) / (3 * FN))

    best = minimize_scalar(lambda x: -abs(g(np.array([x]))[0]), bounds=(0.5 * FN, 1.2 * FN), method="bounded",
                           options={"xatol": 1e-10})
    truth = 20 * math.log10(abs(g(np.array([best.x]))[0]))
    for offset in OFFSETS:
        f = grid(FN * 1e-3, FN * 100, offset, per_decade=20)
        summary = exact_summary(g, f)
        peak = summary.figure("resonance peak")
        assert abs(peak.value + summary.reference_db - truth) <= peak.interpolation + 1e-9
        assert peak.at_low_hz <= best.x <= peak.at_high_hz


@pytest.mark.parametrize("zeta", [0.05, 0.1, 0.3, 0.7, 1.0, 2.0])
def test_phase_crosses_minus_90_at_the_natural_frequency(zeta: float) -> None:
    for offset in OFFSETS:
        summary = exact_summary(second_order(zeta), grid(FN * 1e-2, FN * 100, offset))
        crossing = summary.figure("phase -90 deg")
        assert abs(crossing.value - FN) <= crossing.interpolation + 1e-9 * FN
        assert abs(crossing.value - FN) <= 0.04 * FN
        minus_180 = summary.figure("phase -180 deg")  # the asymptote, never reached
        assert not minus_180.found and "not found in the measured range" in minus_180.note


def test_figures_outside_the_measured_range_are_not_found() -> None:
    """A sweep that stops below the bandwidth, and one that stops on the rising side of the resonance."""
    short = exact_summary(second_order(0.7), grid(0.1, FN * 0.5, 0.0))
    bw = short.figure("bandwidth (-3 dB)")
    assert not bw.found and math.isnan(bw.value) and "not found in the measured range" in bw.note
    assert not short.figure("phase -90 deg").found
    rising = exact_summary(second_order(0.1), grid(0.1, FN * 0.9, 0.0)).figure("resonance peak")
    assert not rising.found and "not found in the measured range" in rising.note
    overdamped = exact_summary(second_order(1.0), grid(0.1, FN * 100, 0.0)).figure("resonance peak")
    assert not overdamped.found and overdamped.note.startswith("none")


@pytest.mark.parametrize(("k", "a"), [(1.0, 1.0), (30.0, 2.0), (400.0, 10.0)])
def test_margins_of_an_integrator_with_a_lag(k: float, a: float) -> None:
    """L = K / (s (s + a)): w_c^2 = (sqrt(a^4 + 4 K^2) - a^2) / 2, PM = 90 - atan(w_c / a); the phase never
    reaches -180 deg, so the gain margin is not found in the measured range (it is infinite)."""
    def loop(f: np.ndarray) -> np.ndarray:
        s = 2j * math.pi * np.asarray(f, dtype=float)
        return k / (s * (s + a))

    wc = math.sqrt((math.sqrt(a**4 + 4 * k**2) - a**2) / 2)
    pm_truth = 90 - math.degrees(math.atan(wc / a))
    for offset in OFFSETS:
        summary = exact_summary(loop, grid(1e-3, 1e3, offset), kind="open_loop")
        pm = summary.figure("phase margin")
        assert abs(pm.value - pm_truth) <= max(pm.interpolation, 1e-9)
        assert abs(pm.value - pm_truth) <= 0.2
        assert abs(pm.at_hz - wc / (2 * math.pi)) <= 0.01 * wc / (2 * math.pi)
        gm = summary.figure("gain margin")
        assert not gm.found and "not found in the measured range" in gm.note
        assert {f.name for f in summary.figures} == {"phase -90 deg", "phase -180 deg", "phase margin", "gain margin"}


@pytest.mark.parametrize(("k", "t1", "t2"), [(2.0, 0.05, 0.02), (10.0, 0.5, 0.1), (1.0, 1.0, 1.0)])
def test_margins_of_an_integrator_with_two_lags(k: float, t1: float, t2: float) -> None:
    """L = K / (s (1 + s T1)(1 + s T2)): the phase is -180 deg at w = 1 / sqrt(T1 T2), where the gain margin is
    (T1 + T2) / (K T1 T2); the gain crossover from a root solve of |L| = 1."""
    def loop(f: np.ndarray) -> np.ndarray:
        s = 2j * math.pi * np.asarray(f, dtype=float)
        return k / (s * (1 + s * t1) * (1 + s * t2))

    f180 = 1 / (2 * math.pi * math.sqrt(t1 * t2))
    gm_truth = 20 * math.log10((t1 + t2) / (k * t1 * t2))
    fc = brentq(lambda x: abs(loop(np.array([x]))[0]) - 1, 1e-4, 1e4)
    pm_truth = 90 - math.degrees(math.atan(2 * math.pi * fc * t1) + math.atan(2 * math.pi * fc * t2))
    for offset in OFFSETS:
        summary = exact_summary(loop, grid(1e-3, 1e3, offset), kind="open_loop")
        gm = summary.figure("gain margin")
        assert abs(gm.value - gm_truth) <= gm.interpolation + 1e-9 and abs(gm.value - gm_truth) <= 0.1
        assert abs(gm.at_hz - f180) <= 0.01 * f180
        pm = summary.figure("phase margin")
        assert abs(pm.value - pm_truth) <= pm.interpolation + 1e-9 and abs(pm.value - pm_truth) <= 0.2
        assert abs(pm.at_hz - fc) <= 0.01 * fc
        assert summary.figure("phase -180 deg").value == pytest.approx(gm.at_hz, rel=1e-12)


def test_point_intervals_propagate_into_the_figures() -> None:
    """Every point's gain known to +-2 % (95 %): the bandwidth's interval ends are the crossings of the bound
    curves |G| (1 -+ r) with |G(f_min)| (1 +- r) / sqrt(2), the -90 deg crossing's those of the phase
    -+ asin(r); each from a root solve on the exact curve, to within the interpolation at 40 points per
    decade. The margins' intervals hold the exact margins."""
    r = 0.02
    g = second_order(0.4)
    f = grid(FN * 1e-2, FN * 30, 0.37, per_decade=40)
    (summary,) = summarize_response(FrequencyResponse(points(g, f, r)))
    g0 = abs(g(f[:1])[0])

    def solve(target: Callable[[float], float]) -> float:
        return brentq(target, FN, FN * 30)

    bw = summary.figure("bandwidth (-3 dB)")
    low = solve(lambda x: abs(g(np.array([x]))[0]) * (1 - r) - g0 * (1 + r) / math.sqrt(2))
    high = solve(lambda x: abs(g(np.array([x]))[0]) * (1 + r) - g0 * (1 - r) / math.sqrt(2))
    assert low < bw.value < high
    assert bw.low == pytest.approx(low, abs=bw.interpolation) and bw.high == pytest.approx(high, abs=bw.interpolation)
    shift = math.degrees(math.asin(r))

    def phase(x: float) -> float:
        return math.degrees(np.angle(g(np.array([x]))[0]))

    p90 = summary.figure("phase -90 deg")
    assert p90.low == pytest.approx(brentq(lambda x: phase(x) - shift + 90, FN / 3, FN * 3), abs=p90.interpolation)
    assert p90.high == pytest.approx(brentq(lambda x: phase(x) + shift + 90, FN / 3, FN * 3), abs=p90.interpolation)
    assert p90.low < FN < p90.high

    def loop(freq: np.ndarray) -> np.ndarray:
        s = 2j * math.pi * np.asarray(freq, dtype=float)
        return 10.0 / (s * (1 + s * 0.5) * (1 + s * 0.1))

    (open_loop,) = summarize_response(FrequencyResponse(points(loop, grid(1e-2, 1e2, 0.1, 40), r)), "open_loop")
    gm, pm = open_loop.figure("gain margin"), open_loop.figure("phase margin")
    assert gm.low < 20 * math.log10(0.6 / 0.5) < gm.high and gm.at_low_hz < gm.at_hz < gm.at_high_hz
    assert pm.low < pm.value < pm.high and pm.at_low_hz < pm.at_hz < pm.at_high_hz
    # +-2 % in gain is +-0.17 dB; the gain margin's interval is at least that wide on each side.
    assert gm.high - gm.value >= 20 * math.log10(1 + r) - 1e-9 and gm.value - gm.low >= -20 * math.log10(1 - r) - 1e-9


def test_summary_per_channel_leaves_out_points_without_a_phase() -> None:
    """Two channels summarised apart; a point below the resolution (no phase) and the second harmonic are not
    used; a channel with fewer than two usable points gets no summary."""
    f = grid(FN * 1e-2, FN * 100, 0.0)
    pts = points(second_order(0.3), f, 1e-4) + points(second_order(0.3, fn=2 * FN), f, 1e-4, channel="velocity")
    pts.append(ResponsePoint(1.0, 2, "position", 0.5, 1e-9, 0.0, 100, True, "below_resolution",
                             uncertainty=1e-6))
    pts.append(ResponsePoint(1.0, 1, "current", 0.5, 0.0, 0.0, 100, True, "below_resolution", uncertainty=1e-6))
    summaries = summarize_response(FrequencyResponse(pts))
    assert [s.channel for s in summaries] == ["position", "velocity"]
    assert summaries[1].figure("phase -90 deg").value == pytest.approx(2 * FN, rel=0.04)
    json.dumps([s.to_json() for s in summaries], allow_nan=False)  # JSON types only, no NaN


def test_summarize_refuses_bad_input() -> None:
    with pytest.raises(ValueError, match="at least two points"):
        summarize([1.0], [0.0], [0.0], [0.0], [0.0], [0.0])
    with pytest.raises(ValueError, match="kind must be one of"):
        summarize([1.0, 2.0], [0, 0], [0, 0], [0, 0], [0, 0], [0, 0], kind="loop")
    with pytest.raises(ValueError, match="distinct"):
        summarize([1.0, 1.0], [0, 0], [0, 0], [0, 0], [0, 0], [0, 0])


def test_a_response_starting_near_zero_phase_is_not_read_as_minus_360() -> None:
    """A folded phase of -359.99 deg at the lowest frequency (a lead of 0.01 deg) starts the curve at +0.01 deg."""
    f = np.array([1.0, 2.0, 4.0, 8.0])
    summary = summarize(f, np.zeros(4), np.zeros(4), np.zeros(4), [-359.99, -45.0, -100.0, -170.0], np.zeros(4))
    crossing = summary.figure("phase -90 deg")
    assert 2.0 < crossing.value < 4.0


BASE = {"plant": {"model": "lag"}, "excitation": {"amplitude": 1.0, "frequencies_hz": [1.0, 2.0]}}


def test_analysis_response_is_validated() -> None:
    config = parse_config({**BASE, "analysis": {"response": "open_loop"}}, "x.toml")
    assert config.cases[0].analysis.response_kind == "open_loop"
    plain = parse_config(BASE, "x.toml").cases[0]
    assert plain.analysis.response_kind == "system" and "response" not in plain.raw["analysis"]
    with pytest.raises(ConfigError) as info:
        parse_config({**BASE, "analysis": {"response": "loop"}}, "x.toml")
    assert str(info.value).startswith('x.toml: analysis.response: must be one of "system", "closed_loop", ')
    assert "\n" not in str(info.value)


def test_simulate_writes_and_prints_the_summary(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An offline sweep of a first-order lag (T = 0.1 s): the summary is in response.json and printed; the
    -3 dB bandwidth is near 1 / (2 pi T) relative to the gain at 0.1 Hz, from a root solve."""
    config = tmp_path / "lag.toml"
    freqs = [round(float(x), 6) for x in grid(0.1, 20.0, 0.0)]
    config.write_text('[plant]\nmodel = "lag"\ntime_constant = 0.1\n[excitation]\namplitude = 1.0\n'
                      f"frequencies_hz = {freqs}\n[analysis]\ntolerance_percent = 0.1\nsteps_per_period = 64\n")
    out = tmp_path / "out"
    assert main(["simulate", str(config), "--out", str(out), "--jobs", "1", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "bandwidth (-3 dB): " in printed and "phase -90 deg: not found in the measured range" in printed
    sidecar = json.loads((out / "response.json").read_text())
    (summary,) = sidecar["summary"]
    assert summary["response"] == "system" and summary["confidence"] == 0.95
    bw = next(f for f in summary["figures"] if f["name"] == "bandwidth (-3 dB)")

    def lag(f: float) -> float:
        return 1 / abs(1 + 2j * math.pi * f * 0.1)

    truth = brentq(lambda f: lag(f) - lag(freqs[0]) / math.sqrt(2), 0.1, 20.0)
    assert abs(bw["value"] - truth) <= bw["interpolation"] + 1e-3 * truth
    assert bw["low"] <= bw["value"] <= bw["high"]


# ------------------------------------------------------------------------------------------- an honest readout


def _second_order(f: np.ndarray, fn: float = 10.0, zeta: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Gain (dB) and phase (deg) of 1 / (1 - u^2 + 2 j zeta u), u = f / fn: a resonance near fn."""
    u = f / fn
    g = 1.0 / (1.0 - u * u + 2j * zeta * u)
    return 20.0 * np.log10(np.abs(g)), np.degrees(np.angle(g))


def test_a_figure_read_from_a_point_that_did_not_converge_says_so() -> None:
    f = np.array([1.0, 5.0, 9.0, 10.0, 11.0, 20.0, 40.0])
    gain, phase = _second_order(f)
    zero = np.zeros_like(f)
    settled = summarize(f, gain, gain, gain, phase, zero)
    assert not any("did not converge" in fig.note for fig in settled.figures)
    capped = summarize(f, gain, gain, gain, phase, zero, converged=[True, True, True, False, True, True, True])
    peak = capped.figure("resonance peak")
    assert peak.note.startswith("read from points that did not converge (10 Hz)"), peak.note
    assert "did not converge (10 Hz)" in capped.figure("phase -90 deg").note  # the crossing sits on 10 Hz
    assert "did not converge" not in capped.figure("phase -180 deg").note  # not found: nothing read


def test_the_peak_says_what_it_is_relative_to() -> None:
    f = np.array([2.0, 5.0, 9.0, 10.0, 11.0, 20.0])
    gain, phase = _second_order(f)
    gain = gain + 6.0  # a static gain of 2: the peak is still read above the gain at the lowest frequency
    peak = summarize(f, gain, gain, gain, phase, np.zeros_like(f)).figure("resonance peak")
    assert "above the gain at 2 Hz" in peak.text()
    largest = float(np.max(gain) - gain[0])
    assert peak.value >= largest - 1e-12 and f"largest measured: {largest:.4g} dB" in peak.text()


def test_an_interpolation_error_larger_than_the_figure_is_not_printed_as_a_plus_minus() -> None:
    from bodebench.core.summary import Figure

    wide = Figure("bandwidth (-3 dB)", "Hz", value=16.05, low=16.05, high=16.05, interpolation=160.0)
    assert "+-" not in wide.text() and "measure more frequencies near it" in wide.text()
    narrow = Figure("bandwidth (-3 dB)", "Hz", value=16.05, low=16.0, high=16.1, interpolation=0.2)
    assert "interpolation +-0.2" in narrow.text()
