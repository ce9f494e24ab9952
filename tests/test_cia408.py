"""CiA 408 fluid-power devices: the device state machine, the profile's configuration, and the host driver against
the simulated valve on python-can's virtual bus: whole sweeps against the exact sampled response of the valve, and
each way a 408 device can refuse or stop a sweep (hardware enable input missing, ACTIVE refused, an EMCY, a lost
host), each ending with the device seen DISABLED on the bus (read back by a third node that records every frame).

The facts checked come from the profile (CiA 408 as summarised in the project's notes): control word bits D, H, M, R
(0x1, 0x2, 0x4, reset on the rising edge of 0x8), status word low nibble DISABLED 1001, HOLD 1011, ACTIVE 1111,
FAULT_REACTION 0111, FAULT_HOLD 0011, FAULT_DISABLED 0001; the spool set point 0x6300:1 counts 16384 for 100 %.
"""

from __future__ import annotations

import copy
import math
import time
import uuid
from pathlib import Path
from typing import Any

import can
import helpers
import numpy as np
import pytest
from helpers import FrameRecorder, sdo_values
from scipy.signal import cont2discrete

from bodebench.bench.connection import plan_link
from bodebench.bench.events import SessionError
from bodebench.bench.session import BenchSession
from bodebench.drivers import cia408
from bodebench.drivers.canopen_link import CanopenDriver
from bodebench.drivers.cia408 import State, decode_statusword, next_state, statusword
from bodebench.drivers.errors import DriveFaultError
from bodebench.drivers.ports import CanPort
from bodebench.io.config import SIMULATED_DRIVE_EDS, ConfigError, load_config, parse_config
from bodebench.io.results import load_response
from bodebench.sim.canopen_device import serve_canopen
from bodebench.sim.controller import ControllerTiming, SimulatedController
from bodebench.sim.models import plant_from_config
from bodebench.status import FaultKind

ROOT = Path(__file__).resolve().parents[1]
VALVE_CONFIG = ROOT / "configs" / "sim_cia408_valve.toml"
NODE = 8
VALVE = {"model": "valve", "valve_natural_frequency_hz": 60.0, "valve_damping_ratio": 0.6}


def channel() -> str:
    return f"cia408-{uuid.uuid4().hex[:8]}"


def bench(name: str, **tables: dict[str, Any]) -> dict[str, Any]:
    """A CiA 408 bench config: the valve behind the simulated device, lockstep at 1 kHz, node 8, spool mode."""
    data: dict[str, Any] = {
        "plant": dict(VALVE),
        "excitation": {"amplitude": 10.0, "frequencies_hz": [5.0, 45.0]},
        "analysis": {"harmonics": [1], "tolerance_percent": 0.1},
        "bench": {"transport": "canopen", "rate_hz": 1000, "clock": "lockstep", "output_channels": ["spool"]},
        "can": {"interface": "virtual", "channel": name},
        "canopen": {"node_id": NODE, "profile": "408", "heartbeat_ms": 50, "heartbeat_timeout_s": 1.0,
                    "drive_heartbeat_timeout_ms": 2000},
        "safety": {"max_amplitude": 20.0, "watchdog_s": 3.0},
        "simulator": {},
    }
    for table, value in tables.items():
        data[table] = {**data.get(table, {}), **copy.deepcopy(value)}
    return data


def sdo_writes(frames: list[can.Message], index: int) -> list[tuple[int, int]]:
    """(frame position, value) of every expedited SDO download to ``index`` of the node (client to server)."""
    return sdo_values(frames, NODE, index)


def sdo_reads(frames: list[can.Message], index: int) -> list[tuple[int, int]]:
    """(frame position, value) of every expedited SDO upload answer from ``index`` of the node."""
    return sdo_values(frames, NODE, index, answers=True)


