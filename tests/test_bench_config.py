"""Bench configs: every impossible combination is one line naming the file and the key."""

from __future__ import annotations

import copy
import os
from typing import Any

import pytest

from instrument.config import ConfigError, parse_config

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
    assert case.tables["bench"].rate_hz == 1000 and case.tables["safety"].max_amplitude == 0.02


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
    assert "simulator.faults: dorp: unknown key" in error(lambda d: d["simulator"].update(faults={"dorp": 0.1}))


def test_fault_probability_out_of_range() -> None:
    assert "simulator.faults: drop" in error(lambda d: d["simulator"].update(faults={"drop": 1.5}))


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
    assert parse_config(data, "bench.toml").cases[0].tables["bench"].pacing_cpu == cpus - 1
