"""Measurement modes (``[analysis] measured``) against exact answers: the simulated drive's loop assembled apart,
from scipy's zero-order-hold discretisation of the plant and the PID's z-transform, and each mode's ratio of
channels measured on the virtual bus within its points' intervals."""

from __future__ import annotations

import math
import tomllib
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.signal as sg

from bodebench.apps.check import _case_lines
from bodebench.bench.connection import plan_link, simulator_spec
from bodebench.bench.session import BenchSession
from bodebench.core.measured import INJECTION, FormError, formed_columns
from bodebench.drivers.canopen_link import CanopenDriver
from bodebench.drivers.ports import CanPort
from bodebench.io.config import ConfigError, parse_config
from bodebench.sim.canopen_device import serve_canopen
from bodebench.sim.plants import FirstOrderLag, LinearOscillator, LinearPlant
from bodebench.sim.servo_loop import ServoLoop
from bodebench.status import PointStatus


def load_config(path: Path) -> dict[str, Any]:
    """The TOML table of a configuration file, to edit before parsing."""
    with path.open("rb") as fh:
        return tomllib.load(fh)


RATE_HZ = 2000.0
H = 1.0 / RATE_HZ
FLOAT32 = 1e-6  # a few float32 roundings of each channel, relative
CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def exact(plant: LinearPlant, gains: tuple[float, float, float], f: float, h: float = H) -> dict[str, complex]:
    """The loop at f Hz in z over one control period h (s): P from the input held over a period to the output at its
    end (scipy's ZOH discretisation), C = kp + ki h/(1 - 1/z) + kd (1 - 1/z)/h, the error read one period late."""
    kp, ki, kd = gains
    ad, bd, cd, _, _ = sg.cont2discrete((plant.a, plant.b.reshape(-1, 1), plant.c, np.zeros((plant.c.shape[0], 1))),
                                        h, "zoh")
    z = np.exp(2j * math.pi * f * h)
    p = complex((cd @ np.linalg.solve(np.eye(ad.shape[0]) - ad / z, bd))[0, 0])
    c = kp + ki * h / (1 - 1 / z) + kd * (1 - 1 / z) / h
    loop = p * c / z
    return {"plant": p, "loop": loop, "sensitivity": 1 / (1 + loop), "complementary": loop / (1 + loop)}


PLANTS: dict[str, tuple[LinearPlant, tuple[float, float, float]]] = {
    "position PID": (LinearOscillator(0.01, 1.0, 0.05), (60.0, 300.0, 0.9)),
    "velocity PI": (FirstOrderLag(0.05, 10.0), (0.5, 20.0, 0.0)),
}


@pytest.mark.parametrize("name", list(PLANTS))
def test_the_drive_loop_steps_as_its_z_transform_says(name: str) -> None:
    """The simulated drive's loop, driven at its plant input by a sine held over each control period, settles to
    channel ratios equal to the exact loop (DFT over whole periods of the settled record, 1e-9)."""
    plant, gains = PLANTS[name]
    loop = ServoLoop(plant, *gains, inject="effort")
    for f in (2.0, 12.5, 40.0):
        per_period = round(RATE_HZ / f)
        n = per_period * 400
        k = np.arange(1, n + 1)
        d = np.sin(2 * math.pi * f * k * H)
        out = loop.run_held(loop.initial_state(), d, H)
        tail = slice(n - 40 * per_period, n)
        basis = np.exp(-2j * math.pi * f * k[tail] * H)

        def phasor(x: np.ndarray, basis: np.ndarray = basis, tail: slice = tail) -> complex:
            return complex(np.sum(x[tail] * basis))

        y, u, uc, dd = (phasor(out[:, 0]), phasor(out[:, -2]), phasor(out[:, -1]), phasor(d))
        want = exact(plant, gains, f)
        got = {"plant": y / u, "loop": -uc / u, "sensitivity": u / dd, "complementary": -uc / dd}
        for mode, value in got.items():
            assert abs(value - want[mode]) <= 1e-9 * max(1.0, abs(want[mode])), (name, f, mode, value, want[mode])