def assert_left_disabled(frames: list[can.Message], *, safe: tuple[State, ...] = (State.DISABLED,)) -> None:
    """On the bus: the last set point was 0 and a SYNC applied it; then control words HOLD, DISABLED, 0; then NMT
    pre-operational; the device's last status word reads one of ``safe``."""
    rpdo = [i for i, m in enumerate(frames) if m.arbitration_id == 0x200 + NODE]
    if rpdo:
        last = rpdo[-1]
        assert int.from_bytes(bytes(frames[last].data), "little", signed=True) == 0
        assert any(m.arbitration_id == 0x80 for m in frames[last:])
    else:
        last = -1
    words = [(i, v) for i, v in sdo_writes(frames, 0x6040) if i > last]
    assert [v for _, v in words][-3:] == [0x0003, 0x0001, 0x0000]
    nmt = [i for i, m in enumerate(frames) if m.arbitration_id == 0 and bytes(m.data) == bytes([0x80, NODE])]
    assert nmt and nmt[-1] > words[-1][0]
    assert decode_statusword(sdo_reads(frames, 0x6041)[-1][1]) in safe


def exact_valve(frequency_hz: np.ndarray, h: float = 1e-3) -> np.ndarray:
    """The valve's response as the lockstep bench samples it: the continuous second-order spool loop under a
    set point held over each period h (zero-order hold, from scipy), read at the end of the period."""
    w, z = 2 * math.pi * VALVE["valve_natural_frequency_hz"], VALVE["valve_damping_ratio"]
    a = np.array([[0.0, 1.0], [-w * w, -2 * z * w]])
    ad, bd, cd, _, _ = cont2discrete((a, np.array([[0.0], [w * w]]), np.array([[1.0, 0.0]]), np.zeros((1, 1))), h,
                                     "zoh")
    out = []
    for f in np.atleast_1d(frequency_hz):
        zz = np.exp(2j * math.pi * f * h)
        out.append((cd @ np.linalg.solve(zz * np.eye(2) - ad, bd))[0, 0])
    return np.array(out)


# ------------------------------------------------------------------------------------------ the state machine


def test_each_state_reads_back_from_its_status_word() -> None:
    nibbles = {State.NOT_READY: 0b0000, State.INIT: 0b1000, State.DISABLED: 0b1001, State.HOLD: 0b1011,
               State.ACTIVE: 0b1111, State.FAULT_REACTION: 0b0111, State.FAULT_HOLD: 0b0011,
               State.FAULT_DISABLED: 0b0001}
    for state, nibble in nibbles.items():
        assert statusword(state) & 0x0F == nibble
        assert decode_statusword(statusword(state)) is state
        assert decode_statusword(nibble | 0x0610) is state  # bits above the nibble say nothing of the state
    for undefined in set(range(16)) - set(nibbles.values()):
        assert decode_statusword(undefined) is None


@pytest.mark.parametrize(("state", "word", "expected"), [
    (State.DISABLED, 0x0001, State.DISABLED),
    (State.DISABLED, 0x0003, State.HOLD),
    (State.DISABLED, 0x0007, State.ACTIVE),
    (State.HOLD, 0x0007, State.ACTIVE),
    (State.ACTIVE, 0x0003, State.HOLD),     # bit 2 cleared leaves ACTIVE
    (State.ACTIVE, 0x0001, State.DISABLED),  # bits 1 and 2 cleared
    (State.HOLD, 0x0001, State.DISABLED),
    (State.HOLD, 0x0000, State.DISABLED),    # no bit: the fail-safe
    (State.ACTIVE, 0x0000, State.DISABLED),
])
def test_the_control_word_bits_ask_for_a_state(state: State, word: int, expected: State) -> None:
    assert next_state(state, word) is expected


def test_hold_and_active_need_the_hardware_enable_input() -> None:
    for word in (0x0003, 0x0007):
        assert next_state(State.DISABLED, word, enable_input=False) is State.DISABLED
        assert next_state(State.ACTIVE, word, enable_input=False) is State.DISABLED


