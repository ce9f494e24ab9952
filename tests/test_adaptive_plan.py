"""The adaptive plan: where it adds frequencies, and that the figures it ends with are within the accuracy it was
asked for, against figures solved apart from the summary (root finding and bounded minimisation on the exact
response), on plants whose resonances lie anywhere between the coarse grid's points."""

from __future__ import annotations

import cmath
import json
import math
import tomllib
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy import signal
from scipy.optimize import brentq, minimize_scalar

from bodebench.bench.events import OverviewProgress, PlanGrew, PointFinished
from bodebench.bench.procedure import CaseOutcome, SweepProcedure
from bodebench.core.refine import FIGURE_NAMES, next_round
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.core.summary import channel_curves, summarize_response, unwrapped_phase
from bodebench.io.config import ConfigError, parse_config
from bodebench.io.results import SIDECAR_NAME, load_response
from bodebench.io.tables import AdaptivePlan, FrequencyRange

Response = Callable[[float], complex]


def second_order(fn: float, zeta: float, delay_s: float = 0.0) -> Response:
    def g(f: float) -> complex:
        s, wn = 2j * math.pi * f, 2.0 * math.pi * fn
        return wn * wn / (s * s + 2.0 * zeta * wn * s + wn * wn) * cmath.exp(-s * delay_s)
    return g


def two_mass(f1: float, f2: float, zeta: float, delay_s: float) -> Response:
    """A drive with a load on a compliant shaft: two lightly damped pairs, the second a resonance over an
    anti-resonance."""
    first, second = second_order(f1, zeta), second_order(f2, zeta)
    anti = second_order(0.8 * f2, zeta)

    def g(f: float) -> complex:
        return first(f) * second(f) / anti(f) * cmath.exp(-2j * math.pi * f * delay_s)
    return g


def lag(tau_s: float, delay_s: float = 0.0) -> Response:
    """A first-order lag and a dead time: the phase crosses -90 and -180 deg with no resonance."""
    return lambda f: cmath.exp(-2j * math.pi * f * delay_s) / (1.0 + 2j * math.pi * f * tau_s)


def butterworth(fc: float, order: int) -> Response:
    """An analogue Butterworth low-pass, its poles on the unit circle (in units of 2 pi fc)."""
    poles = [cmath.exp(1j * math.pi * (2 * k + order + 1) / (2 * order)) for k in range(order)]

    def g(f: float) -> complex:
        s, out = 1j * f / fc, 1.0 + 0j
        for p in poles:
            out *= -p / (s - p)
        return out
    return g


def product(*parts: Response) -> Response:
    """The response of parts in series."""
    def g(f: float) -> complex:
        out = 1.0 + 0j
        for part in parts:
            out *= part(f)
        return out
    return g


def notch(f0: float, zeta_zero: float, zeta_pole: float) -> Response:
    """A notch: a lightly damped pair of zeros over a well damped pair of poles at f0."""
    def g(f: float) -> complex:
        s, w = 2j * math.pi * f, 2.0 * math.pi * f0
        return (s * s + 2.0 * zeta_zero * w * s + w * w) / (s * s + 2.0 * zeta_pole * w * s + w * w)
    return g


def points(g: Response, frequencies: list[float], amplitude: float = 0.5) -> FrequencyResponse:
    out = []
    for f in frequencies:
        c = g(f) * amplitude
        out.append(ResponsePoint(f, 1, "y", amplitude, c.real, c.imag, 40, True, "converged", 1e-9, 1e-9, True))
    return FrequencyResponse(out)


def grown(g: Response, plan: AdaptivePlan, start: float, stop: float, per_decade: int,
          kind: str = "system") -> tuple[list[float], FrequencyResponse, int]:
    """The plan's rounds on exact points: the frequencies it ends with, their response and the rounds taken."""
    frequencies = list(FrequencyRange(start, stop, per_decade).expand())
    for rounds in range(40):
        response = points(g, frequencies)
        step = next_round(response, plan, kind, frequencies)
        if not step.additions:
            return frequencies, response, rounds
        frequencies = sorted(frequencies + [a.frequency_hz for a in step.additions])
    raise AssertionError("the plan did not end in 40 rounds")


