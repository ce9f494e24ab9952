"""The whole instrument chain against the simulated drive: real python-can buses, real pseudo-terminals.

Each sweep over a transport must agree with the offline run of the same bench config (``bodebench simulate``:
the same controller called directly), and every way a sweep ends must leave the drive at a zero setpoint and
disabled, as seen on the bus.
"""

from __future__ import annotations

import copy
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import BusRecorder

from bodebench.bench.connection import plan_link
from bodebench.bench.events import BusStatus, PointProgress, SessionError
from bodebench.bench.session import BenchSession
from bodebench.core.response import FrequencyResponse
from bodebench.io.config import parse_config
from bodebench.io.results import load_response
from bodebench.status import PointStatus

FREQS = [5.0, 8.0, 20.0]  # below, near and above resonance (the -90 degree crossing is at 9.3 Hz)

BASE: dict[str, Any] = {
    "plant": {"model": "coulomb", "mass": 2.533e-4, "stiffness": 1.0, "friction": 0.008},
    "excitation": {"amplitude": 0.01, "frequencies_hz": FREQS},
    "analysis": {"harmonics": [1, 3], "tolerance_percent": 0.01, "fold_decay": 3},  # as configs/sim_can.toml
    "bench": {"transport": "can", "rate_hz": 1000, "clock": "lockstep", "timebase": "counter"},
    "can": {"interface": "virtual", "channel": "e2e"},
    "safety": {"max_amplitude": 0.02, "max_rate": 5.0, "watchdog_s": 5.0},  # a loaded machine may stall the link
    "simulator": {},
}

SERIAL_FRAMES = {
    "setpoint": {"id": 1, "signals": [{"name": "setpoint", "byte": 0, "type": "float32"},
                                      {"name": "counter", "byte": 4, "type": "uint16"}]},
    "feedback": [{"id": 0x81, "signals": [{"name": "position", "byte": 0, "type": "float32"},
                                          {"name": "setpoint_echo", "byte": 4, "type": "float32"},
                                          {"name": "counter", "byte": 8, "type": "uint16"},
                                          {"name": "timestamp_us", "byte": 10, "type": "uint32"}]}],
    "enable": {"id": 0x10, "data": [1]},
    "disable": {"id": 0x10, "data": [0]},
}


def config(**tables: dict[str, Any]) -> dict[str, Any]:
    data = copy.deepcopy(BASE)
    for name, value in tables.items():
        if value is None:
            data.pop(name, None)
        else:
            data[name] = {**data.get(name, {}), **value} if isinstance(value, dict) and name in data else value
    return data


def sweep(data: dict[str, Any], out: Path | None = None, direct: bool = False, listener=None) -> BenchSession:
    case = parse_config(data, "e2e.toml").cases[0]
    session = BenchSession(case, plan_link(case, direct=direct), out, listener)
    session.run()
    return session


def compare(a: FrequencyResponse, b: FrequencyResponse, gain_db: float, phase_deg: float,
            freqs: list[float] = FREQS) -> None:
    first_a, first_b = a.select(harmonic=1), b.select(harmonic=1)
    assert list(first_a.frequency_hz) == list(first_b.frequency_hz) == freqs
    assert np.max(np.abs(first_a.gain_db - first_b.gain_db)) <= gain_db
    assert np.max(np.abs(first_a.phase_deg - first_b.phase_deg)) <= phase_deg
    # each point measured to the end: converged, or alias_limited where what the rate folds onto it may exceed the
    # tolerance (harmonic 3 at 20 Hz, 50 samples a period, where it does: tests/test_benchgrid.py)
    assert all(p.converged or p.status == PointStatus.ALIAS_LIMITED for p in a.points)
    assert all(p.converged or p.status == PointStatus.ALIAS_LIMITED for p in b.points)


@pytest.fixture(scope="module")
def offline() -> FrequencyResponse:
    return sweep(config(), direct=True).response


@pytest.fixture(scope="module")
def offline_serial() -> FrequencyResponse:
    return sweep(config(bench={"transport": "serial"}, can=None, serial={"framing": "binary"},
                        frames=SERIAL_FRAMES), direct=True).response