def test_a_fault_is_left_only_on_the_rising_edge_of_the_reset_bit() -> None:
    for fault in (State.FAULT_HOLD, State.FAULT_DISABLED):
        for word in (0x0000, 0x0001, 0x0003, 0x0007):
            assert next_state(fault, word) is fault
        assert next_state(fault, 0x0008, previous=0x0000) is State.DISABLED
        assert next_state(fault, 0x0008, previous=0x0008) is fault  # held high: no edge
    assert next_state(State.FAULT_REACTION, 0x0008) is State.FAULT_REACTION  # the reaction runs to its end


# ------------------------------------------------------------------------------------------ configuration


def test_the_408_defaults_are_the_spool_process_values_in_percent() -> None:
    case = parse_config(bench(channel()), "valve.toml").cases[0]
    setup = case.canopen_setup
    assert setup is not None and setup.profile == "408" and setup.mode == "spool"
    assert (setup.setpoint.index, setup.setpoint.subindex, setup.setpoint.type) == (0x6300, 1, "int16")
    [(name, ref, scale)] = setup.actual
    assert (name, ref.index, ref.subindex) == ("spool", 0x6301, 1)
    assert setup.setpoint_scale == scale == 100 / 16384  # 16384 increments are 100 %
    assert setup.assumed == ((0x6311, 1, 16384, "spool position reference value"),)
    assert setup.eds.endswith("cia408_sim.eds")


def test_axis_position_is_scaled_by_the_prefix_of_its_record() -> None:
    data = bench(channel(), canopen={"mode": "position"}, bench={"output_channels": ["position"]})
    setup = parse_config(data, "axis.toml").cases[0].canopen_setup
    assert setup is not None
    assert (setup.setpoint.index, setup.setpoint.type) == (0x6600, "int32")
    assert [(n, r.index) for n, r, _ in setup.actual] == [("position", 0x6601)]
    assert setup.setpoint_scale == setup.actual[0][2] == pytest.approx(1e-6)  # prefix -6 in the shipped EDS
    given = bench(channel(), canopen={"mode": "position", "setpoint_scale": 1e-3, "actual_scale": {"position": 2e-3}},
                  bench={"output_channels": ["position"]})
    setup = parse_config(given, "axis.toml").cases[0].canopen_setup
    assert setup is not None and setup.setpoint_scale == 1e-3 and setup.actual[0][2] == 2e-3
    assert setup.assumed == ()  # scales given: nothing to check on the device


