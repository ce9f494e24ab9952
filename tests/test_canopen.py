"""CANopen (CiA 402): the power state machine, the host driver against the simulated drive on python-can's virtual
bus, and whole sweeps that end on a drive fault, each ending with the drive seen disabled on the bus.

A third node on the bus (``CanopenRecorder``) reads what went over the wire: setpoints in the RPDO, SYNC,
controlwords written over SDO, statuswords read back, NMT commands.
"""

from __future__ import annotations

import copy
import dataclasses
import time
import uuid
from pathlib import Path
from typing import Any

import can
import helpers
import numpy as np
import pytest
from helpers import FrameRecorder, sdo_values

from bodebench.bench.events import SessionError
from bodebench.bench.session import BenchSession
from bodebench.drivers.canopen_link import CanopenDriver
from bodebench.drivers.cia402 import (
    CONTROLWORD,
    Command,
    State,
    command_of,
    decode_statusword,
    next_state,
    statusword,
)
from bodebench.drivers.errors import DriveFaultError
from bodebench.drivers.ports import CanPort
from bodebench.io.config import ConfigError, parse_config
from bodebench.io.results import load_response
from bodebench.sim.canopen_device import serve_canopen
from bodebench.sim.controller import ControllerTiming, SimulatedController
from bodebench.sim.faults import CanopenFaults
from bodebench.sim.models import plant_from_config
from bodebench.status import FaultKind

NODE = 5
LAG = {"model": "lag", "time_constant": 0.02, "gain": 2.0}


def bench(channel: str, **tables: dict[str, Any]) -> dict[str, Any]:
    """A CANopen bench config: the lag plant behind the simulated drive, lockstep at 1 kHz, node 5."""
    data: dict[str, Any] = {
        "plant": dict(LAG),
        "excitation": {"amplitude": 0.01, "frequencies_hz": [5.0, 12.0]},
        "analysis": {"harmonics": [1], "tolerance_percent": 0.05},
        "bench": {"transport": "canopen", "rate_hz": 1000, "clock": "lockstep", "timebase": "counter"},
        "can": {"interface": "virtual", "channel": channel},
        "canopen": {"node_id": NODE, "mode": "csp", "setpoint_scale": 1e-9,
                    "actual": {"position": "0x6064", "counter": "Sample counter"},
                    "actual_scale": {"position": 1e-9}, "heartbeat_ms": 50, "heartbeat_timeout_s": 1.0},
        "safety": {"max_amplitude": 0.02, "watchdog_s": 3.0},
        "simulator": {},
    }
    for name, value in tables.items():
        data[name] = {**data.get(name, {}), **copy.deepcopy(value)}
    return data


def channel() -> str:
    return f"canopen-{uuid.uuid4().hex[:8]}"


def sdo_writes(frames: list[can.Message], index: int) -> list[tuple[int, int]]:
    """(frame position, value) of every expedited SDO download to ``index`` of the node (client to server)."""
    return sdo_values(frames, NODE, index)


def sdo_reads(frames: list[can.Message], index: int) -> list[tuple[int, int]]:
    """(frame position, value) of every expedited SDO upload answer from ``index`` of the node."""
    return sdo_values(frames, NODE, index, answers=True)


def assert_left_safe(frames: list[can.Message], *, answered: bool = True) -> None:
    """On the bus: the last setpoint was 0 and a SYNC applied it; then quick stop, then disable voltage, then NMT
    pre-operational; with ``answered`` the drive's last statusword reads "switch on disabled" or "fault"."""
    rpdo = [i for i, m in enumerate(frames) if m.arbitration_id == 0x200 + NODE]
    last = rpdo[-1]
    assert int.from_bytes(bytes(frames[last].data), "little", signed=True) == 0
    assert any(m.arbitration_id == 0x80 for m in frames[last:])
    controlwords = [(i, v) for i, v in sdo_writes(frames, 0x6040) if i > last]
    assert [v for _, v in controlwords] == [CONTROLWORD[Command.QUICK_STOP], CONTROLWORD[Command.DISABLE_VOLTAGE]]
    nmt = [i for i, m in enumerate(frames) if m.arbitration_id == 0 and bytes(m.data) == bytes([0x80, NODE])]
    assert nmt and nmt[-1] > controlwords[-1][0]
    if answered:
        word = sdo_reads(frames, 0x6041)[-1][1]
        assert decode_statusword(word) in (State.SWITCH_ON_DISABLED, State.FAULT)