@dataclass
class Exact:
    """A figure solved on the exact response: value, and the frequency it is read at (Hz)."""

    value: float
    at_hz: float = math.nan


def exact_figures(g: Response, start: float, stop: float, kind: str) -> dict[str, Exact]:
    """The summary's figures of ``g`` over [start, stop], from the exact response: root finding on a dense
    bracket scan, bounded minimisation around the largest gain."""
    f = np.geomspace(start, stop, 20001)
    gain = np.array([20.0 * math.log10(abs(g(x))) for x in f])
    phase = np.degrees(np.unwrap(np.array([cmath.phase(g(x)) for x in f])))
    phase += -360.0 * math.floor((phase[0] + 180.0) / 360.0)

    def gain_db(x: float) -> float:
        return 20.0 * math.log10(abs(g(x)))

    def phase_deg(x: float) -> float:
        return _phase_at(g, f, phase, x)

    def first_down(values: np.ndarray, level: float, fun: Callable[[float], float]) -> float:
        below = np.flatnonzero((values[:-1] > level) & (values[1:] <= level))
        if not below.size:
            return math.nan
        i = int(below[0])
        return float(brentq(lambda x: fun(x) - level, f[i], f[i + 1], xtol=1e-12))

    out: dict[str, Exact] = {}
    ref = gain[0]
    if kind != "open_loop":
        out["bandwidth"] = Exact(first_down(gain, ref - 10.0 * math.log10(2.0), gain_db))
        i = int(np.argmax(gain))
        if 0 < i < f.size - 1:
            best = minimize_scalar(lambda x: -gain_db(x), bounds=(f[i - 1], f[i + 1]), method="bounded",
                                   options={"xatol": 1e-10})
            out["resonance"] = Exact(-float(best.fun) - ref, float(best.x))
    out["phase_90"] = Exact(first_down(phase, -90.0, phase_deg))
    out["phase_180"] = Exact(first_down(phase, -180.0, phase_deg))
    if kind == "open_loop":
        wc = first_down(gain, 0.0, gain_db)
        out["phase_margin"] = Exact(180.0 + phase_deg(wc), wc)
        w180 = first_down(phase, -180.0, phase_deg)
        out["gain_margin"] = Exact(-gain_db(w180), w180)
    return out


def _phase_at(g: Response, f: np.ndarray, unwrapped: np.ndarray, x: float) -> float:
    """The unwrapped phase (deg) at ``x``: the wrapped phase there, on the branch of the nearest scanned one."""
    near = float(np.interp(math.log(x), np.log(f), unwrapped))
    wrapped = math.degrees(cmath.phase(g(x)))
    return wrapped + 360.0 * round((near - wrapped) / 360.0)


def curve_share(response: FrequencyResponse, g: Response | None, gain_db: float = 1.0, phase_deg: float = 10.0
                ) -> float:
    """The largest error of the gain and phase drawn straight between neighbouring points of harmonic 1 (log
    frequency) against the exact curve ``g``, at a quarter, half and three quarters of each interval, over its
    accuracy (NaN: no exact curve)."""
    if g is None:
        return math.nan
    (curve,) = channel_curves(response)
    x = np.log10(curve.frequency_hz)
    phase = unwrapped_phase(curve.phase_deg)
    worst = 0.0
    for i in range(len(x) - 1):
        for t in (0.25, 0.5, 0.75):
            exact = g(10.0 ** (x[i] + t * (x[i + 1] - x[i])))
            drawn_phase = phase[i] + t * (phase[i + 1] - phase[i])
            wrapped = math.degrees(cmath.phase(exact))
            phase_error = abs(wrapped + 360.0 * round((drawn_phase - wrapped) / 360.0) - drawn_phase)
            gain_error = abs(curve.gain_db[i] + t * (curve.gain_db[i + 1] - curve.gain_db[i])
                             - 20.0 * math.log10(abs(exact)))
            worst = max(worst, gain_error / gain_db, phase_error / phase_deg)
    return worst


PLAN = AdaptivePlan()