@pytest.mark.parametrize(("change", "message"), [
    ({"canopen": {"mode": "csp"}}, r'valve.toml: canopen.mode: "csp" is not a CiA 408 mode .*spool'),
    ({"canopen": {"profile": "408", "mode": "spool", "eds": str(SIMULATED_DRIVE_EDS)}},
     r"valve.toml: canopen.eds: the EDS has no device mode \(0x6042\): not a CiA 408 device"),
    ({"canopen": {"profile": "409"}}, r'valve.toml: canopen.profile: must be one of "402", "408"'),
])
def test_config_errors_name_the_key(change: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        parse_config(bench(channel(), **change), "valve.toml")
    assert "\n" not in str(info.value)


def test_pressure_flow_control_sweeps_the_pressure_set_point() -> None:
    data = bench(channel(), canopen={"mode": "pq"}, bench={"output_channels": ["pressure"]})
    setup = parse_config(data, "pq.toml").cases[0].canopen_setup
    assert setup is not None and setup.device_profile.modes[setup.mode] == 5
    assert (setup.setpoint.index, setup.setpoint.subindex) == (0x6380, 1)
    assert [(n, r.index, r.subindex) for n, r, _ in setup.actual] == [("pressure", 0x6381, 1)]
    assert setup.setpoint_scale == 1.0  # prefix 0 in the shipped EDS


def test_a_402_mode_on_a_402_drive_still_loads() -> None:
    data = bench(channel(), canopen={"profile": "402", "mode": "", "eds": str(SIMULATED_DRIVE_EDS),
                                     "setpoint_scale": 1e-9},
                 bench={"output_channels": ["position"]})
    data["plant"] = {"model": "lag"}
    data["excitation"]["amplitude"] = 0.01
    setup = parse_config(data, "drive.toml").cases[0].canopen_setup
    assert setup is not None and setup.mode == "csp" and setup.setpoint.index == 0x607A


# ------------------------------------------------------------------------------- the driver and the device


def _device_and_host(name: str, faults: Any = None, **canopen: Any) -> tuple[Any, CanopenDriver]:
    case = parse_config(bench(name, canopen=canopen), "valve.toml").cases[0]
    setup = case.canopen_setup
    assert setup is not None and case.layout is not None
    controller = SimulatedController(plant_from_config(**VALVE), case.layout, ControllerTiming(1000.0))
    serving = serve_canopen(controller, setup, {"interface": "virtual", "channel": name}, faults)
    return serving, CanopenDriver(CanPort.open("virtual", name), setup, case.layout)


def test_the_host_walks_the_device_to_active_and_back_to_disabled() -> None:
    """DISABLED -> HOLD -> ACTIVE in that order with device mode 1 and control mode 2 read back; set points act only
    in ACTIVE, each one control period of the valve, read back as the plant stepped directly gives them; the exit
    leaves it DISABLED (HOLD, DISABLED, no bit) and pre-operational."""
    name = channel()
    serving, host = _device_and_host(name)
    device = serving.drive
    try:
        assert device.state is State.DISABLED
        host.enable()
        assert device.state is State.ACTIVE and device.device_mode == 1 and device.control_mode == 2
        assert device.transitions == [(State.DISABLED, State.HOLD), (State.HOLD, State.ACTIVE)]
        assert device.node.sdo[0x1600][1].raw == 0x63000110  # the RPDO maps 0x6300:1, 16 bits
        assert [device.node.sdo[0x1A00][i].raw for i in (1, 2)] == [0x60410010, 0x63010110]
        setpoints = 10.0 * np.sin(2 * np.pi * np.arange(50) / 25)
        samples = []
        for k, u in enumerate(setpoints):
            host.send_setpoint(float(u), k)
            got: list[Any] = []
            while not got:
                got = host.receive(2.0)
            samples.extend(got)
        counts = np.round(setpoints / (100 / 16384))
        plant = plant_from_config(**VALVE)
        expected = plant.run_held(plant.initial_state(), counts * (100 / 16384), 1e-3)[:, 0]
        got_values = np.array([s.values[0] for s in samples])
        np.testing.assert_allclose(got_values, np.round(expected / (100 / 16384)) * (100 / 16384), rtol=0,
                                   atol=1e-12)
        assert host.disable()
        assert device.state is State.DISABLED and device.nmt_state == "PRE-OPERATIONAL"
        assert device.transitions[-2:] == [(State.ACTIVE, State.HOLD), (State.HOLD, State.DISABLED)]
        assert "DISABLED (controlword 0x0001): statusword 0x0009 (DISABLED)" in host.shutdown_account
        assert "own fault reaction" in host.protection and "0x6007" not in host.protection
    finally:
        host.close()
        serving.close()


def test_a_device_whose_reference_value_differs_from_its_eds_is_refused_before_it_moves() -> None:
    name = channel()
    serving, host = _device_and_host(name)
    try:
        serving.drive.node.sdo[0x6311][1].raw = 10000  # the device was set up for 10000 increments = 100 %
        with pytest.raises(DriveFaultError, match=r"0x6311:01 reads 10000 on the device, the scales assumed 16384"):
            host.enable()
        assert serving.drive.transitions == []
    finally:
        host.close()
        serving.close()


def test_a_device_in_fault_is_refused_or_reset_by_the_edge_of_bit_3() -> None:
    name = channel()
    serving, host = _device_and_host(name)
    try:
        serving.drive.state = State.FAULT_HOLD
        with pytest.raises(DriveFaultError, match=r"node 8 is in fault .*FAULT_HOLD.*canopen.fault_reset"):
            host.enable()
    finally:
        host.close()
        serving.close()
    name = channel()
    recorder = FrameRecorder(name)
    serving, host = _device_and_host(name, fault_reset=True)
    try:
        serving.drive.state = State.FAULT_DISABLED
        host.enable()
        assert serving.drive.state is State.ACTIVE
        assert (State.FAULT_DISABLED, State.DISABLED) in serving.drive.transitions
    finally:
        host.disable()
        host.close()
        serving.close()
    words = [v for _, v in sdo_writes(recorder.frames_seen(), 0x6040)]
    assert words[:5] == [0x0000, 0x0008, 0x0001, 0x0003, 0x0007]


# --------------------------------------------------------------------------------------- whole sweeps


def run_session(data: dict[str, Any], out: Path | None = None) -> tuple[BenchSession, SessionError | None]:
    return helpers.run_session(data, "valve.toml", out)


def test_a_sweep_of_the_shipped_valve_config_is_within_its_tolerance_of_the_exact_response(tmp_path: Path) -> None:
    """``configs/sim_cia408_valve.toml`` on the virtual bus: every point converged and within the tolerance of the
    valve's exact sampled response; the device is left DISABLED."""
    name = channel()
    config = load_config(VALVE_CONFIG).cases[0]
    data = bench(name, excitation={"frequencies_hz": list(config.excitation.frequencies_hz)})
    recorder = FrameRecorder(name)
    session, error = run_session(data, tmp_path)
    assert error is None, error
    response = load_response(tmp_path)
    frequencies = np.array([p.frequency_hz for p in response.points])
    assert list(frequencies) == list(config.excitation.frequencies_hz)
    measured = np.array([p.gain * np.exp(1j * math.radians(p.phase_deg)) for p in response.points])
    exact = exact_valve(frequencies)
    assert all(p.converged for p in response.points)
    assert np.all(np.abs(measured / exact - 1) <= config.analysis.tolerance_percent / 100), np.abs(measured / exact - 1)
    assert_left_disabled(recorder.frames_seen())
    assert session.ended is not None and session.ended.disabled


def test_without_the_hardware_enable_input_the_sweep_says_so_and_the_device_stays_disabled(tmp_path: Path) -> None:
    name = channel()
    recorder = FrameRecorder(name)
    session, error = run_session(bench(name, simulator={"canopen": {"enable_input": False}}), tmp_path)
    assert error is not None and error.kind is FaultKind.DRIVE
    assert "did not reach 'HOLD'" in str(error) and "hardware enable input" in str(error)
    frames = recorder.frames_seen()
    setpoints = [int.from_bytes(bytes(m.data), "little", signed=True) for m in frames
                 if m.arbitration_id == 0x200 + NODE]
    assert setpoints and set(setpoints) == {0}  # the exit's zero set points only: the sweep never started
    assert_left_disabled(frames)
    assert session.ended is not None and session.ended.disabled


def test_a_device_that_refuses_active_is_taken_back_to_disabled(tmp_path: Path) -> None:
    name = channel()
    recorder = FrameRecorder(name)
    session, error = run_session(bench(name, simulator={"canopen": {"refuse_enable": True}}), tmp_path)
    assert error is not None and "did not reach 'ACTIVE'" in str(error) and "(HOLD)" in str(error)
    frames = recorder.frames_seen()
    assert [v for _, v in sdo_writes(frames, 0x6040)] == [0x0001, 0x0003, 0x0007, 0x0003, 0x0001, 0x0000]
    assert_left_disabled(frames)


def test_an_emcy_mid_sweep_keeps_the_converged_point_and_the_device_ends_fault_disabled(tmp_path: Path) -> None:
    name = channel()
    recorder = FrameRecorder(name)
    # the 9 Hz point ends near 2.5 s of controller time, the 2 Hz one takes about 9 s more: the EMCY comes during
    # it, seconds from its ends (where a point ends depends on how far ahead of the analysis the host keeps the
    # device, and on the replies a busy host misses)
    session, error = run_session(bench(name, excitation={"frequencies_hz": [9.0, 2.0]},
                                       simulator={"canopen": {"emcy_at_s": 4.8, "emcy_code": 0x5000}}), tmp_path)
    frames = recorder.frames_seen()
    assert error is not None and error.kind is FaultKind.DRIVE and "EMCY 0x5000" in str(error)
    emcy = [m for m in frames if m.arbitration_id == 0x80 + NODE]
    assert emcy and int.from_bytes(bytes(emcy[0].data[:2]), "little") == 0x5000
    kept = load_response(tmp_path)
    assert [p.frequency_hz for p in kept.points] == [9.0] and kept.points[0].converged
    assert_left_disabled(frames, safe=(State.FAULT_DISABLED,))
    assert session.ended is not None and session.ended.disabled
    assert "FAULT_DISABLED" in session.ended.drive_state()


def test_a_host_that_falls_silent_puts_the_device_in_fault_disabled() -> None:
    """The host's heartbeat stops (as when its process dies) and it sends nothing more: within the consumer time
    the device sends EMCY 0x8130 and goes FAULT_REACTION, FAULT_DISABLED, its input zeroed, with no SYNC to wake
    it."""
    name = channel()
    recorder = FrameRecorder(name)
    # a consumer time 20 host heartbeats long: a busy machine may hold the heartbeat's thread back for 250 ms
    serving, host = _device_and_host(name, host_heartbeat_ms=50, drive_heartbeat_timeout_ms=1000)
    device = serving.drive
    try:
        host.enable()
        assert device.state is State.ACTIVE and device.consumers == {1: (127, 1.0)}
        for k in range(20):
            host.send_setpoint(5.0, k)
            host.receive(1.0)
        host.port.bus.stop_all_periodic_tasks()
        stopped = time.monotonic()
        while device.heartbeat_events == 0 and time.monotonic() - stopped < 5:
            time.sleep(0.01)
        assert device.heartbeat_events == 1 and device.state is State.FAULT_DISABLED
        assert device.transitions[-2:] == [(State.ACTIVE, State.FAULT_REACTION),
                                           (State.FAULT_REACTION, State.FAULT_DISABLED)]
        assert device.controller.setpoint == 0.0 and not device.controller.enabled
        assert not host.disable() or device.state is State.FAULT_DISABLED
        assert "lost-host settings: consumer heartbeat time 0x1016:01 = 0x00000000 restored" in host.shutdown_account
    finally:
        host.close()
        serving.close()
    emcy = [m for m in recorder.frames_seen() if m.arbitration_id == 0x80 + NODE]
    assert [int.from_bytes(bytes(m.data[:2]), "little") for m in emcy][:1] == [0x8130]
    assert {State.FAULT_DISABLED} <= cia408.FAULT_STATES


def test_a_hydraulic_axis_in_position_control_on_the_bus_agrees_with_the_same_plant_run_in_process(
        tmp_path: Path) -> None:
    """Control mode 9 (axis position) on the electrohydraulic drive: set point 0x6600:1 and actual 0x6601:1 in um
    (prefix -6 of the records), swept over the virtual bus and in-process (``bodebench simulate``'s direct link):
    the same points within each other's tolerance."""
    name = channel()
    data = bench(name, canopen={"mode": "position"}, bench={"output_channels": ["position"]},
                 excitation={"amplitude": 0.001, "frequencies_hz": [2.0, 8.0]},
                 analysis={"tolerance_percent": 0.5}, safety={"max_amplitude": 0.002})
    data["plant"] = {"model": "hydraulic"}
    case = parse_config(data, "axis.toml").cases[0]
    results = []
    for direct, out in ((False, tmp_path / "bus"), (True, tmp_path / "direct")):
        session = BenchSession(case, plan_link(case, direct=direct), out)
        session.run()
        results.append(load_response(out))
    bus, direct = ([p.gain * np.exp(1j * math.radians(p.phase_deg)) for p in r.points] for r in results)
    assert all(p.converged for r in results for p in r.points)
    np.testing.assert_allclose(bus, direct, rtol=case.analysis.tolerance_percent / 100)