# ------------------------------------------------------------------------------------------ the state machine


# statuswords as CiA 402 drives report them (bit 4 voltage enabled, bit 9 remote set where they apply)
REPORTED = {0x0250: State.SWITCH_ON_DISABLED, 0x0231: State.READY_TO_SWITCH_ON, 0x0233: State.SWITCHED_ON,
            0x0237: State.OPERATION_ENABLED, 0x0217: State.QUICK_STOP_ACTIVE, 0x0218: State.FAULT,
            0x021F: State.FAULT_REACTION_ACTIVE, 0x0200: State.NOT_READY, 0x0640: State.SWITCH_ON_DISABLED}


@pytest.mark.parametrize("word", sorted(REPORTED))
def test_statuswords_decode_to_their_states(word: int) -> None:
    assert decode_statusword(word) is REPORTED[word]


@pytest.mark.parametrize("state", list(State))
def test_the_drive_statusword_of_every_state_reads_back_as_that_state(state: State) -> None:
    assert decode_statusword(statusword(state)) is state
    assert decode_statusword(statusword(state, voltage=False, remote=False, warning=True)) is state


def test_controlwords_give_their_commands() -> None:
    for command in (Command.SHUTDOWN, Command.ENABLE_OPERATION, Command.QUICK_STOP, Command.DISABLE_VOLTAGE):
        assert command_of(CONTROLWORD[command]) is command
    assert command_of(0x0007) is Command.SWITCH_ON
    assert command_of(0x0080, previous=0x0000) is Command.FAULT_RESET
    assert command_of(0x0080, previous=0x0080) is Command.DISABLE_VOLTAGE  # no rising edge: bit 1 clear


def test_the_enable_and_exit_sequences_walk_the_state_machine() -> None:
    state = State.SWITCH_ON_DISABLED
    path = []
    for word in (0x06, 0x07, 0x0F, 0x02, 0x00):
        state = next_state(state, command_of(word))
        path.append(state)
    assert path == [State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE,
                    State.SWITCH_ON_DISABLED]
    # no shortcut: enable operation from switch on disabled does nothing; a fault only leaves on a fault reset
    assert next_state(State.SWITCH_ON_DISABLED, Command.ENABLE_OPERATION) is State.SWITCH_ON_DISABLED
    for command in Command:
        expected = State.SWITCH_ON_DISABLED if command is Command.FAULT_RESET else State.FAULT
        assert next_state(State.FAULT, command) is expected


# ------------------------------------------------------------------------------- the driver and the drive


def _drive_and_host(name: str, faults: CanopenFaults | None = None, **canopen: Any) -> tuple[Any, CanopenDriver]:
    case = parse_config(bench(name, canopen=canopen), "canopen.toml").cases[0]
    setup = case.canopen_setup
    assert setup is not None and case.layout is not None
    controller = SimulatedController(plant_from_config(**LAG), case.layout, ControllerTiming(1000.0))
    serving = serve_canopen(controller, setup, {"interface": "virtual", "channel": name}, faults)
    host = CanopenDriver(CanPort.open("virtual", name), setup, case.layout)
    return serving, host


