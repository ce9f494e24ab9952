"""The overview measurement: the multisine against its definitions, every line against the exact sampled-data
response of a linear plant (a zero-order hold, worked out here with scipy), the distortion indicator on the friction
link against a linear plant, the [overview] table's errors and safety refusals, and ``bodebench overview``."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.signal

from bodebench.apps.cli import main
from bodebench.bench.worker import TableProgram
from bodebench.core.multisine import LINE_GAP, Multisine, design_multisine, sine_coefficients
from bodebench.core.overview import LineIntegrator, OverviewLine, RuleSettings
from bodebench.sim.plants import CoulombOscillator, LinearOscillator, Plant

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
MASS, STIFFNESS = 2.533e-4, 1.0  # the friction link's m and K_p: a resonance near 10 Hz


def direct_sum(design: Multisine) -> np.ndarray:
    """One period of the multisine summed sine by sine from its definition (no FFT)."""
    n = np.arange(design.samples)
    return sum(design.line_amplitude * np.sin(2 * np.pi * k * n / design.samples + phase)
               for k, phase in zip(design.lines, design.phases, strict=True))


def exact_zoh_response(plant: LinearOscillator, rate_hz: float, frequencies_hz: np.ndarray) -> np.ndarray:
    """Position over setpoint of the plant driven by a zero-order hold at ``rate_hz`` and sampled at the same
    instants: the discretised plant's C (zI - A_d)^-1 B_d at z = exp(j 2 pi f / rate)."""
    a_d, b_d, c_d, _, _ = scipy.signal.cont2discrete((plant.a, plant.b.reshape(-1, 1), plant.c[:1], np.zeros((1, 1))),
                                                     1.0 / rate_hz, method="zoh")
    return np.array([(c_d @ np.linalg.solve(np.exp(2j * np.pi * f / rate_hz) * np.eye(2) - a_d, b_d))[0, 0]
                     for f in frequencies_hz])


def run_lines(design: Multisine, plant: Plant, rules: RuleSettings, noise: float, seed: int) -> list[OverviewLine]:
    """The overview of ``plant`` with white noise of standard deviation ``noise`` on its sampled position."""
    rng = np.random.default_rng(seed)
    integrator = LineIntegrator(design, "position", rules)
    setpoint = design.waveform()
    state, at_start = plant.initial_state(), 0.0
    while not integrator.done:
        after = plant.run_held(state, setpoint, 1.0 / design.rate_hz)[:, 0]
        output = np.concatenate([[at_start], after[:-1]])
        at_start = float(after[-1])
        integrator.feed_period(setpoint, output + rng.normal(0.0, noise, output.size))
    return integrator.result()