def test_each_mode_forms_its_columns_from_the_channels() -> None:
    values = np.array([[3.0, 1.0, 7.0], [5.0, -2.0, 11.0]])  # effort, control, position
    names = ("effort", "control", "position")

    def formed(measured: str) -> tuple[tuple[str, ...], str, np.ndarray]:
        form = formed_columns(measured, ("position",), "", "effort", "control")
        raw = values[:, [names.index(n) for n in form.raw]]
        return form.outputs, form.reference, form.combine(raw)

    outputs, reference, columns = formed("plant")
    assert (outputs, reference) == (("position",), "effort") and np.array_equal(columns, values[:, [2, 0]])
    outputs, reference, columns = formed("loop")
    assert (outputs, reference) == (("loop",), "effort")
    assert np.array_equal(columns, np.stack([-values[:, 1], values[:, 0]], axis=1))
    for mode, numerator in (("sensitivity", values[:, 0]), ("complementary", -values[:, 1])):
        outputs, reference, columns = formed(mode)
        assert (outputs, reference) == ((mode,), INJECTION)
        assert np.array_equal(columns, np.stack([numerator, values[:, 0] - values[:, 1]], axis=1))
    form = formed_columns("output", ("position", "velocity"), "setpoint_echo")
    assert form.raw == ("position", "velocity", "setpoint_echo") and form.selects
    assert form.formulas() == ("position / setpoint_echo", "velocity / setpoint_echo")
    # what check prints: each column as its channels form it
    assert [formed_columns(m, ("position",), "", "effort", "control").formulas()[0]
            for m in ("output", "plant", "loop", "sensitivity", "complementary")] == [
        "position against the excitation", "position / effort", "loop = -control / effort",
        "sensitivity = effort / (effort - control)", "complementary = -control / (effort - control)"]
    with pytest.raises(FormError) as missing:
        formed_columns("loop", ("position",), "", "effort")
    assert missing.value.field == "control_channel"
    with pytest.raises(FormError) as missing:
        formed_columns("plant", ("position",))
    assert missing.value.field == "effort_channel"


def case_of(measured: str, plant: str, gains: tuple[float, float, float], noise: float = 0.0,
            frequencies: tuple[float, ...] = (2.0, 12.5, 40.0), seed: int = 1) -> Any:
    data = load_config(CONFIGS / "sim_loop.toml")
    data["plant"] = ({"model": "linear", "mass": 0.01, "stiffness": 1.0, "damping_ratio": 0.05}
                     if plant == "position PID" else {"model": "lag", "time_constant": 0.05, "gain": 10.0})
    data["excitation"]["frequencies_hz"] = list(frequencies)
    data["analysis"]["measured"] = measured
    data["can"]["channel"] = f"loop-{uuid.uuid4().hex[:8]}"
    data["simulator"]["loop"].update(kp=gains[0], ki=gains[1], kd=gains[2])
    data["simulator"].update(noise=noise, seed=seed)
    data["safety"]["feedback_limits"] = {}
    return parse_config(data, "loop.toml").cases[0]


@pytest.mark.slow
@pytest.mark.parametrize("name", list(PLANTS))
def test_every_mode_measures_its_exact_ratio_within_the_points_intervals(name: str) -> None:
    plant, gains = PLANTS[name]
    for measured in ("plant", "loop", "sensitivity", "complementary"):
        case = case_of(measured, name, gains)
        result = BenchSession(case, plan_link(case)).run()
        assert result.completed, result
        for point in result.response.points:
            want = exact(plant, gains, point.frequency_hz)[measured]
            got = complex(point.p, point.q) / point.amplitude
            assert point.converged and point.within_eps, (measured, point)
            # the frames carry float32: their rounding, the same every period, is below the spread's reach
            bound = point.uncertainty / point.amplitude + FLOAT32 * abs(want)
            assert abs(got - want) <= bound, (name, measured, point.frequency_hz, got, want)
            assert abs(got - want) <= point.tolerance_percent / 100 * abs(want)


@pytest.mark.slow
def test_with_sensor_noise_the_loop_intervals_cover_the_exact_answer() -> None:
    """Noise on every channel, the divisor's too: the per-period ratio's 95 % discs hold the exact loop gain."""
    plant, gains = PLANTS["position PID"]
    held = []
    for seed in range(1, 5):
        case = case_of("loop", "position PID", gains, noise=2e-3, frequencies=(5.0, 17.0, 30.0), seed=seed)
        result = BenchSession(case, plan_link(case)).run()
        assert result.completed, result
        for point in result.response.points:
            want = exact(plant, gains, point.frequency_hz)["loop"]
            held.append(abs(complex(point.p, point.q) / point.amplitude - want) <= point.uncertainty / point.amplitude)
    assert np.mean(held) >= 10 / 12


