"""Bench configs: every impossible combination is one line naming the file and the key."""

from __future__ import annotations

import copy
import os
from typing import Any

import pytest

from bodebench.io.config import ConfigError, parse_config

GOOD: dict[str, Any] = {
    "plant": {"model": "coulomb", "mass": 2.533e-4, "stiffness": 1.0, "friction": 0.008},
    "excitation": {"amplitude": 0.01, "frequencies_hz": [2.0, 20.0]},
    "analysis": {"harmonics": [1, 3]},
    "bench": {"transport": "can", "rate_hz": 1000},
    "can": {"interface": "virtual", "channel": "x"},
    "safety": {"max_amplitude": 0.02, "max_rate": 5.0},
    "simulator": {},
}


def error(edit) -> str:
    data = copy.deepcopy(GOOD)
    edit(data)
    with pytest.raises(ConfigError) as info:
        parse_config(data, "bench.toml")
    text = str(info.value)
    assert "\n" not in text and text.startswith("bench.toml: ")
    return text


def test_the_good_config_loads() -> None:
    case = parse_config(GOOD, "bench.toml").cases[0]
    assert case.bench is not None and case.bench.rate_hz == 1000
    assert case.safety is not None and case.safety.max_amplitude == 0.02


def test_frequency_above_what_the_sample_rate_resolves() -> None:
    text = error(lambda d: d["excitation"].update(frequencies_hz=[2.0, 50.0]))
    assert "excitation.frequencies_hz[1]" in text and "harmonic 3" in text


def test_amplitude_above_the_safety_limit() -> None:
    assert "excitation.amplitude" in error(lambda d: d["excitation"].update(amplitude=0.05))


def test_sine_faster_than_the_slew_limit() -> None:
    assert "max_rate" in error(lambda d: d["safety"].update(max_rate=0.5))


def test_a_bench_needs_safety_limits() -> None:
    assert "bench.toml: safety:" in error(lambda d: d.pop("safety"))


def test_a_measured_channel_must_be_in_the_layout() -> None:
    assert "bench.output_channels" in error(lambda d: d["bench"].update(output_channels=["pressure"]))


def test_binary_serial_needs_one_byte_ids() -> None:
    def edit(d: dict[str, Any]) -> None:
        d["bench"]["transport"] = "serial"
        d.pop("can")
        d["serial"] = {}
    assert "exceeds 0xFF" in error(edit)


def test_unknown_fault_key() -> None:
    assert "simulator.faults.dorp: unknown key" in error(lambda d: d["simulator"].update(faults={"dorp": 0.1}))


def test_fault_probability_out_of_range() -> None:
    assert "simulator.faults.drop: must be <= 1" in error(lambda d: d["simulator"].update(faults={"drop": 1.5}))


def test_receive_times_on_the_lockstep_clock() -> None:
    assert "bench.timebase" in error(lambda d: d["bench"].update(timebase="receive"))


def test_feedback_window_must_be_low_high() -> None:
    assert "safety.feedback_limits" in error(lambda d: d["safety"].update(feedback_limits={"position": [1, -1]}))


def test_bench_tables_without_a_bench() -> None:
    assert "bench.toml: can: needs a [bench] table" in error(lambda d: d.pop("bench"))


def test_pacing_cpu_must_exist_on_this_machine() -> None:
    cpus = os.cpu_count() or 1
    text = error(lambda d: d["bench"].update(clock="realtime", pacing_cpu=cpus))
    assert "bench.pacing_cpu" in text and f"CPU {cpus} does not exist" in text
    assert "bench.pacing_cpu" in error(lambda d: d["bench"].update(pacing_cpu=-1))
    data = copy.deepcopy(GOOD)
    data["bench"].update(clock="realtime", pacing_cpu=cpus - 1)
    assert parse_config(data, "bench.toml").cases[0].on_bench.bench.pacing_cpu == cpus - 1


FRAMES: dict[str, Any] = {
    "setpoint": {"id": 0x201, "signals": [{"name": "setpoint", "byte": 0, "type": "float32"},
                                          {"name": "counter", "byte": 4, "type": "uint16"}]},
    "feedback": [{"id": 0x181, "signals": [{"name": "position", "byte": 0, "type": "float32"},
                                           {"name": "counter", "byte": 4, "type": "uint16"}]}],
    "enable": {"id": 0x10, "data": [1]},
    "disable": {"id": 0x10, "data": [0]},
}


def with_frames(edit) -> str:  # type: ignore[no-untyped-def]
    def apply(d: dict[str, Any]) -> None:
        d["frames"] = copy.deepcopy(FRAMES)
        edit(d["frames"])
    return error(apply)


def test_enable_and_disable_must_differ() -> None:
    text = with_frames(lambda f: f["disable"].update(data=[1]))
    assert "frames" in text and "enable and disable are the same frame (id 0x10, data 01)" in text


@pytest.mark.parametrize("bad", [["float32"], {"name": "float32"}, 3])
def test_a_signal_type_that_is_not_a_name_is_one_line(bad: object) -> None:
    text = with_frames(lambda f: f["feedback"][0]["signals"][0].update(type=bad))
    assert "frames.feedback[0].signals[0].type: one of int8" in text