CLOSED = [
    ("light resonance", second_order(7.31, 0.02, 0.002), 1.0, 100.0),
    ("very light resonance", second_order(23.7, 0.005, 0.0005), 1.0, 100.0),
    ("moderate resonance", second_order(3.17, 0.2, 0.004), 0.5, 50.0),
    ("well damped", second_order(13.9, 0.6, 0.001), 1.0, 200.0),
    ("two-mass drive", two_mass(4.3, 37.0, 0.03, 0.001), 1.0, 150.0),
    ("lag and dead time", lag(0.02, 0.01), 0.5, 200.0),
    ("fourth-order Butterworth", butterworth(20.0, 4), 1.0, 200.0),
    ("two resonances", product(second_order(5.0, 0.05), second_order(31.0, 0.01)), 1.0, 100.0),
    ("a notch in a loop", product(second_order(40.0, 0.5), notch(12.0, 0.01, 0.3)), 1.0, 200.0),
    ("a sharp mode and a delay", second_order(61.8, 0.003, 0.001), 2.0, 300.0),
]


@pytest.mark.parametrize("name, g, start, stop", CLOSED, ids=[c[0] for c in CLOSED])
def test_every_figure_the_plan_calls_met_is_within_its_accuracy_of_the_exact_one(
        name: str, g: Response, start: float, stop: float) -> None:
    frequencies, response, rounds = grown(g, PLAN, start, stop, per_decade=3)
    (summary,) = summarize_response(response)
    exact = exact_figures(g, start, stop, "system")
    step = next_round(response, PLAN, "system", frequencies)
    assert rounds > 0 and not step.additions
    checked = 0
    for standing in step.standings:
        if standing.figure == "curve":  # a curve called within its accuracy is, against the exact one
            assert not standing.met or curve_share(response, g) <= 1.0, f"{name}: {standing.text}"
            continue
        figure = summary.figure(FIGURE_NAMES[standing.figure])
        truth = exact.get(standing.figure)
        if not standing.found:
            assert truth is None or not math.isfinite(truth.value), f"{name}: {standing.text}"
            continue
        assert standing.met, f"{name}: {standing.text}"
        assert truth is not None
        assert abs(figure.value - truth.value) <= standing.accuracy, (
            f"{name}: {figure.name} {figure.value:.6g} vs exact {truth.value:.6g} (accuracy {standing.accuracy:.3g})")
        if standing.figure == "resonance":
            assert abs(figure.at_hz - truth.at_hz) <= PLAN.frequency_percent / 100.0 * truth.at_hz, name
        checked += 1
    assert checked >= 3, f"{name}: only {checked} figures found"


def test_open_loop_margins_are_pinned_down_to_their_accuracy() -> None:
    """A servo loop's open-loop gain (an integrator, a lag and a delay): the margins and their crossovers within
    the asked accuracy of those solved on the exact response."""
    def loop(f: float) -> complex:
        s = 2j * math.pi * f
        return 60.0 / (s * (1.0 + s / (2.0 * math.pi * 31.0))) * cmath.exp(-s * 0.0011)

    frequencies, response, _ = grown(loop, PLAN, 1.0, 300.0, per_decade=3, kind="open_loop")
    (summary,) = summarize_response(response, "open_loop")
    exact = exact_figures(loop, 1.0, 300.0, "open_loop")
    for key in ("phase_margin", "gain_margin", "phase_180"):
        figure = summary.figure(FIGURE_NAMES[key])
        accuracy = {"phase_margin": PLAN.phase_deg, "gain_margin": PLAN.gain_db}.get(
            key, PLAN.frequency_percent / 100.0 * exact[key].value)
        assert abs(figure.value - exact[key].value) <= accuracy, (key, figure.value, exact[key].value)
    assert len(frequencies) < PLAN.max_points


def test_a_resonance_between_two_coarse_points_is_found_by_the_curve() -> None:
    """A mode that the coarse grid steps over (its peak between two points, two points a decade): the phase
    drop bends the curve there, and the plan measures where it lies."""
    g = second_order(31.6, 0.01)
    plan = AdaptivePlan(figures=())
    frequencies, response, _ = grown(g, plan, 1.0, 1000.0, per_decade=2)
    near = [f for f in frequencies if 25.0 < f < 40.0]
    assert len(near) >= 3, frequencies
    (summary,) = summarize_response(response)
    peak = summary.figure("resonance peak")
    assert abs(peak.at_hz - 31.6 * math.sqrt(1 - 2 * 0.01**2)) < 0.05 * 31.6