@pytest.mark.slow
def test_virtual_can_agrees_with_the_offline_run(offline: FrequencyResponse, tmp_path: Path) -> None:
    session = sweep(config(), tmp_path)
    compare(session.response, offline, 0.05, 0.2)
    on_disk = load_response(tmp_path)
    assert len(on_disk.points) == len(session.response.points) == 2 * len(FREQS)


@pytest.mark.slow
def test_slcan_adapter_on_a_pty_agrees_with_the_offline_run() -> None:
    """python-can's slcan interface reads its adapter a byte at a time (about 1 ms a setpoint here), so this sweep
    keeps to the frequencies above and below resonance that take the fewest setpoints."""
    freqs = [8.0, 20.0]
    offline = sweep(config(excitation={"frequencies_hz": freqs}), direct=True).response
    session = sweep(config(can={"interface": "slcan", "channel": ""}, excitation={"frequencies_hz": freqs}))
    compare(session.response, offline, 0.05, 0.2, freqs)
    assert "slcan" in session.plan.where


@pytest.mark.slow
@pytest.mark.parametrize("framing", ["binary", "ascii"])
def test_serial_on_a_pty_agrees_with_the_offline_run(offline_serial: FrequencyResponse, framing: str) -> None:
    session = sweep(config(bench={"transport": "serial"}, can=None, serial={"framing": framing},
                           frames=SERIAL_FRAMES))
    compare(session.response, offline_serial, 0.05, 0.2)


@pytest.mark.slow
def test_jittered_sampling_with_timestamps_agrees() -> None:
    """Sampling instants jitter by +-5 % of the period; the controller's timestamps say when each sample was
    taken and the sampler integrates on them. Jitter is noise, so the tolerance is 0.05 % here (and noise costs
    periods, so the sweep keeps to the frequencies that take the fewest setpoints)."""
    freqs = [8.0, 20.0]
    serial: dict[str, Any] = {"can": None, "serial": {"framing": "binary"}, "frames": SERIAL_FRAMES,
                              "excitation": {"frequencies_hz": freqs}}
    offline = sweep(config(bench={"transport": "serial"}, **serial), direct=True).response
    session = sweep(config(bench={"transport": "serial", "timebase": "timestamp"}, **serial,
                           simulator={"jitter": 0.05, "seed": 11},
                           analysis={"harmonics": [1], "tolerance_percent": 0.05}))
    compare(session.response, offline, 0.05, 0.2, freqs)


@pytest.mark.slow
@pytest.mark.parametrize("pacing_cpu", [None, 0])
def test_realtime_clock_over_a_serial_pty_agrees_with_lockstep(pacing_cpu: int | None) -> None:
    """A short run on the wall clock: the drive, in its own process behind a pty, ticks at 1 kHz on its own clock;
    the worker paces setpoints on another; a busy machine may stall the line for a while (retried within the
    watchdog budget). Position over the echoed setpoint (two-channel mode) takes out what the
    unlocked clocks do to the input, so a damped linear oscillator measures as on the lockstep clock, within the
    intervals the two state."""
    tables: dict[str, Any] = {
        "excitation": {"frequencies_hz": [10.0, 20.0]},
        "analysis": {"harmonics": [1], "tolerance_percent": 0.2, "max_periods": 60},
        "bench": {"transport": "serial", "reference_channel": "setpoint_echo"},
        "can": None, "serial": {"framing": "binary"}, "frames": SERIAL_FRAMES,
    }
    data = config(**tables)
    data["plant"] = {"model": "linear", "mass": 2.533e-4, "stiffness": 1.0, "damping_ratio": 0.2}
    lockstep = sweep(data, direct=True).response
    data["bench"]["clock"] = "realtime"
    if pacing_cpu is not None:
        data["bench"]["pacing_cpu"] = pacing_cpu
    health: list[Any] = []

    def listener(event: object) -> None:
        if isinstance(event, BusStatus):
            health.append(event.health)

    realtime = sweep(data, listener=listener).response
    assert [p.frequency_hz for p in realtime.points] == [10.0, 20.0]
    for rt, ls in zip(realtime.points, lockstep.points, strict=True):
        # each agrees with the other within the 95 % intervals both state: on a quiet machine the realtime point
        # converges within 0.2 % (0.017 dB); on a busy one late setpoints cost periods and it may end capped at
        # max_periods, with an interval as wide as the load made it (1.1 dB was seen beside two CPU-bound
        # processes; in a loaded test run, once an interval that held zero), which must still hold the answer
        said = (rt.status, rt.periods, rt.coherence, rt.uncertainty, rt.uncertainty_1d, rt.magnitude)
        assert ls.within_eps, said
        if rt.converged or math.isfinite(rt.gain_db_ci):
            assert math.isfinite(rt.gain_db_ci) and rt.phase_ci_deg < 180.0, said
            assert abs(rt.gain_db - ls.gain_db) <= rt.gain_db_ci + ls.gain_db_ci, said
            assert abs(rt.phase_deg - ls.phase_deg) <= rt.phase_ci_deg + ls.phase_ci_deg, said
    assert any(math.isfinite(rt.gain_db_ci) for rt in realtime.points)
    last = health[-1]
    assert last.pacing is not None and last.pacing.count > 500  # every setpoint's send time was measured
    # what the OS granted the loop is reported; the worker keeps to the chosen CPU, by default the last one
    cpus = os.sched_getaffinity(0)
    expected = pacing_cpu if pacing_cpu is not None else (max(cpus) if len(cpus) > 1 else None)
    if expected is None:
        assert last.pacing.scheduling
    else:
        assert last.pacing.scheduling.endswith(f"CPU {expected}")
    # setpoint to its echo was measured; how fast it is, and how closely the drive kept up, depend on how busy the
    # machine is: those figures are benchmarks/bench_pacing.py's. What holds anyway: nothing was lost on the line
    assert last.round_trip_s > 0.0
    assert last.bus.frames_in > 0 and last.bus.lost_samples <= 0.01 * last.bus.frames_in