def test_the_host_enables_drives_and_disables_the_simulated_drive() -> None:
    """Enable walks the drive to "operation enabled" through the states in order; each setpoint (RPDO + SYNC) is
    one control period of the plant, read back with the drive's counter; disable leaves it switch on disabled and
    pre-operational. The actual values are those of the same plant stepped directly."""
    name = channel()
    serving, host = _drive_and_host(name)
    drive = serving.drive
    try:
        host.enable()
        assert drive.state is State.OPERATION_ENABLED and drive.nmt_state == "OPERATIONAL"
        assert drive.transitions == [(State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON),
                                     (State.READY_TO_SWITCH_ON, State.SWITCHED_ON),
                                     (State.SWITCHED_ON, State.OPERATION_ENABLED)]
        assert drive.mode == 8  # cyclic synchronous position, as the host asked
        # the drive runs the mapping the host wrote over SDO: statusword, position actual, sample counter
        node = drive.node
        assert node is not None
        assert [node.sdo[0x1A00][i].raw for i in range(1, 4)] == [0x60410010, 0x60640020, 0x20000010]
        assert node.sdo[0x1600][1].raw == 0x607A0020
        setpoints = 0.01 * np.sin(2 * np.pi * np.arange(40) / 20)
        samples = []
        for k, u in enumerate(setpoints):
            host.send_setpoint(float(u), k)
            got = []
            while not got:
                got = host.receive(2.0)
            samples.extend(got)
        plant = plant_from_config(**LAG)
        expected = plant.run_held(plant.initial_state(), np.round(setpoints / 1e-9) * 1e-9, 1e-3)[:, 0]
        counters = [s.counter for s in samples]
        assert counters == list(range(counters[0], counters[0] + 40))
        np.testing.assert_allclose([s.values[0] for s in samples], expected, rtol=0, atol=1e-9)
        assert host.disable()
        assert drive.state is State.SWITCH_ON_DISABLED and drive.nmt_state == "PRE-OPERATIONAL"
        assert drive.transitions[-2:] == [(State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE),
                                          (State.QUICK_STOP_ACTIVE, State.SWITCH_ON_DISABLED)]
        assert "switch on disabled" in host.shutdown_account
    finally:
        host.close()
        serving.close()


def test_a_drive_in_fault_is_refused_unless_a_reset_is_asked_for() -> None:
    name = channel()
    serving, host = _drive_and_host(name)
    try:
        serving.drive.state = State.FAULT
        with pytest.raises(DriveFaultError, match=r"node 5 is in fault .*canopen.fault_reset"):
            host.enable()
        assert serving.drive.state is State.FAULT
    finally:
        host.close()
        serving.close()
    name = channel()
    serving, host = _drive_and_host(name, fault_reset=True)
    try:
        serving.drive.state = State.FAULT
        host.enable()
        assert serving.drive.state is State.OPERATION_ENABLED
        assert (State.FAULT, State.SWITCH_ON_DISABLED) in serving.drive.transitions
    finally:
        host.disable()
        host.close()
        serving.close()


def test_a_node_that_is_not_there_is_named_and_nothing_is_configured() -> None:
    """The host asks for node 6 where only node 5 is: no heartbeat, so the enable stops before any SDO write of
    the mapping or the state machine reaches the bus."""
    name = channel()
    recorder = FrameRecorder(name)
    serving, host = _drive_and_host(name)
    host.close()
    setup = dataclasses.replace(host.setup, node_id=6, heartbeat_timeout_s=0.3, state_timeout_s=0.3)
    host = CanopenDriver(CanPort.open("virtual", name), setup)
    try:
        with pytest.raises(DriveFaultError, match=r"node 6: no SDO answer writing producer heartbeat time"):
            host.enable()
        assert not host.disable()
        assert "not confirmed" in host.shutdown_account
    finally:
        host.close()
        serving.close()
    frames = recorder.frames_seen()
    assert not any(m.arbitration_id == 0x600 + NODE for m in frames)  # node 5 was never addressed
    assert serving.drive.transitions == [] and serving.drive.nmt_state == "PRE-OPERATIONAL"


def test_an_sdo_answer_is_waited_for_as_long_as_state_timeout_s_says() -> None:
    """canopen.state_timeout_s is the longest wait for an SDO answer, above one second too (a drive busy with its
    own start-up answers late): asked of a node that is not there, the first write is given up only after it."""
    name = channel()
    serving, host = _drive_and_host(name)
    host.close()
    setup = dataclasses.replace(host.setup, node_id=6, heartbeat_timeout_s=0.3, state_timeout_s=1.5)
    host = CanopenDriver(CanPort.open("virtual", name), setup)
    try:
        started = time.monotonic()
        with pytest.raises(DriveFaultError, match=r"node 6: no SDO answer writing producer heartbeat time"):
            host.enable()
        assert time.monotonic() - started >= 1.5
    finally:
        host.close()
        serving.close()