def test_each_period_dft_is_exact_on_a_whole_number_of_samples() -> None:
    """The waveform is its definition's sum of sines; its DFT gives every excited line's coefficient and nothing on
    any other line, and a sine on the grid comes back exactly whatever its phase."""
    design = design_multisine(1000.0, 1.0, 50.0, 8, 0.5, seed=3)
    u = design.waveform()
    # np.sin of arguments up to pi N carries round-off of about N ulps of a radian
    assert np.max(np.abs(u - direct_sum(design))) <= 1e-10 * design.peak
    every = np.arange(1, design.samples // 2)
    coefficients = sine_coefficients(u, every)
    excited = np.isin(every, design.lines)
    assert np.max(np.abs(coefficients[excited] - design.coefficients)) <= 1e-12 * design.line_amplitude
    assert np.max(np.abs(coefficients[~excited])) <= 1e-12 * design.line_amplitude
    n = np.arange(design.samples)
    for line, amplitude, phase in ((design.lines[0], 0.3, 2.0), (7, 1.7, -0.4), (design.samples // 2 - 3, 0.2, 1.0)):
        sine = amplitude * np.sin(2 * np.pi * line * n / design.samples + phase)
        found = sine_coefficients(sine, np.array([line, line + 1]))
        assert abs(found[0] - amplitude * np.exp(1j * phase)) <= 1e-10 * amplitude
        assert abs(found[1]) <= 1e-10 * amplitude


def test_lines_are_odd_log_spread_with_detection_lines_between() -> None:
    for rate, start, stop, per_decade in ((2000.0, 2.0, 100.0, 10), (1000.0, 0.5, 200.0, 20), (5000.0, 10.0, 600.0, 5)):
        design = design_multisine(rate, start, stop, per_decade, 1.0)
        lines = np.array(design.lines)
        assert design.samples * design.resolution_hz == pytest.approx(rate)
        assert np.all(lines % 2 == 1) and np.all(np.diff(lines) >= LINE_GAP)
        assert abs(design.frequencies_hz[0] - start) <= design.resolution_hz
        assert design.frequencies_hz[-1] <= stop
        decades = math.log10(design.frequencies_hz[-1] / design.frequencies_hz[0])
        assert abs(len(lines) - 1 - decades * per_decade) <= 1.0
        ratio = lines[1:] / lines[:-1]
        assert np.all(np.abs(np.log10(ratio) * per_decade - 1.0) <= 0.25)  # one line a 1/per_decade decade
        for k in lines:
            detection = design.detection_lines(int(k))
            assert set(detection) == {k - 2, k - 1, k + 1, k + 2}
            assert not set(detection) & set(design.lines)


def test_crest_factor_against_its_definition() -> None:
    """Peak over rms of the summed sines; the refined phases beat random ones; the peak is the amplitude asked
    for; the slew is the steepest step of the held samples (the period's wrap included) times the rate."""
    design = design_multisine(2000.0, 2.0, 100.0, 10, 0.04, seed=0)
    u = direct_sum(design)
    crest = np.max(np.abs(u)) / np.sqrt(np.mean(u * u))
    assert design.crest_factor == pytest.approx(crest, rel=1e-9)
    assert design.peak == pytest.approx(0.04, rel=1e-9)
    assert design.rms == pytest.approx(design.line_amplitude * math.sqrt(len(design.lines) / 2), rel=1e-9)
    steps = np.abs(np.diff(np.concatenate([u, u[:1]])))
    assert design.peak_slew == pytest.approx(np.max(steps) * 2000.0, rel=1e-9)
    rng = np.random.default_rng(11)
    n = np.arange(design.samples)
    random_crests = []
    for _ in range(20):
        phases = rng.uniform(-np.pi, np.pi, len(design.lines))
        w = sum(np.sin(2 * np.pi * k * n / design.samples + p) for k, p in zip(design.lines, phases, strict=True))
        random_crests.append(np.max(np.abs(w)) / np.sqrt(np.mean(w * w)))
    assert crest < min(random_crests)


def test_linear_plant_lines_cover_the_exact_response() -> None:
    """A damped resonance with white noise on its output, twelve noise records: every line's 95 % disc and gain
    interval against the exact zero-order-hold response, counted over all lines; lines at the noise end
    noise-limited, well before the period budget."""
    plant = LinearOscillator(MASS, STIFFNESS, 0.05)
    design = design_multisine(2000.0, 2.0, 200.0, 10, 0.01, seed=0)
    exact = exact_zoh_response(plant, design.rate_hz, design.frequencies_hz)
    rules = RuleSettings("adaptive", tolerance_percent=1.0, skip_periods=1, window=5, max_periods=300)
    inside_disc = inside_gain = total = 0
    statuses: dict[str, list[int]] = {}
    records = 12
    for seed in range(records):
        for line, truth in zip(run_lines(design, plant, rules, 2e-3, seed), exact, strict=True):
            p = line.point
            h = complex(p.p, p.q) / p.amplitude
            inside_disc += abs(h - truth) <= p.uncertainty / p.amplitude
            inside_gain += abs(p.gain - abs(truth)) <= p.gain_ci
            total += 1
            statuses.setdefault(p.status, []).append(p.periods)
            if p.status == "converged":
                assert abs(h - truth) <= 2 * rules.tolerance_percent / 100 * abs(h)
    assert total == records * len(design.lines) >= 250
    assert inside_disc / total >= 0.9, (inside_disc, total)
    assert inside_gain / total >= 0.9, (inside_gain, total)
    assert len(statuses["converged"]) >= total // 3
    early = [periods for periods in statuses["noise_limited"] if periods < rules.max_periods]
    assert len(early) >= len(statuses["noise_limited"]) / 2 >= 1


def test_distortion_stands_above_the_noise_for_the_friction_link_only() -> None:
    """The same multisine and noise on the friction link and on a linear resonance: at the lines whose output
    stands 30 dB above the noise, the friction link's distortion is far above the noise, the linear plant's is the
    noise."""
    design = design_multisine(2000.0, 2.0, 100.0, 10, 0.04, seed=0)
    rules = RuleSettings("adaptive", tolerance_percent=1.0, skip_periods=1, window=5, max_periods=200)
    ratios = {}
    for name, plant in (("linear", LinearOscillator(MASS, STIFFNESS, 0.05)),
                        ("friction", CoulombOscillator(MASS, STIFFNESS, 0.008))):
        lines = run_lines(design, plant, rules, 1e-3, seed=7)
        clear = [line for line in lines if line.noise_db < -30.0]
        assert len(clear) >= len(lines) // 2
        ratios[name] = np.array([line.distortion / line.noise for line in clear])
    assert np.median(ratios["friction"]) > 20.0
    assert np.max(ratios["linear"]) < 2.5
    assert 0.6 < np.median(ratios["linear"]) < 1.6


def read_overview(directory: Path) -> list[dict[str, str]]:
    with (directory / "overview.csv").open() as handle:
        return list(csv.DictReader(handle))


def test_overview_command_offline(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """configs/sim_overview.toml: the linear case's lines are the exact zero-order-hold response, its distortion
    round-off; the friction link's distortion is tens of dB below its output; the files of a response are there."""
    out = tmp_path / "out"
    assert main(["overview", str(CONFIGS / "sim_overview.toml"), "--out", str(out), "-q"]) == 0
    sidecar = json.loads((out / "linear" / "response.json").read_text())
    plant_table = sidecar["config"]["plant"]
    design = sidecar["multisine"]
    assert sidecar["config"]["overview"]["amplitude"] == design["peak"]
    plant = LinearOscillator(plant_table["mass"], plant_table["stiffness"], plant_table["damping_ratio"])
    rows = read_overview(out / "linear")
    frequencies = np.array([float(r["frequency_hz"]) for r in rows])
    assert np.allclose(frequencies, np.array(design["lines"]) * design["resolution_hz"])
    exact = exact_zoh_response(plant, design["rate_hz"], frequencies)
    gain = np.array([float(r["gain"]) for r in rows])
    phase = np.array([float(r["phase_deg"]) for r in rows])
    assert np.max(np.abs(gain / np.abs(exact) - 1.0)) < 1e-9
    exact_phase = np.degrees(np.angle(exact))
    assert np.max(np.abs((phase - exact_phase + 180.0) % 360.0 - 180.0)) < 1e-7
    assert all(r["status"] == "converged" for r in rows)
    assert max(float(r["distortion_db"]) for r in rows) < -200.0
    friction = read_overview(out / "friction")
    assert min(float(r["distortion_db"]) for r in friction) > -60.0
    for case in ("linear", "friction"):
        assert {"response.csv", "response.json", "overview.csv", "bode.png", "levels.png"} <= \
            {p.name for p in (out / case).iterdir()}
    assert main(["overview", str(CONFIGS / "sim_overview.toml"), "--out", str(out), "-q"]) == 2
    assert "results already here" in capsys.readouterr().err


BAD = [
    (["--set", "overview.stop_hz=1"], "overview.stop_hz: must be > overview.start_hz (2 Hz), got 1"),
    (["--set", "overview.start_hz=0.001"], "overview.start_hz: 0.001 Hz needs a period of"),
    (["--set", "overview.rate_hz=500"], "overview.stop_hz: 100 Hz needs at least 8 samples a period at "
                                        "overview.rate_hz = 500 (at most 62.5 Hz)"),
    (["--set", "overview.lines_per_decade=0"], "overview.lines_per_decade: must be >= 1, got 0"),
    (["--set", "overview.amplitude=-1"], "overview.amplitude: must be > 0, got -1"),
    (["--set", "overview.periods=3"], "overview.periods: unknown key"),
]


@pytest.mark.parametrize(("options", "message"), BAD)
def test_bad_overview_gives_one_line_naming_the_key(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    options: list[str], message: str) -> None:
    status = main(["overview", str(CONFIGS / "sim_overview.toml"), "--out", str(tmp_path / "o"), *options])
    err = capsys.readouterr().err.strip()
    assert status == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith(f"bodebench: {CONFIGS / 'sim_overview.toml'}: ") and message in err, err
    assert not (tmp_path / "o").exists()


def test_overview_needs_its_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["overview", str(CONFIGS / "paper2013.toml"), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == (f"bodebench: {CONFIGS / 'paper2013.toml'}: overview: missing "
                                               "(bodebench overview needs an [overview] table: start_hz, stop_hz, "
                                               "amplitude)")
    assert not (tmp_path / "o").exists()


ON_CAN = ["--set", "overview={start_hz = 5, stop_hz = 100, amplitude = 0.01, lines_per_decade = 5}",
          "--set", 'plant={model = "linear", mass = 2.533e-4, stiffness = 1.0, damping_ratio = 0.05}']
"""configs/sim_can.toml's drive (lockstep, virtual CAN) around a damped linear resonance, with an overview."""


def test_overview_on_the_simulated_can_drive_is_the_exact_response(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """The whole chain: the multisine sent as a table of setpoints over the bus, the drive's feedback dated by its
    counter; every line is the exact zero-order-hold response to the float32 frames' precision, and the drive is
    left at zero and disabled."""
    out = tmp_path / "can"
    assert main(["overview", str(CONFIGS / "sim_can.toml"), "--out", str(out), "-q", *ON_CAN]) == 0
    assert "drive left at setpoint 0, disabled" in capsys.readouterr().out
    design = json.loads((out / "response.json").read_text())["multisine"]
    assert design["rate_hz"] == 2000.0  # bench.rate_hz
    rows = read_overview(out)
    frequencies = np.array([float(r["frequency_hz"]) for r in rows])
    exact = exact_zoh_response(LinearOscillator(MASS, STIFFNESS, 0.05), design["rate_hz"], frequencies)
    gain = np.array([float(r["gain"]) for r in rows])
    phase = np.array([float(r["phase_deg"]) for r in rows])
    assert np.max(np.abs(gain / np.abs(exact) - 1.0)) < 1e-6
    assert np.max(np.abs((phase - np.degrees(np.angle(exact)) + 180.0) % 360.0 - 180.0)) < 1e-4
    assert max(float(r["distortion_db"]) for r in rows) < -100.0
    assert all(r["status"] == "converged" for r in rows)


def test_a_trip_during_the_overview_leaves_the_drive_at_zero(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "trip"
    status = main(["overview", str(CONFIGS / "sim_can.toml"), "--out", str(out), "-q", *ON_CAN,
                   "--set", "safety.feedback_limits={position = [-1e-3, 1e-3]}"])
    err = capsys.readouterr().err.strip()
    assert status == 1
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("bodebench: sim_can: stopped: feedback_limit: position = ") and \
        err.endswith("outside [-0.001, 0.001]; drive left at setpoint 0, disabled"), err
    assert not out.exists()


def test_table_program_repeats_its_table_between_whole_period_ramps() -> None:
    table = (0.5, -1.0, 2.0, 0.25)
    program = TableProgram(table, ramp_in_periods=2, ramp_out_periods=1, tick0=10, period_s=1e-3)
    assert program.f == pytest.approx(250.0)
    assert [program.value(t) for t in range(8, 10)] == [0.0, 0.0]
    ramp = [program.value(10 + n) for n in range(8)]
    assert ramp == pytest.approx([table[n % 4] * n / 8 for n in range(8)])
    assert [program.value(18 + n) for n in range(8)] == pytest.approx([table[n % 4] for n in range(8)])
    program.finish(27)
    assert [program.value(27 + n) for n in range(4)] == pytest.approx([table[(17 + n) % 4] * (1 - n / 4)
                                                                       for n in range(4)])
    assert program.finished(31) and program.value(31) == 0.0 and not program.finished(30)


def test_multisine_beyond_the_safety_limits_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    """On a bench the whole multisine must keep within [safety]: its peak within max_amplitude, the steepest
    step of its held samples within max_rate; each refusal is one line naming overview.amplitude."""
    config = str(CONFIGS / "sim_can.toml")
    assert main(["check", config, "--set", "overview={start_hz = 2, stop_hz = 50, amplitude = 0.03}"]) == 2
    assert capsys.readouterr().err.strip() == (f"bodebench: {config}: --set overview.amplitude: the multisine's "
                                               "peak 0.03 exceeds safety.max_amplitude (0.02)")
    design = design_multisine(2000.0, 2.0, 200.0, 10, 0.019)  # sim_can.toml's rate; within max_amplitude
    u = direct_sum(design)
    slew = np.max(np.abs(np.diff(np.concatenate([u, u[:1]])))) * 2000.0
    assert slew > 5.0  # sim_can.toml's max_rate
    assert main(["check", config, "--set", "overview={start_hz = 2, stop_hz = 200, amplitude = 0.019}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"bodebench: {config}: --set overview.amplitude: 0.019: the multisine's steepest step is "
                          f"{slew:g} a second, above safety.max_rate (5)"), err
    assert main(["check", config, "--set", "overview={start_hz = 2, stop_hz = 20, amplitude = 0.01}"]) == 0
    design = design_multisine(2000.0, 2.0, 20.0, 10, 0.01)
    assert (f"overview: {len(design.lines)} odd lines from 2 to {design.frequencies_hz[-1]:.4g} Hz, a period of "
            f"{design.samples} samples") in capsys.readouterr().out


@pytest.mark.slow
def test_bench_overview_intervals_cover_the_exact_response_under_noise() -> None:
    """configs/sim_can.toml's drive called in-process around a damped linear resonance, with white noise on its
    feedback ([simulator] noise), three noise seeds: every line's 95 % disc against the exact zero-order-hold
    response, counted over all lines."""
    from bodebench.bench.connection import plan_link
    from bodebench.bench.overview import measure_overview_on_bench
    from bodebench.io.config import load_config
    from bodebench.io.document import parse_override

    inside = total = 0
    for seed in range(3):
        overrides = [parse_override(text) for text in (
            "overview={start_hz = 5, stop_hz = 100, amplitude = 0.01, lines_per_decade = 10, tolerance_percent = 1}",
            'plant={model = "linear", mass = 2.533e-4, stiffness = 1.0, damping_ratio = 0.05}',
            "simulator.noise=2e-5", f"simulator.seed={seed}")]
        case = load_config(CONFIGS / "sim_can.toml", overrides).cases[0]
        result = measure_overview_on_bench(case, plan_link(case, direct=True))
        assert result.ended is not None and result.ended.zero_sent and result.ended.disabled
        exact = exact_zoh_response(LinearOscillator(MASS, STIFFNESS, 0.05), result.design.rate_hz,
                                   result.design.frequencies_hz)
        for line, truth in zip(result.lines, exact, strict=True):
            p = line.point
            inside += abs(complex(p.p, p.q) / p.amplitude - truth) <= p.uncertainty / p.amplitude
            total += 1
    assert total >= 40
    assert inside / total >= 0.85, (inside, total)


def test_an_abort_during_a_bench_overview_stops_it_within_a_second_and_leaves_the_drive_at_zero() -> None:
    """An abort requested after the third period (the sweep's controls, asked before each wait as the procedure
    asks them): the overview stops with the abort's own fault, before its lines are measured, and the end it
    reports leaves the drive at setpoint 0, disabled."""
    from bodebench.bench.connection import plan_link
    from bodebench.bench.controls import SweepControls
    from bodebench.bench.events import SessionEnded, SessionError
    from bodebench.bench.overview import measure_overview_on_bench
    from bodebench.io.config import load_config
    from bodebench.io.document import parse_override
    from bodebench.status import FaultKind

    case = load_config(CONFIGS / "sim_can.toml", [parse_override(text) for text in ON_CAN[1::2]]).cases[0]
    controls = SweepControls()
    periods: list[int] = []
    ended: list[SessionEnded] = []

    def period(n: int) -> None:
        periods.append(n)
        if n == 3:
            controls.request_abort()

    with pytest.raises(SessionError) as info:
        measure_overview_on_bench(case, plan_link(case, direct=True), period, on_end=ended.append,
                                  before_wait=controls.check_abort)
    assert info.value.kind == FaultKind.ABORT and str(info.value) == "abort: aborted by the user"
    assert 3 <= len(periods) < 10
    (end,) = ended
    assert not end.completed and end.reason == "abort: aborted by the user"
    assert end.drive_state() == "drive left at setpoint 0, disabled"
