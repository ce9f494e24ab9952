"""On the realtime clock the host's send times and the drive's counter are two clocks; the drive's setpoint echo
dates the sine on the drive's own clock (drivers/PROTOCOL.md section 7), so the host's latency never enters a
single-channel result, and a drive without an echo says its phase is untied instead of claiming converged."""

from __future__ import annotations

import copy
import math
import uuid
from typing import Any

import pytest
from test_bench_e2e import SERIAL_FRAMES, config, sweep

from bodebench.bench.session import sine_dating
from bodebench.io.config import parse_config
from bodebench.status import PointStatus

PLANT = {"model": "linear", "mass": 2.533e-4, "stiffness": 1.0, "damping_ratio": 0.2}
TABLES: dict[str, Any] = {
    "excitation": {"frequencies_hz": [10.0, 20.0]},
    "analysis": {"harmonics": [1], "tolerance_percent": 0.2, "max_periods": 60},
    "bench": {"transport": "serial"},
    "can": None, "serial": {"framing": "binary"}, "frames": SERIAL_FRAMES,
}


def bench(**changes: Any) -> Any:
    data = config(**TABLES)
    data["plant"] = PLANT
    data["bench"].update(changes)
    return parse_config(data, "dating.toml").cases[0].bench


@pytest.mark.parametrize("changes, channels, expected", [
    ({}, ("position", "setpoint_echo"), ("", 0.0, False)),  # lockstep: the counter is the host's tick
    ({"clock": "realtime"}, ("position", "setpoint_echo"), ("setpoint_echo", -2 * math.pi * 10.0 / 1000, False)),
    ({"clock": "realtime", "reference_channel": "setpoint_echo"}, ("position", "setpoint_echo"),
     ("setpoint_echo", 0.0, False)),  # two-channel mode as asked: its reference has phase zero
    ({"clock": "realtime"}, ("position",), ("", 0.0, True)),
])
def test_the_sine_is_dated_by_the_drive_where_the_clocks_are_two(changes: dict[str, Any], channels: tuple[str, ...],
                                                                 expected: tuple[str, float, bool]) -> None:
    assert sine_dating(bench(**changes), channels, 10.0) == pytest.approx(expected)


CAN_FRAMES: dict[str, Any] = {
    "setpoint": {"id": 0x201, "signals": [{"name": "setpoint", "byte": 0, "type": "float32"},
                                          {"name": "counter", "byte": 4, "type": "uint16"}]},
    "feedback": [{"id": 0x181, "signals": [{"name": "position", "byte": 0, "type": "float32"},
                                           {"name": "counter", "byte": 4, "type": "uint16"}]},
                 {"id": 0x182, "signals": [{"name": "setpoint_echo", "byte": 0, "type": "float32"},
                                           {"name": "counter", "byte": 4, "type": "uint16"}]}],
    "enable": {"id": 0x10, "data": [1]},
    "disable": {"id": 0x10, "data": [0]},
}


@pytest.mark.slow
def test_a_late_host_does_not_move_the_realtime_phase_and_a_drive_without_echo_is_untied() -> None:
    """The drive's frames reach the host 3 ms late (a slow USB adapter, a busy host), on python-can's virtual bus:
    on the realtime clock the single-channel result agrees with the lockstep one within the intervals both state;
    3 ms is 10.8 degrees at 10 Hz, far outside them, which is what dating by the host's clock put into the phase."""
    data = config(excitation={"frequencies_hz": [10.0, 20.0]},
                  analysis={"harmonics": [1], "tolerance_percent": 0.2, "max_periods": 60},
                  can={"channel": f"dating-{uuid.uuid4().hex[:8]}"}, frames=CAN_FRAMES)
    data["plant"] = PLANT
    lockstep = sweep(copy.deepcopy(data), direct=True).response
    data["bench"].update(clock="realtime", worker="thread")
    data["simulator"] = {"faults": {"delay_s": 0.003}}
    realtime = sweep(copy.deepcopy(data)).response
    for rt, ls in zip(realtime.points, lockstep.points, strict=True):
        assert ls.within_eps and math.isfinite(rt.gain_db_ci) and rt.phase_ci_deg < 180.0
        assert abs(rt.gain_db - ls.gain_db) <= rt.gain_db_ci + ls.gain_db_ci
        assert abs(rt.phase_deg - ls.phase_deg) <= rt.phase_ci_deg + ls.phase_ci_deg
        assert rt.phase_ci_deg + ls.phase_ci_deg < 360 * rt.frequency_hz * 0.003 / 3
    # the same drive without an echo in its frames: measured, but its phase holds the host's latency: untied
    data["frames"] = {**CAN_FRAMES, "feedback": CAN_FRAMES["feedback"][:1]}
    data["excitation"]["frequencies_hz"] = [10.0]
    (point,) = sweep(data).response.points
    assert point.status == PointStatus.UNTIED and not point.converged and not point.within_eps