def test_the_loader_says_what_a_mode_lacks() -> None:
    data = load_config(CONFIGS / "sim_loop.toml")
    del data["bench"]["control_channel"]
    with pytest.raises(ConfigError, match=r"bench\.control_channel.*missing: loop needs the controller output"):
        parse_config(data, "loop.toml")
    data = load_config(CONFIGS / "sim_loop.toml")
    data["analysis"]["harmonics"] = [1, 2]
    with pytest.raises(ConfigError, match=r"analysis\.harmonics.*ratio of fundamentals"):
        parse_config(data, "loop.toml")
    data = load_config(CONFIGS / "sim_loop.toml")
    data["bench"]["effort_channel"] = "torque"
    with pytest.raises(ConfigError, match=r"bench\.effort_channel.*'torque' is not a feedback channel"):
        parse_config(data, "loop.toml")


def test_the_loader_checks_what_the_simulated_drive_can_send_and_regulate() -> None:
    """A loop regulating no output of the plant, and a feedback channel the simulated drive does not have, are
    one line each from the loader, not a failure after the bus is up; the names it
    gives are the plant's own."""
    from bodebench.bench.offline import build_plant

    data = load_config(CONFIGS / "sim_loop.toml")
    data["simulator"]["loop"]["feedback"] = "velocty"
    outputs = build_plant(parse_config(load_config(CONFIGS / "sim_loop.toml"), "loop.toml").cases[0].plant
                          ).output_names
    with pytest.raises(ConfigError) as info:
        parse_config(data, "loop.toml")
    assert str(info.value) == (f"loop.toml: simulator.loop.feedback: 'velocty' is not an output of the linear plant "
                               f"({', '.join(outputs)})")
    data["simulator"]["loop"]["feedback"] = "velocity"
    assert parse_config(data, "loop.toml").cases[0].simulator.loop.feedback == "velocity"
    data = load_config(CONFIGS / "sim_loop.toml")
    data["frames"]["feedback"][1]["signals"][0]["name"] = "torque"
    data["bench"]["effort_channel"] = "torque"
    with pytest.raises(ConfigError) as info:
        parse_config(data, "loop.toml")
    assert str(info.value).startswith("loop.toml: simulator: feedback channel 'torque' (feedback[1], id 0x182) is "
                                      "not sent by the simulated drive: it sends the linear plant's position, velocity")