def test_a_bench_frequency_below_a_millihertz_is_refused() -> None:
    text = error(lambda d: d["excitation"].update(frequencies_hz=[2e-6, 2.0]))
    assert "excitation.frequencies_hz[0]: 2e-06 Hz is below 0.001 Hz" in text


def test_negative_seeds_are_refused() -> None:
    assert "simulator.faults.seed: must be >= 0" in error(lambda d: d["simulator"].update(faults={"seed": -1}))
    assert "simulator.seed" in error(lambda d: d["simulator"].update(seed=-1))


def test_a_heartbeat_slower_than_half_the_drive_watchdog_is_refused() -> None:
    def edit(f: dict[str, Any]) -> None:
        f["heartbeat"] = {"id": 0x700, "data": [5], "period_s": 0.3}
        f["drive_watchdog_s"] = 0.5
    assert "more than half of drive_watchdog_s" in with_frames(edit)


def dbc_error(tmp_path, order: str = "1", scale: str = "0.001") -> str:  # type: ignore[no-untyped-def]
    from test_drivers import DBC_TEXT

    (tmp_path / "drive.dbc").write_text(DBC_TEXT.replace("ActPos : 0|32@1- (0.001,0)",
                                                         f"ActPos : 0|32@{order}- ({scale},0)"))
    frames = {"dbc": "drive.dbc",
              "setpoint": {"message": "SETPOINT", "signals": {"setpoint": "SetpointPos", "counter": "SeqCnt"}},
              "feedback": [{"message": "FEEDBACK1", "signals": {"position": "ActPos", "counter": "SeqCnt"}}]}
    data = copy.deepcopy(GOOD)
    data["frames"] = frames
    data["analysis"]["harmonics"] = [1]
    with pytest.raises(ConfigError) as info:
        parse_config(data, str(tmp_path / "bench.toml"))
    text = str(info.value)
    assert "\n" not in text
    return text


def test_a_dbc_signal_with_scale_zero_is_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    text = dbc_error(tmp_path, scale="0")
    assert "frames.feedback[0]" in text and "signal \"ActPos\" has scale 0" in text


def test_a_malformed_dbc_byte_order_is_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    text = dbc_error(tmp_path, order="9")
    assert "frames.dbc: drive.dbc line 14: signal \"ActPos\": @9- is not a byte order" in text


def test_the_in_process_drive_gets_a_worker_process_for_a_long_sweep_only() -> None:
    from pathlib import Path

    from bodebench.bench.procedure import LEAST_ANALYSED_PERIODS, least_setpoints
    from bodebench.io.config import load_config
    from bodebench.io.tables import SETPOINTS_FOR_A_PROCESS

    case = load_config(Path(__file__).resolve().parent.parent / "configs" / "sim_can.toml").cases[0]
    bench, excitation = case.on_bench.bench, case.excitation
    by_hand = sum(bench.rate_hz * (excitation.settle_at(f) + case.analysis.skip_periods + LEAST_ANALYSED_PERIODS) / f
                  for f in excitation.frequencies_hz)
    assert least_setpoints(case) == int(by_hand) >= SETPOINTS_FOR_A_PROCESS
    assert bench.worker == "auto" and bench.clock == "lockstep"
    assert bench.worker_mode() == "thread"  # a bus: the drive is served in the worker's own process anyway
    assert bench.worker_mode(in_process_setpoints=least_setpoints(case)) == "process"
    assert bench.worker_mode(in_process_setpoints=SETPOINTS_FOR_A_PROCESS - 1) == "thread"
    assert bench.worker_mode(beside_a_ui=True) == "process"


def _integer_setpoint(scale: float) -> Any:
    def edit(d: dict[str, Any]) -> None:
        d["frames"] = copy.deepcopy(d.get("frames") or FRAMES)
        d["frames"]["setpoint"]["signals"] = [{"name": "setpoint", "byte": 0, "type": "int16", "scale": scale},
                                              {"name": "counter", "byte": 4, "type": "uint16"}]
    return edit


def test_a_setpoint_the_frame_rounds_to_a_few_steps_is_refused_and_a_coarse_one_warned() -> None:
    """An int16 setpoint of 0.003 units a count carries an amplitude of 0.01 in 3.3 steps: a staircase; at 0.001 in
    10 steps: measured, with a warning of the harmonics the rounding adds; float32 carries it whole."""
    amplitude = GOOD["excitation"]["amplitude"]
    text = error(_integer_setpoint(0.003))
    assert f"excitation.amplitude: {amplitude:g} at " in text and "3.33 steps of the setpoint's frame" in text
    data = copy.deepcopy(GOOD)
    _integer_setpoint(0.001)(data)
    notes = parse_config(data, "bench.toml").cases[0].plan_notes
    assert any("is 10 steps of the setpoint's frame (0.001 each)" in n for n in notes), notes
    assert not any("steps of the setpoint" in n for n in parse_config(GOOD, "bench.toml").cases[0].plan_notes)