def test_a_plan_for_the_figures_only_adds_nothing_for_the_curve_and_still_meets_every_figure() -> None:
    """``curve = false``: a lightly damped mode from three points a decade; every addition names a figure, the
    curve has no standing, each figure called met is within its accuracy of the exact one, and the plan ends with
    fewer points than the same plan drawing the curve too."""
    g = second_order(7.31, 0.02)
    plan = AdaptivePlan(curve=False)
    frequencies, response, _ = grown(g, plan, 1.0, 100.0, per_decade=3)
    step = next_round(response, plan, "system", frequencies)
    assert not step.additions
    assert all(s.figure != "curve" for s in step.standings)
    exact = exact_figures(g, 1.0, 100.0, "system")
    (summary,) = summarize_response(response)
    found = [s for s in step.standings if s.found]
    assert {s.figure for s in found} == {"bandwidth", "resonance", "phase_90"}  # a second order: no -180 deg
    for standing in found:
        assert standing.met, standing.text
        figure = summary.figure(FIGURE_NAMES[standing.figure])
        allowed = plan.gain_db if figure.unit == "dB" else plan.frequency_percent / 100.0 * exact[standing.figure].value
        assert abs(figure.value - exact[standing.figure].value) <= allowed, standing.text
    with_curve, _, _ = grown(g, AdaptivePlan(), 1.0, 100.0, per_decade=3)
    assert len(frequencies) < len(with_curve)
    added = [f for f in frequencies if f not in FrequencyRange(1.0, 100.0, 3).expand()]
    assert added  # the figures alone call for points here


def test_a_figure_limited_by_the_measurement_adds_nothing_for_it() -> None:
    """Points whose intervals are wider than the accuracy: the bandwidth's standing says the measurement limits
    it; what the plan adds for it is only where interpolation errs, never a point on top of another."""
    g = second_order(9.0, 0.3)
    frequencies = list(FrequencyRange(1.0, 100.0, 10).expand())
    noisy = FrequencyResponse([
        ResponsePoint(p.frequency_hz, 1, "y", p.amplitude, p.p, p.q, 40, True, "converged", 0.05 * p.magnitude,
                      0.05 * p.magnitude, False) for p in points(g, frequencies).points])
    step = next_round(noisy, PLAN, "system", frequencies)
    bandwidth = next(s for s in step.standings if s.figure == "bandwidth")
    assert bandwidth.measurement > bandwidth.accuracy
    assert "limited by the measurement" in bandwidth.text
    assert not any(a.reason.startswith("y: bandwidth") for a in step.additions)
    # the same points stated exactly: the bandwidth's interpolation alone asks for a point
    exact = next_round(points(g, frequencies), PLAN, "system", frequencies)
    assert any(a.reason.startswith("y: bandwidth") for a in exact.additions)


def test_nothing_is_added_next_to_a_measured_frequency_nor_outside_the_range() -> None:
    g = second_order(7.31, 0.02)
    frequencies = list(FrequencyRange(1.0, 100.0, 3).expand())
    step = next_round(points(g, frequencies), PLAN, "system", frequencies)
    gap = 0.25 * PLAN.frequency_percent / 100.0
    assert step.additions
    for a in step.additions:
        assert frequencies[0] < a.frequency_hz < frequencies[-1]
        assert min(abs(math.log(a.frequency_hz / f)) for f in frequencies) >= gap
        assert a.reason.startswith("y: ")
    added = [a.frequency_hz for a in step.additions]
    assert all(abs(math.log(a / b)) >= gap for i, a in enumerate(added) for b in added[:i])


# --- the plan in a sweep: offline and on the bench chain

MASS, ZETA = 4.8e-4, 0.03  # a resonance at 7.264 Hz, between the coarse points 6.81 and 10 Hz


def oscillator(f: float) -> complex:
    """The linear plant's exact response: 1 / (1 - m w^2 + 2 zeta sqrt(m) j w), stiffness 1."""
    w = 2.0 * math.pi * f
    return 1.0 / (1.0 - MASS * w * w + 2j * ZETA * math.sqrt(MASS) * w)