# --------------------------------------------------------------------------------------- whole sweeps


def run_session(data: dict[str, Any], out: Path | None = None) -> tuple[BenchSession, SessionError | None]:
    return helpers.run_session(data, "canopen.toml", out)


def test_a_drive_that_refuses_to_enable_stops_the_session_with_the_reason(tmp_path: Path) -> None:
    name = channel()
    recorder = FrameRecorder(name)
    session, error = run_session(bench(name, simulator={"canopen": {"refuse_enable": True}}), tmp_path)
    frames = recorder.frames_seen()
    assert error is not None and error.kind is FaultKind.DRIVE
    assert "did not reach 'operation enabled'" in str(error) and "switched on" in str(error)
    assert session.ended is not None and session.ended.disabled
    assert "seen disabled" in session.ended.drive_state()
    # on the bus: enable operation was asked, never granted; quick stop, disable voltage, pre-operational followed
    words = [v for _, v in sdo_writes(frames, 0x6040)]
    assert words == [0x06, 0x07, 0x0F, 0x02, 0x00]
    assert decode_statusword(sdo_reads(frames, 0x6041)[-1][1]) is State.SWITCH_ON_DISABLED
    assert frames[-1].arbitration_id == 0 or any(m.arbitration_id == 0 and bytes(m.data) == bytes([0x80, NODE])
                                                 for m in frames[-5:])
    assert not list(tmp_path.iterdir())


SLEW_LIMITS = [pytest.param({}, id="no-rate-limit"), pytest.param({"max_rate": 5.0}, id="rate-limited")]
"""Without and with a rate limit: with one, the way out slews the setpoint to zero, and on the lockstep clock each
step of the slew waits for the drive's answer, which a faulted drive does not give."""


@pytest.mark.parametrize("limits", SLEW_LIMITS)
def test_an_emcy_mid_sweep_stops_it_keeps_the_converged_points_and_leaves_the_drive_disabled(
        tmp_path: Path, limits: dict[str, float]) -> None:
    name = channel()
    recorder = FrameRecorder(name)
    # the 5 Hz point takes about 4 s of controller time (ramps and 17 periods); the EMCY comes during the 12 Hz one
    session, error = run_session(bench(name, simulator={"canopen": {"emcy_at_s": 4.8, "emcy_code": 0x2310}},
                                       safety=limits), tmp_path)
    frames = recorder.frames_seen()
    assert error is not None and error.kind is FaultKind.DRIVE
    assert "EMCY 0x2310" in str(error) and "Current" in str(error)
    emcy = [m for m in frames if m.arbitration_id == 0x80 + NODE]
    assert emcy and int.from_bytes(bytes(emcy[0].data[:2]), "little") == 0x2310
    kept = load_response(tmp_path)
    assert [p.frequency_hz for p in kept.points] == [5.0] and kept.points[0].converged
    assert_left_safe(frames)
    assert session.ended is not None and session.ended.disabled


@pytest.mark.parametrize("limits", SLEW_LIMITS)
def test_a_missed_heartbeat_is_a_drive_fault(tmp_path: Path, limits: dict[str, float]) -> None:
    name = channel()
    recorder = FrameRecorder(name)
    session, error = run_session(bench(name, canopen={"heartbeat_timeout_s": 0.4}, safety=limits,
                                       simulator={"canopen": {"heartbeat_stops_at_s": 0.5}}), tmp_path)
    frames = recorder.frames_seen()
    assert error is not None and error.kind is FaultKind.DRIVE and "no heartbeat" in str(error)
    assert_left_safe(frames)  # the drive still answers SDO: it is seen disabled
    assert session.ended is not None and session.ended.disabled