def test_a_loop_sweep_reanalyses_to_itself_and_refuses_another_mode_and_the_chain(tmp_path: Path) -> None:
    """The record holds the mode's columns: ``analyse`` gives the same points; another mode, or taking the bench's
    delays off a ratio of two channels, is refused in one line."""
    import subprocess
    import sys

    from bodebench.analysis.reanalyse import reanalyse

    plant, gains = PLANTS["velocity PI"]
    case = case_of("loop", "velocity PI", gains, frequencies=(5.0, 20.0))
    result = BenchSession(case, plan_link(case), out_dir=tmp_path).run()
    assert result.completed, result
    again = reanalyse(tmp_path)
    assert [(p.p, p.q, p.periods) for p in again.response.points] == \
        [(p.p, p.q, p.periods) for p in result.response.points]
    with pytest.raises(ConfigError, match=r"analysis\.measured: the samples hold the columns of 'loop'"):
        reanalyse(tmp_path, measured="plant")
    run = subprocess.run([sys.executable, "-m", "bodebench", "analyse", str(tmp_path), "--without-chain"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode != 0 and "Traceback" not in run.stderr
    assert "the sweep measured loop, a ratio of two of the drive's channels" in run.stderr


@pytest.mark.slow
def test_a_divisor_drowned_in_noise_ends_divisor_limited_not_with_a_short_interval() -> None:
    """Far inside the loop's bandwidth its effort |S| A is small: with enough sensor noise a period's effort
    coefficient scatters by about half its size, where the mean of the periods' ratios is biased by more than
    their spread can say (MAX_DIVISOR_SCATTER), and the points say so instead of standing as measurements."""
    plant, gains = PLANTS["position PID"]
    case = case_of("loop", "position PID", gains, noise=0.25, frequencies=(5.0,))
    result = BenchSession(case, plan_link(case)).run()
    assert result.completed, result
    for point in result.response.points:
        want = exact(plant, gains, point.frequency_hz)["loop"]
        assert abs(complex(point.p, point.q) / point.amplitude - want) > point.tolerance_percent / 100 * abs(want)
        assert point.status == PointStatus.DIVISOR_LIMITED and not point.converged and not point.within_eps


def test_the_divisor_scatter_is_the_spread_of_its_fundamental_over_its_size() -> None:
    """Two-channel feed of a noiseless output over a reference whose fundamental is 1 + n per period, n drawn
    with a known relative spread: divisor_scatter gives that spread over the settled periods (numpy on the same
    draws, the periods a coherence is taken over), and a spread above MAX_DIVISOR_SCATTER ends every point
    divisor_limited. A divisor that starts at three times its size and settles within the skipped periods (a
    loop's effort as the loop settles) is judged on its settled spread alone; a point too short for a settled
    half of MIN_SCATTER_PERIODS is judged on every period after the skipped ones."""
    from bodebench.core.autointegration import MAX_DIVISOR_SCATTER, MIN_SCATTER_PERIODS, Autointegrator
    from bodebench.core.quality import coherence_periods

    f, steps = 10.0, 200
    rng = np.random.default_rng(5)
    for spread, transient, periods in ((0.05, False, 64), (0.4, False, 64), (0.05, True, 64), (0.6, False, 6)):
        draws = 1 + spread / math.sqrt(2) * (rng.standard_normal(periods) + 1j * rng.standard_normal(periods))
        analysis = case_of("loop", "velocity PI", PLANTS["velocity PI"][1]).analysis
        if transient:
            draws = draws * (1 + 2 * np.exp(-np.arange(periods) / 2.0))
        t = np.arange(periods * steps + 1) / (f * steps)
        phase = 2 * math.pi * f * t
        index = np.minimum((t * f).astype(int), periods - 1)
        reference = (draws[index] * np.exp(1j * phase)).imag  # P + jQ = draw, as the integrator defines them
        output = 0.5 * np.sin(phase)
        sampler = Autointegrator(f, 1.0, ("loop",), analysis, reference="effort", grid_steps_per_period=steps)
        sampler.feed(t, np.stack([output, reference], axis=1))
        if not sampler.done:
            sampler.end_of_record()
        start, stop = coherence_periods(analysis.skip_periods, sampler.periods)
        if stop - start < MIN_SCATTER_PERIODS:
            start = analysis.skip_periods
        used = draws[start:stop]
        want = float(np.sqrt(np.mean(np.abs(used - used.mean()) ** 2)) / abs(used.mean()))
        # (each period's edge sample is the next period's draw: the coefficients differ from the draws slightly)
        assert sampler.divisor_scatter() == pytest.approx(want, rel=2e-2)
        everything = draws[: sampler.periods]
        if transient:  # over every period the transient alone would have called the divisor drowned
            assert float(np.sqrt(np.mean(np.abs(everything - everything.mean()) ** 2))
                         / abs(everything.mean())) > MAX_DIVISOR_SCATTER > want
        limited = {p.status == PointStatus.DIVISOR_LIMITED for p in sampler.points()}
        assert limited == {want > MAX_DIVISOR_SCATTER}


def canopen_loop_case(measured: str) -> Any:
    """The position PID drive as a simulated CiA 402 drive in csp: the host excites the torque offset 0x60B2; the
    TPDO carries the torque demand 0x6074 (effort) and the drive's controller output 0x2002 (control)."""
    data = load_config(CONFIGS / "sim_loop.toml")
    del data["frames"]
    data["analysis"]["measured"] = measured
    data["excitation"]["frequencies_hz"] = [5.0, 17.0, 40.0]
    data["bench"] = {"transport": "canopen", "rate_hz": 1000, "clock": "lockstep", "effort_channel": "effort",
                     "control_channel": "control"}
    data["can"]["channel"] = f"loop-{uuid.uuid4().hex[:8]}"
    data["canopen"] = {"node_id": 5, "mode": "csp", "setpoint": "Torque offset", "setpoint_scale": 1e-4,
                       "heartbeat_timeout_s": 1.0, "drive_heartbeat_timeout_ms": 2000,
                       "actual": {"effort": "Torque demand", "control": "0x2002"},
                       "actual_scale": {"effort": 1e-4, "control": 1e-4}}
    data["safety"]["feedback_limits"] = {}
    data["simulator"]["noise"] = 2e-4  # two counts: the quantization of a sine repeating every period is dithered
    return parse_config(data, "loop402.toml").cases[0]


@pytest.mark.slow
def test_a_cia402_drive_excited_at_its_torque_offset_gives_its_loop_gain() -> None:
    """Over CANopen: the host holds the drive's target position where the drive stands (0x607A from 0x6064) and
    sweeps the torque offset; the loop gain and the sensitivity from the TPDO's torque demand and controller output
    are the exact ones within each point's tolerance, and within its interval (noise on both channels)."""
    plant, gains = PLANTS["position PID"]
    for measured in ("loop", "sensitivity"):
        case = canopen_loop_case(measured)
        assert case.canopen_setup.operating_point is not None
        target, held = case.canopen_setup.operating_point
        assert (target.index, held.index if held else None) == (0x607A, 0x6064)
        rate_hz = case.bench.rate_hz
        result = BenchSession(case, plan_link(case)).run()
        assert result.completed, result
        for point in result.response.points:
            want = exact(plant, gains, point.frequency_hz, 1.0 / rate_hz)[measured]
            got = complex(point.p, point.q) / point.amplitude
            assert point.converged, (measured, point)
            assert abs(got - want) <= point.tolerance_percent / 100 * abs(want), (measured, point.frequency_hz)
            assert abs(got - want) <= point.uncertainty / point.amplitude, (measured, point.frequency_hz, got, want)


def test_the_host_holds_the_target_where_the_drive_stands_while_it_excites_an_offset() -> None:
    """A csp drive excited at its torque offset: before enabling, the host reads the position actual value and
    writes it to the target position, so the drive's position loop holds where it stands (on the drive's own
    object dictionary, read back)."""
    case = canopen_loop_case("loop")
    setup = case.canopen_setup
    assert setup is not None and case.layout is not None and case.can is not None
    plan = [line for line in _case_lines(case) if "0x607A" in line]
    assert len(plan) == 1 and "SDO write 0x607A:00 = 0x6064:00 (Position actual value) as read" in plan[0]
    serving = serve_canopen(simulator_spec(case).controller(), setup,
                            {"interface": "virtual", "channel": case.can.channel})
    node = serving.drive.node
    assert node is not None
    node.sdo[0x6064].raw = 123456  # counts: the drive stands away from zero
    host = CanopenDriver(CanPort.open("virtual", case.can.channel), setup, case.layout)
    try:
        host.enable()
        assert node.sdo[0x607A].raw == 123456
        assert "operating point 0x607A:00 (Target position) = 123456 (Position actual value)" in host.start_account
        assert host.disable()
    finally:
        host.close()
        serving.close()


def test_a_loop_sweep_resumed_measures_only_the_frequencies_it_lacks(tmp_path: Path) -> None:
    """The points of a loop sweep are named by their mode ("loop"): a resumed sweep counts them as measured."""
    from bodebench.bench.events import PointStarted
    from bodebench.io.results import load_response

    gains = PLANTS["velocity PI"][1]
    first = case_of("loop", "velocity PI", gains, frequencies=(5.0, 20.0))
    assert first.analysed_channels == ("loop",)
    assert BenchSession(first, plan_link(first), out_dir=tmp_path).run().completed
    started: list[float] = []
    more = case_of("loop", "velocity PI", gains, frequencies=(5.0, 20.0, 30.0))
    result = BenchSession(more, plan_link(more), resume=load_response(tmp_path),
                          listener=lambda e: started.append(e.frequency_hz) if isinstance(e, PointStarted) else None
                          ).run()
    assert result.completed and started == [30.0]
    assert sorted(p.frequency_hz for p in result.response.points) == [5.0, 20.0, 30.0]