def held(rate_hz: float) -> Response:
    """The oscillator held and sampled at ``rate_hz``: its zero-order-hold discretisation on the unit circle."""
    num_d, den_d, _ = signal.cont2discrete(([1.0], [MASS, 2.0 * ZETA * math.sqrt(MASS), 1.0]), 1.0 / rate_hz,
                                           method="zoh")

    def g(f: float) -> complex:
        z = cmath.exp(2j * math.pi * f / rate_hz)
        return complex(np.polyval(np.ravel(num_d), z) / np.polyval(den_d, z))
    return g


ADAPTIVE = {"start_hz": 1.0, "stop_hz": 100.0, "per_decade": 3,
            "adaptive": {"figures": ["bandwidth", "resonance", "phase_90"]}}


def assert_figures_within_accuracy(outcome: CaseOutcome, g: Response, start: float = 1.0, stop: float = 100.0
                                   ) -> None:
    """Each figure the plan calls met is within its accuracy, plus the points' own tolerance, of the exact one."""
    assert outcome.plan is not None and outcome.plan.added
    (summary,) = outcome.summary
    exact = exact_figures(g, start, stop, "system")
    for standing in outcome.plan.standings:
        if standing.figure == "curve":  # the figures are what this checks; the curve, the exact-points test
            continue
        assert standing.met, standing.text
        figure = summary.figure(FIGURE_NAMES[standing.figure])
        slack = 0.01 if figure.unit == "dB" else 0.001 * figure.value  # the points' 0.1 % tolerance
        assert abs(figure.value - exact[standing.figure].value) <= standing.accuracy + slack, standing.text


def test_an_offline_sweep_grows_its_plan_and_records_why(tmp_path: Path) -> None:
    data = {"plant": {"model": "linear", "mass": MASS, "stiffness": 1.0, "damping_ratio": ZETA},
            "excitation": {"amplitude": 0.01, "frequencies": ADAPTIVE},
            "analysis": {"harmonics": [1], "tolerance_percent": 0.1, "steps_per_period": 200}}
    events: list[object] = []
    (outcome,) = SweepProcedure(parse_config(data, "adaptive.toml"), tmp_path, listener=events.append).run()
    grew = [e for e in events if isinstance(e, PlanGrew)]
    added = [f for e in grew for f in e.frequencies_hz]
    assert added and all(reason for e in grew for reason in e.reasons)
    on_disk = sorted(p.frequency_hz for p in load_response(tmp_path).points)
    assert on_disk == sorted([*FrequencyRange(1.0, 100.0, 3).expand(), *added])
    record = json.loads((tmp_path / SIDECAR_NAME).read_text())["plan"]
    assert [a["frequency_hz"] for a in record["added"]] == added
    assert record["ended"].startswith("every requested figure")
    assert len([e for e in events if isinstance(e, PointFinished)]) == len(on_disk)
    assert_figures_within_accuracy(outcome, oscillator)


def test_an_offline_sweep_for_the_figures_alone_says_nothing_of_the_curve(tmp_path: Path) -> None:
    """``curve = false`` through the sweep: every added frequency names a figure, the record's account has no
    curve standing and its end says nothing of the curve, and the figures are within their accuracy."""
    data = {"plant": {"model": "linear", "mass": MASS, "stiffness": 1.0, "damping_ratio": ZETA},
            "excitation": {"amplitude": 0.01, "frequencies": {**ADAPTIVE, "adaptive": {
                **ADAPTIVE["adaptive"], "curve": False}}},
            "analysis": {"harmonics": [1], "tolerance_percent": 0.1, "steps_per_period": 200}}
    (outcome,) = SweepProcedure(parse_config(data, "figures.toml"), tmp_path).run()
    record = json.loads((tmp_path / SIDECAR_NAME).read_text())["plan"]
    assert record["added"] and not any("the curve" in a["reason"] for a in record["added"])
    assert {f["figure"] for f in record["figures"]} == set(ADAPTIVE["adaptive"]["figures"])
    assert record["ended"] == "every requested figure found within its accuracy"
    assert_figures_within_accuracy(outcome, oscillator)