def test_a_drive_that_keeps_its_own_tpdo_mapping_is_refused_before_a_setpoint_naming_both(tmp_path: Path) -> None:
    """The drive acknowledges the mapping writes but its TPDO keeps the mapping of its EDS (none): the host reads the
    mapping back and stops before enabling, naming what it wrote and what the drive reads, rather than measure
    whatever objects the drive sends."""
    name = channel()
    recorder = FrameRecorder(name)
    session, error = run_session(bench(name, simulator={"canopen": {"fixed_tpdo_mapping": True}}), tmp_path)
    frames = recorder.frames_seen()
    assert error is not None and error.kind is FaultKind.DRIVE
    assert str(error).endswith("the drive did not take the TPDO1 (communication 0x1800, mapping 0x1A00) mapping: it "
                               "reads [], [0x6041:00 16 bit, 0x6064:00 32 bit, 0x2000:00 16 bit] was written (a fixed "
                               "mapping of the drive's own: map the objects it has, or change it in the drive)"), error
    setpoints = [int.from_bytes(bytes(m.data), "little", signed=True) for m in frames
                 if m.arbitration_id == 0x200 + NODE]
    assert set(setpoints) <= {0}  # the way out's zeros only
    assert 0x0F not in [v for _, v in sdo_writes(frames, 0x6040)]  # never told to enable operation
    assert session.ended is not None and session.ended.disabled


def test_a_silent_drive_is_a_fault_and_the_session_says_it_was_not_seen_disabled(tmp_path: Path) -> None:
    name = channel()
    recorder = FrameRecorder(name)
    session, error = run_session(bench(name, canopen={"heartbeat_timeout_s": 0.4, "state_timeout_s": 0.3},
                                       simulator={"canopen": {"silent_at_s": 0.5}}), tmp_path)
    frames = recorder.frames_seen()
    assert error is not None and error.kind is FaultKind.DRIVE and "no heartbeat" in str(error)
    assert_left_safe(frames, answered=False)  # everything was still sent
    assert session.ended is not None and not session.ended.disabled
    assert "NOT seen disabled" in session.ended.drive_state() and "not confirmed" in session.ended.drive_state()


# ------------------------------------------------------------------------------------------ configuration


@pytest.mark.parametrize(("change", "message"), [
    ({"canopen": {"velocity": 3}}, r"canopen\.velocity: unknown key"),
    ({"canopen": {"node_id": 128}}, r"canopen\.node_id: .*127"),
    ({"canopen": {"setpoint": "0x6099"}}, r"canopen\.setpoint: .*no object 0x6099"),
    ({"canopen": {"actual": {"position": "Position demand"}}}, r"canopen\.actual\.position: .*no object of that name"),
    ({"canopen": {"actual": {"position": "0x6064", "counter": "0x6064"}}}, r"canopen\.actual\.counter: .*UNSIGNED"),
    ({"canopen": {"actual": {"position": "0x6064", "velocity": "0x606C", "counter": "0x2000"}}},
     r"canopen\.actual: .*12 bytes"),
    ({"canopen": {"actual_scale": {"velocity": 2.0}}}, r"canopen\.actual_scale: velocity: not a channel"),
    ({"canopen": {"heartbeat_ms": 500, "heartbeat_timeout_s": 0.4}}, r"canopen\.heartbeat_timeout_s: .*longer"),
    ({"canopen": {"eds": "missing.eds"}}, r"canopen\.eds: cannot read the EDS"),
    ({"canopen": {"mode": "pp"}}, r"canopen\.mode: "),
    ({"frames": {"drive_watchdog_s": 1.0}}, r"frames: not used on transport canopen"),
])
def test_canopen_config_errors_name_the_key(change: dict[str, Any], message: str) -> None:
    data = bench("cfg")
    for table, value in change.items():
        data[table] = {**data.get(table, {}), **value}
    with pytest.raises(ConfigError, match=message) as info:
        parse_config(data, "canopen.toml")
    assert str(info.value).startswith("canopen.toml: ") and "\n" not in str(info.value)


def test_a_real_drive_needs_its_eds_and_a_counter_for_the_counter_timebase() -> None:
    data = bench("cfg")
    del data["simulator"]
    data["can"]["channel"] = "can0"
    with pytest.raises(ConfigError, match=r"canopen\.eds: missing"):
        parse_config(data, "canopen.toml")
    data = bench("cfg", canopen={"actual": {"position": "0x6064"}})
    with pytest.raises(ConfigError, match=r"bench\.timebase: counter: .*canopen\.actual\.counter"):
        parse_config(data, "canopen.toml")