def test_abort_leaves_zero_setpoint_and_disable_on_the_bus(tmp_path: Path) -> None:
    recorder = BusRecorder("e2e-abort")
    holder: dict[str, BenchSession] = {}

    def listener(event: object) -> None:
        if isinstance(event, PointProgress) and event.index == 1 and event.periods >= 2:
            holder["s"].controls.request_abort()

    case = parse_config(config(can={"channel": "e2e-abort"}), "e2e.toml").cases[0]
    session = holder["s"] = BenchSession(case, plan_link(case), tmp_path, listener)
    with pytest.raises(SessionError, match="abort"):
        session.run()
    value, disabled = recorder.close()
    assert value == 0.0 and disabled
    # the point measured before the abort is on disk, whole
    kept = load_response(tmp_path)
    assert [p.frequency_hz for p in kept.points] == [5.0, 5.0]


def test_watchdog_trips_when_the_drive_does_not_answer() -> None:
    recorder = BusRecorder("e2e-mute")
    data = config(can={"channel": "e2e-mute"}, safety={"watchdog_s": 0.3}, simulator=None)
    with pytest.raises(SessionError, match="watchdog"):
        sweep(data)
    value, disabled = recorder.close()
    assert value == 0.0 and disabled


def test_feedback_window_trips_and_zeroes_the_drive() -> None:
    recorder = BusRecorder("e2e-window")
    data = config(can={"channel": "e2e-window"}, safety={"feedback_limits": {"position": [-0.002, 0.002]}})
    with pytest.raises(SessionError, match="feedback_limit"):
        sweep(data)
    value, disabled = recorder.close()
    assert value == 0.0 and disabled


def test_setpoints_respect_amplitude_and_rate_limits() -> None:
    """Everything the instrument sent, read off the bus: never above max_amplitude, never faster than max_rate."""
    recorder = BusRecorder("e2e-limits")
    data = config(can={"channel": "e2e-limits"}, safety={"max_amplitude": 0.0101, "max_rate": 0.55})
    data["excitation"]["frequencies_hz"] = [5.0, 8.0]
    sweep(data)
    recorder.close()
    sp = recorder.layout.setpoint
    values = np.array([sp.decode(bytes(m.data))["setpoint"] for m in recorder.frames
                       if m.arbitration_id == sp.id])
    assert np.max(np.abs(values)) <= 0.0101 * (1 + 1e-6)
    assert np.max(np.abs(np.diff(values))) <= 0.55 / 1000 * (1 + 1e-5)
    assert values[-1] == 0.0