@pytest.mark.slow
def test_a_bench_sweep_grows_its_plan_on_the_virtual_bus(tmp_path: Path) -> None:
    """An adaptive plan over python-can's virtual bus to the simulated drive, lockstep at 1 kHz: the figures are
    those of the held and sampled plant, each within its accuracy."""
    plan = {"start_hz": 2.0, "stop_hz": 50.0, "per_decade": 3,
            "adaptive": {"figures": ["bandwidth", "resonance", "phase_90"], "max_points": 24}}
    data = {"plant": {"model": "linear", "mass": MASS, "stiffness": 1.0, "damping_ratio": ZETA},
            "excitation": {"amplitude": 0.01, "frequencies": plan},
            "analysis": {"harmonics": [1], "tolerance_percent": 0.1},
            "bench": {"transport": "can", "rate_hz": 1000, "clock": "lockstep"},
            "can": {"interface": "virtual", "channel": f"adaptive-{uuid.uuid4().hex[:8]}"},
            "safety": {"max_amplitude": 0.02, "watchdog_s": 5.0}, "simulator": {}}
    events: list[object] = []
    (outcome,) = SweepProcedure(parse_config(data, "adaptive.toml"), tmp_path, listener=events.append).run()
    assert any(isinstance(e, PlanGrew) for e in events)
    assert_figures_within_accuracy(outcome, held(1000.0), 2.0, 50.0)
    added = len(outcome.plan.added) if outcome.plan is not None else 0
    assert len(load_response(tmp_path).points) == len(FrequencyRange(2.0, 50.0, 3).expand()) + added


def test_the_guide_s_plan_table_loads_as_written() -> None:
    """The TOML block of docs/adaptive.md, under a plant, is a valid adaptive plan with the values it states."""
    text = (Path(__file__).resolve().parent.parent / "docs" / "adaptive.md").read_text()
    block = text.split("```toml\n", 1)[1].split("```", 1)[0]
    data = tomllib.loads('[plant]\nmodel = "lag"\n[excitation]\namplitude = 0.01\n' + block)
    (case,) = parse_config(data, "adaptive.md").cases
    plan = case.excitation.adaptive
    assert plan is not None and plan.max_points == 40 and plan.budget_s == 600
    assert case.excitation.frequencies_hz == FrequencyRange(1.0, 100.0, 3).expand()


def test_an_overview_first_seeds_the_grid_where_its_lines_call_for_points(tmp_path: Path) -> None:
    """adaptive.from_overview: the multisine runs first, its lines read as the rounds read measured points; the
    frequencies it calls for are in the first round (said so), its files kept in overview/, and the plan then
    ends with every figure within its accuracy of the exact one."""
    data = {"plant": {"model": "linear", "mass": MASS, "stiffness": 1.0, "damping_ratio": ZETA},
            "excitation": {"amplitude": 0.01, "frequencies": {**ADAPTIVE, "adaptive": {
                **ADAPTIVE["adaptive"], "from_overview": True}}},
            "analysis": {"harmonics": [1], "tolerance_percent": 0.1, "steps_per_period": 200},
            "overview": {"start_hz": 1.0, "stop_hz": 100.0, "amplitude": 0.02, "lines_per_decade": 20,
                         "rate_hz": 2000.0}}
    events: list[object] = []
    (outcome,) = SweepProcedure(parse_config(data, "seeded.toml"), tmp_path, listener=events.append).run()
    assert outcome.plan is not None
    seeded = [a for a in outcome.plan.added if a.reason.startswith("overview: ")]
    assert seeded and any(6.5 < a.frequency_hz < 8.0 for a in seeded)  # it saw the resonance
    first_round = {p.frequency_hz for p in load_response(tmp_path).points[:7 + len(seeded)]}
    assert {a.frequency_hz for a in seeded} <= first_round
    assert (tmp_path / "overview" / "overview.csv").exists()
    assert_figures_within_accuracy(outcome, oscillator)
    # the overview's progress is told before the first point, period by period, under the case's name
    told = [e for e in events if isinstance(e, OverviewProgress)]
    first_point = next(i for i, e in enumerate(events) if isinstance(e, PointFinished))
    assert told and all(events.index(e) < first_point for e in told)
    assert [e.periods for e in told] == list(range(1, len(told) + 1)) and {e.case for e in told} == {"seeded"}


