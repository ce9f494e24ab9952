"""A CANopen drive protects itself from a lost host: the host produces a heartbeat of its own and, before enabling,
writes the drive's heartbeat consumer time (0x1016) and abort connection option code (0x6007), and writes both back
on exit. The simulated CiA 402 drive honours them: a host that dies (kill -9) leaves it quick-stopped, not in
"operation enabled". Numbers and states are the drive's own: its printed events, its object dictionary, and what it
answers over SDO.
"""

from __future__ import annotations

import logging
import os
import random
import re
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import can
import canopen
import pytest
from helpers import FrameRecorder
from test_canopen import LAG, NODE, bench, channel, run_session, sdo_writes
from test_cli_bench import command

from bodebench.bench.connection import plan_link
from bodebench.bench.events import PointProgress
from bodebench.bench.session import BenchSession
from bodebench.drivers.canopen_link import CanopenDriver
from bodebench.drivers.cia402 import State, decode_statusword
from bodebench.drivers.ports import CanPort
from bodebench.io.config import SIMULATED_DRIVE_EDS, ConfigError, parse_config
from bodebench.sim.canopen_device import serve_canopen
from bodebench.sim.controller import ControllerTiming, SimulatedController
from bodebench.sim.models import plant_from_config

ROOT = Path(__file__).resolve().parents[1]
HOST = 127  # the default host_node_id
STATES = tuple(str(s) for s in State)


def _state_of(event: str) -> str | None:
    """The state an event of the drive's log enters ("quick stop active (heartbeat ...)"), None for other events."""
    return next((s for s in STATES if event.startswith(s + " (")), None)


def _drive_events(lines: list[str]) -> list[str]:
    return [line.split(" s  drive ", 1)[1].rstrip() for line in lines if " s  drive " in line]


# --------------------------------------------------------------------------------------- kill -9 of the host


def _multicast_delivers(group: str) -> bool:
    """True when python-can's udp_multicast carries a frame from one bus to another on this machine (a time to live
    of 0: the frames never leave the host)."""
    try:
        sender = can.Bus(interface="udp_multicast", channel=group, hop_limit=0)
    except (OSError, can.CanError):
        return False
    try:
        receiver = can.Bus(interface="udp_multicast", channel=group, hop_limit=0)
        try:
            sender.send(can.Message(arbitration_id=0x7FF, data=b"\x01", is_extended_id=False))
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline:
                msg = receiver.recv(0.2)
                if msg is not None and msg.arbitration_id == 0x7FF:
                    return True
            return False
        finally:
            receiver.shutdown()
    except (OSError, can.CanError):
        return False
    finally:
        sender.shutdown()