def test_from_overview_without_an_overview_table_is_one_line_naming_the_key() -> None:
    data = {"plant": {"model": "linear"}, "excitation": {"amplitude": 0.01, "frequencies": {
        **ADAPTIVE, "adaptive": {"from_overview": True}}}}
    with pytest.raises(ConfigError) as info:
        parse_config(data, "seeded.toml")
    assert str(info.value) == ("seeded.toml: excitation.frequencies.adaptive.from_overview: needs an [overview] table "
                               "(start_hz, stop_hz, amplitude): the multisine run first")


def test_check_says_the_plan_grows_and_within_what() -> None:
    from bodebench.apps.check import check_lines
    from bodebench.io.config import load_config

    lines = list(check_lines(load_config(Path(__file__).resolve().parent.parent / "configs" /
                                         "adaptive_oscillator.toml")))
    (said,) = [line for line in lines if "adaptive:" in line]
    assert "bandwidth, resonance, phase_90, phase_180 to 1 % (frequencies), 0.1 dB" in said
    assert said.endswith("up to 40 frequencies")


def test_an_interrupted_adaptive_sweep_resumes_with_the_frequencies_its_plan_had_added(tmp_path: Path) -> None:
    """An adaptive sweep cut short (the twelve lowest of its frequencies kept, some of them added by its plan):
    resumed, it keeps those as its plan's, measures none twice, and ends with every figure within its accuracy."""
    data = {"plant": {"model": "linear", "mass": MASS, "stiffness": 1.0, "damping_ratio": ZETA},
            "excitation": {"amplitude": 0.01, "frequencies": ADAPTIVE},
            "analysis": {"harmonics": [1], "tolerance_percent": 0.1, "steps_per_period": 200}}
    config = parse_config(data, "adaptive.toml")
    SweepProcedure(config, tmp_path).run()
    csv = (tmp_path / "response.csv").read_text().splitlines(keepends=True)
    header = [line for line in csv if line.startswith("#") or line.startswith("frequency")]
    rows = [line for line in csv if line not in header]
    (tmp_path / "response.csv").write_text("".join(header + rows[:12]))
    kept = {p.frequency_hz for p in load_response(tmp_path).points}
    grid = set(FrequencyRange(1.0, 100.0, 3).expand())
    assert kept - grid  # the cut keeps frequencies the plan had added
    (resumed,) = SweepProcedure(config, tmp_path, existing="resume_changed").run()
    on_disk = [p.frequency_hz for p in load_response(tmp_path).points]
    assert len(on_disk) == len(set(on_disk)) and kept | grid <= set(on_disk)
    assert resumed.plan is not None and resumed.plan.ended.startswith("every requested figure")
    earlier = {a.frequency_hz for a in resumed.plan.added if a.reason == "added by an earlier run of this sweep"}
    assert earlier == kept - grid
    assert_figures_within_accuracy(resumed, oscillator)


def test_a_trip_during_the_overview_a_bench_sweep_runs_first_says_how_it_left_the_drive(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """configs/sim_can.toml with an adaptive plan that runs the overview first and a feedback window the
    multisine leaves: the sweep stops in one line that gives the overview's own account of the drive, not
    "nothing was sent to the drive"."""
    from bodebench.apps.cli import main

    status = main(["run", str(Path(__file__).parent.parent / "configs" / "sim_can.toml"), "--out",
                   str(tmp_path / "out"), "-q",
                   "--set", "overview={start_hz = 5, stop_hz = 100, amplitude = 0.01, lines_per_decade = 5}",
                   "--set", 'plant={model = "linear", mass = 2.533e-4, stiffness = 1.0, damping_ratio = 0.05}',
                   "--set", "excitation={amplitude = 0.01, frequencies = {start_hz = 5, stop_hz = 50, per_decade = 2, "
                            "adaptive = {from_overview = true}}}",
                   "--set", "safety.feedback_limits={position = [-1e-3, 1e-3]}",
                   "--set", f"can.channel=overview-trip-{uuid.uuid4().hex[:8]}"])
    err = capsys.readouterr().err.strip()
    assert status == 1 and len(err.splitlines()) == 1, err
    assert err.startswith("bodebench: sim_can: stopped: feedback_limit: position = ")
    assert err.endswith("no point measured; drive left at setpoint 0, disabled"), err