@pytest.mark.slow
def test_kill_9_of_the_host_mid_sweep_leaves_the_canopen_drive_quick_stopped(tmp_path: Path) -> None:
    """``bodebench sim-controller configs/sim_canopen.toml`` (on udp_multicast with a time to live of 0, a bus two
    processes on this host share and nothing outside it sees) and
    ``bodebench run`` of the config it writes, killed with SIGKILL mid-sweep: the drive notices the host's heartbeat
    missing for its consumer time (2 s), takes its abort connection option (quick stop), and says so; over SDO it
    then reports "quick stop active", still watching the dead host (nobody could write 0x1016 back)."""
    group = f"239.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(1, 254)}"
    assert _multicast_delivers(group), "python-can's udp_multicast carries no frames between processes here"
    text = (ROOT / "configs" / "sim_canopen.toml").read_text()
    text = text.replace('interface = "virtual"', 'interface = "udp_multicast"\noptions = { hop_limit = 0 }')
    text = text.replace('channel = "bodebench-canopen"', f'channel = "{group}"')
    text = re.sub(r"frequencies_hz = \[[^]]*\]", "frequencies_hz = [5, 6, 7, 8, 9, 10, 11, 12]", text)
    assert f'channel = "{group}"' in text and 'abort_connection = "quick stop"' in text
    drive_cfg, host_cfg = tmp_path / "drive.toml", tmp_path / "host.toml"
    drive_cfg.write_text(text)
    drive = subprocess.Popen(command() + ["sim-controller", str(drive_cfg), "--write-config", str(host_cfg)],
                             stdout=subprocess.PIPE, text=True, start_new_session=True)
    lines: list[str] = []
    enabled, lost = threading.Event(), threading.Event()
    lost_at: list[float] = []

    def read() -> None:
        assert drive.stdout is not None
        for line in drive.stdout:
            lines.append(line)
            if "drive operation enabled" in line:
                enabled.set()
            if "heartbeat of node 127 lost" in line:
                lost_at.append(time.monotonic())
                lost.set()

    statusword = watched = option = None
    try:
        assert drive.stdout is not None
        first = drive.stdout.readline()
        assert "CANopen node 5, on python-can udp_multicast" in first, first
        threading.Thread(target=read, daemon=True).start()
        host = subprocess.Popen(command() + ["run", str(host_cfg), "--out", str(tmp_path / "out")],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert enabled.wait(60), "".join(lines)
        time.sleep(0.7)  # mid-sweep: the first point's sine is on
        assert host.poll() is None, host.communicate()[1]
        os.kill(host.pid, signal.SIGKILL)  # no finally, no quick stop, no SDO: only the drive can stop itself
        killed = time.monotonic()
        host.communicate(timeout=60)
        assert lost.wait(10), "".join(lines)
        # the drive answers for itself: a third node on the bus reads its statusword and its consumer entry
        network = canopen.Network()
        network.connect(interface="udp_multicast", channel=group, hop_limit=0)
        try:
            node = network.add_node(NODE, str(SIMULATED_DRIVE_EDS))
            statusword = node.sdo[0x6041].raw
            watched = node.sdo[0x1016][1].raw
            option = node.sdo[0x6007].raw
        finally:
            network.disconnect()
    finally:
        os.killpg(drive.pid, signal.SIGINT)
        drive.wait(timeout=30)
    events = _drive_events(lines)
    states = [s for s in map(_state_of, events) if s is not None]
    assert states[-1] == str(State.QUICK_STOP_ACTIVE) and str(State.OPERATION_ENABLED) in states, events
    assert states[-2:] == [str(State.OPERATION_ENABLED), str(State.QUICK_STOP_ACTIVE)], events  # by no command
    # the drive watched the host from before it was enabled, and lost it once, within its consumer time
    watching = events.index("watching the heartbeat of node 127 (consumer time 2 s; abort connection option 3 "
                            "(quick stop))")
    assert watching < events.index("operation enabled (controlword 0x000F)"), events
    trips = [e for e in events if e.startswith("heartbeat of node 127 lost")]
    assert len(trips) == 1, events
    silent = float(re.search(r"lost for ([\d.]+) s", trips[0]).group(1))  # type: ignore[union-attr]
    # the drive checks on its own clock every 20 ms at most; a busy machine may delay that (the event prints the
    # silence to 1 ms, so a trip 0.4 ms past the consumer time reads 2.000)
    assert 2.0 <= silent < 3.0 and trips[0].endswith("(consumer time 2 s): abort connection option 3 (quick stop)")
    assert lost_at[0] - killed < 2.0 + 1.5, f"{lost_at[0] - killed:.3f} s from the kill to the drive's reaction"
    after = events[events.index(trips[0]) + 1:]
    assert after[0] == "quick stop active (heartbeat of node 127 lost)" and after[1].startswith("setpoint zeroed"), \
        events
    assert statusword is not None and decode_statusword(statusword) is State.QUICK_STOP_ACTIVE, hex(statusword or 0)
    assert watched == (HOST << 16) | 2000 and option == 3
    assert lines[-1].rstrip().endswith("last setpoint 0, disabled"), lines[-1]


# ---------------------------------------------------------------------------- the simulated drive's reaction


def _served(name: str, **canopen: Any) -> tuple[Any, CanopenDriver, Any]:
    """The simulated drive served on the virtual bus ``name`` in this process, and a host driver for it."""
    case = parse_config(bench(name, canopen=canopen), "canopen.toml").cases[0]
    setup = case.canopen_setup
    assert setup is not None and case.layout is not None
    controller = SimulatedController(plant_from_config(**LAG), case.layout, ControllerTiming(1000.0))
    serving = serve_canopen(controller, setup, {"interface": "virtual", "channel": name})
    return serving, CanopenDriver(CanPort.open("virtual", name), setup, case.layout), setup


@pytest.mark.parametrize(("option", "code", "state"), [("quick stop", 3, State.QUICK_STOP_ACTIVE),
                                                        ("disable voltage", 2, State.SWITCH_ON_DISABLED),
                                                        ("fault", 1, State.FAULT)])
def test_a_host_that_falls_silent_is_met_with_the_abort_connection_option(option: str, code: int,
                                                                          state: State) -> None:
    """The host enables the drive, sends a few setpoints, then its heartbeat stops (its periodic task ended, as
    when its process dies) and it sends nothing more: the drive sends EMCY 0x8130 and takes the 0x6007 reaction
    within its consumer time, with no SYNC to wake it."""
    name = channel()
    recorder = FrameRecorder(name)
    # a consumer time 20 host heartbeats long: a busy machine may hold the heartbeat's thread back for 250 ms
    serving, host, setup = _served(name, host_heartbeat_ms=50, drive_heartbeat_timeout_ms=1000,
                                   abort_connection=option)
    drive = serving.drive
    events: list[str] = []
    drive.on_event = events.append
    try:
        host.enable()
        assert drive.state is State.OPERATION_ENABLED
        assert drive.consumers == {1: (HOST, 1.0)} and drive.abort_option == code
        watching = next(i for i, e in enumerate(events) if e.startswith("watching the heartbeat of node 127 "
                                                                         "(consumer time 1 s"))
        assert watching < next(i for i, e in enumerate(events) if _state_of(e) is not None), events  # before enabling
        for k in range(20):
            host.send_setpoint(0.005, k)
            host.receive(1.0)
        time.sleep(0.2)
        assert drive.heartbeat_events == 0 and drive.heartbeats_consumed >= 3
        host.port.bus.stop_all_periodic_tasks()  # the host's heartbeat ends; the host says nothing more
        stopped = time.monotonic()
        while drive.heartbeat_events == 0 and time.monotonic() - stopped < 5:
            time.sleep(0.01)
        reacted = time.monotonic() - stopped
        assert drive.heartbeat_events == 1 and drive.state is state, events
        # the last heartbeat came up to a period before the stop; a busy machine may run the drive's timer late
        assert 1.0 - 0.06 < reacted < 1.0 + 1.0
        assert drive.controller.setpoint == 0.0 and not drive.controller.enabled
        lost = next(e for e in events if e.startswith("heartbeat of node 127 lost"))
        assert lost.endswith(f"(consumer time 1 s): abort connection option {code} ({option})")
        if state is not State.QUICK_STOP_ACTIVE:
            assert f"{state} (heartbeat of node 127 lost)" in events
        time.sleep(0.3)
        assert drive.heartbeat_events == 1  # one event: watched again from the host's next heartbeat only
        # the host, still there after all, writes the drive's settings back on the way out
        host.disable()
        assert "lost-host settings: consumer heartbeat time 0x1016:01 = 0x00000000 restored, abort connection " \
               "option code 0x6007 = 1 restored" in host.shutdown_account
        assert drive.consumers == {} and drive.abort_option == 1
    finally:
        host.close()
        serving.close()
    emcy = [m for m in recorder.frames_seen() if m.arbitration_id == 0x80 + NODE]
    assert [int.from_bytes(bytes(m.data[:2]), "little") for m in emcy][:1] == [0x8130]


def test_with_a_bus_log_the_host_heartbeat_comes_from_a_thread_and_is_logged(tmp_path: Path) -> None:
    """A bus log must see every frame, so the port declines python-can's periodic send: the driver sends its
    heartbeat from a thread of its own, and the drive is watched all the same."""
    name = channel()
    case = parse_config(bench(name), "canopen.toml").cases[0]
    setup = case.canopen_setup
    assert setup is not None and case.layout is not None
    controller = SimulatedController(plant_from_config(**LAG), case.layout, ControllerTiming(1000.0))
    serving = serve_canopen(controller, setup, {"interface": "virtual", "channel": name})
    log = tmp_path / "bus.asc"
    host = CanopenDriver(CanPort.open("virtual", name, log=log), setup, case.layout)
    try:
        host.enable()
        assert "sent by a thread of the host" in host.protection
        time.sleep(0.45)
        assert serving.drive.heartbeats_consumed >= 4 and serving.drive.heartbeat_events == 0
        assert host.disable()
    finally:
        host.close()
        serving.close()
    beats = [line for line in log.read_text().splitlines() if re.search(r"\b77F\b", line)]
    assert len(beats) >= 5
    assert serving.drive.heartbeat_events == 0  # written back before the heartbeat stopped


# ------------------------------------------------------------------------- the settings are written back


def test_a_sweep_writes_the_drives_own_0x1016_and_0x6007_back() -> None:
    """The drive had its own settings (watching another node for 2 s; abort connection option 2): during the sweep
    it watches the host (node 127, 2000 ms; option 3, quick stop), and after it both are as they were, read from the
    drive's object dictionary."""
    name = channel()
    data = bench(name)
    del data["simulator"]
    data["canopen"]["eds"] = str(SIMULATED_DRIVE_EDS)
    data["excitation"]["frequencies_hz"] = [12.0]
    case = parse_config(data, "canopen.toml").cases[0]
    setup = case.canopen_setup
    assert setup is not None and case.layout is not None
    controller = SimulatedController(plant_from_config(**LAG), case.layout, ControllerTiming(1000.0))
    serving = serve_canopen(controller, setup, {"interface": "virtual", "channel": name})
    drive = serving.drive
    assert drive.node is not None
    own_consumer = (0x20 << 16) | 2000
    drive.node.sdo[0x1016][1].raw = own_consumer
    drive.node.sdo[0x6007].raw = 2
    assert drive.consumers == {1: (0x20, 2.0)} and drive.abort_option == 2
    during: list[tuple[int, int, dict[int, tuple[int, float]], int]] = []

    def listener(event: object) -> None:
        if isinstance(event, PointProgress) and not during:
            assert drive.node is not None
            during.append((drive.node.sdo[0x1016][1].raw, drive.node.sdo[0x6007].raw, dict(drive.consumers),
                           drive.heartbeats_consumed))

    session = BenchSession(case, plan_link(case), None, listener)
    try:
        result = session.run()
    finally:
        serving.close()
    assert result.completed
    assert during and during[0][:3] == ((HOST << 16) | 2000, 3, {1: (HOST, 2.0)}) and during[0][3] >= 1
    assert drive.node.sdo[0x1016][1].raw == own_consumer and drive.node.sdo[0x6007].raw == 2
    assert drive.consumers == {1: (0x20, 2.0)} and drive.abort_option == 2
    assert drive.heartbeat_events == 0 and drive.state is State.SWITCH_ON_DISABLED
    assert session.ended is not None and session.ended.disabled
    said = session.ended.drive_state()
    assert said.endswith("NMT pre-operational sent; lost-host settings: consumer heartbeat time 0x1016:01 = "
                         "0x002007D0 restored, abort connection option code 0x6007 = 2 restored"), said


def test_a_watch_of_the_host_left_by_a_dead_session_is_switched_off_at_the_end(
        caplog: pytest.LogCaptureFixture) -> None:
    """A host that died left the drive watching node 127: the next session finds that, uses the same sub-entry, and
    at its end switches the watch off instead of writing back a watch of a host that is then gone."""
    name = channel()
    serving, host, setup = _served(name)
    drive = serving.drive
    assert drive.node is not None
    drive.node.sdo[0x1016][1].raw = setup.consumer_value  # as a killed host left it
    drive.node.sdo[0x6007].raw = 3
    try:
        with caplog.at_level(logging.WARNING, logger="bodebench.canopen"):
            host.enable()
        assert drive.consumers == {1: (HOST, 2.0)}
        assert host.disable()
    finally:
        host.close()
        serving.close()
    assert drive.node.sdo[0x1016][1].raw == 0 and drive.consumers == {}
    assert drive.node.sdo[0x6007].raw == 3  # what it was found at: the drive's own setting is not known
    assert any("already watched node 127 (0x007F07D0)" in r.getMessage() for r in caplog.records)
    assert drive.heartbeat_events == 0


# ------------------------------------------------------------------------ a drive without the objects


def _eds_without(objects: tuple[str, ...], path: Path) -> Path:
    """The shipped EDS without the sections of ``objects`` ("1016", "6007") and their OptionalObjects entries."""
    text = SIMULATED_DRIVE_EDS.read_text()
    for obj in objects:
        text = re.sub(rf"\[{obj}(sub\d+)?\]\n(?:[^\[\n][^\n]*\n)*\n?", "", text)
        text = re.sub(rf"\d+=0x{obj}\n", "", text)
    entries = re.search(r"\[OptionalObjects\]\nSupportedObjects=\d+\n((?:\d+=0x[0-9A-F]+\n)+)", text)
    assert entries is not None
    ids = re.findall(r"=(0x[0-9A-F]+)", entries.group(1))
    block = f"[OptionalObjects]\nSupportedObjects={len(ids)}\n" + "".join(f"{i}={o}\n" for i, o in enumerate(ids, 1))
    path.write_text(text[:entries.start()] + block + text[entries.end():])
    return path


def test_a_drive_whose_eds_lacks_0x1016_and_0x6007_is_swept_and_the_run_says_it_cannot_protect_itself(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    eds = _eds_without(("1016", "6007"), tmp_path / "no_consumer.eds")
    od = canopen.import_od(str(eds), NODE)
    assert 0x1016 not in od and 0x6007 not in od and 0x1017 in od and 0x603F in od
    name = channel()
    recorder = FrameRecorder(name)
    data = bench(name, canopen={"eds": str(eds)})
    data["excitation"]["frequencies_hz"] = [12.0]
    with caplog.at_level(logging.WARNING, logger="bodebench.canopen"):
        session, error = run_session(data, tmp_path / "out")
    frames = recorder.frames_seen()
    assert error is None and session.ended is not None and session.ended.disabled
    said = session.ended.drive_state()
    assert said.endswith("NMT pre-operational sent; the drive CANNOT protect itself from a lost host: its EDS has no "
                         "heartbeat consumer time 0x1016 nor abort connection option code 0x6007, so a host that "
                         "dies leaves it as it was (configure the drive's own SYNC or RPDO timeout)"), said
    assert any("CANNOT protect itself" in r.getMessage() for r in caplog.records)
    assert not sdo_writes(frames, 0x1016) and not sdo_writes(frames, 0x6007)  # nothing written it does not have
    assert sum(m.arbitration_id == 0x700 + HOST for m in frames) >= 2  # the host's heartbeat went out all the same


# -------------------------------------------------------------------------------------------- configuration


@pytest.mark.parametrize(("change", "message"), [
    ({"host_node_id": NODE}, r"canopen\.host_node_id: 5 is the drive's own node id"),
    ({"host_node_id": 128}, r"canopen\.host_node_id: .*127"),
    ({"drive_heartbeat_timeout_ms": 100}, r"canopen\.drive_heartbeat_timeout_ms: 100 ms must be longer"),
    ({"host_heartbeat_ms": 200, "drive_heartbeat_timeout_ms": 150}, r"drive_heartbeat_timeout_ms: 150 ms"),
    ({"abort_connection": "halt"}, r"canopen\.abort_connection: must be one of"),
])
def test_protection_config_errors_name_the_key(change: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_config(bench("cfg", canopen=change), "canopen.toml")


def test_the_protection_defaults() -> None:
    setup = parse_config(bench("cfg"), "canopen.toml").cases[0].canopen_setup
    assert setup is not None
    assert (setup.host_node_id, setup.host_heartbeat_ms, setup.drive_heartbeat_timeout_ms, setup.abort_connection) \
        == (127, 100, 2000, 3)
    setup = parse_config(bench("cfg", canopen={"host_heartbeat_ms": 40}), "canopen.toml").cases[0].canopen_setup
    assert setup is not None and setup.drive_heartbeat_timeout_ms == 800  # 20 host periods
    assert setup.consumer_value == (127 << 16) | 800
