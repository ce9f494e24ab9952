"""The drive's watchdog (drivers/PROTOCOL.md section 5): the host feeds it with heartbeats, and a host that dies
(kill -9) leaves the drive zeroed and disabled by the drive itself, on CAN and on a serial line."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can
import pytest
from test_bench_config import FRAMES
from test_bench_e2e import config
from test_cli_bench import SERIAL_BENCH, command

from bodebench.bench.connection import plan_link, simulator_spec
from bodebench.bench.events import PointProgress, SessionError
from bodebench.bench.session import BenchSession
from bodebench.drivers.layout import Layout
from bodebench.io.config import parse_config
from bodebench.sim.serve import serve_can

CAN_FRAMES = {**FRAMES, "heartbeat": {"id": 0x700, "data": [5], "period_s": 0.1}, "drive_watchdog_s": 0.5}
WATCHDOG_TOML = """
[frames.heartbeat]
id = 0x20
data = [5]
period_s = 0.1
[frames]
drive_watchdog_s = 0.5
"""
CAN_BENCH = SERIAL_BENCH.replace('transport = "serial"', 'transport = "can"').replace(
    '[serial]\nport = "{port}"\nframing = "binary"', '[can]\ninterface = "slcan"\nchannel = "{port}"')
"""The same bench on CAN, through python-can's slcan interface (a simulated adapter on a pty)."""


def _drive_events(text: str) -> list[str]:
    return [line.split(" s  drive ", 1)[1] for line in text.splitlines() if " s  drive " in line]


def _kill_host_mid_sweep(tmp_path: Path, drive_text: str, host_for: Callable[[str], str],
                         pattern: str) -> tuple[list[str], str]:
    """``bodebench sim-controller`` on a pty, ``bodebench run`` against it killed with SIGKILL after its first
    point; returns the drive's state changes and its last line."""
    drive_cfg, host_cfg = tmp_path / "drive.toml", tmp_path / "host.toml"
    drive_cfg.write_text(drive_text)
    drive = subprocess.Popen(command() + ["sim-controller", str(drive_cfg)], stdout=subprocess.PIPE, text=True,
                             start_new_session=True)
    lines: list[str] = []
    tripped = threading.Event()

    def read() -> None:
        assert drive.stdout is not None
        for line in drive.stdout:
            lines.append(line)
            if "watchdog trip" in line:
                tripped.set()

    try:
        assert drive.stdout is not None
        first = drive.stdout.readline()
        assert "watchdog 0.5 s" in first, first
        path = re.search(pattern, first).group(1)  # type: ignore[union-attr]
        threading.Thread(target=read, daemon=True).start()
        time.sleep(1.0)  # an idle, disabled drive at zero does not trip, however long it waits for a host
        host_cfg.write_text(host_for(path))
        out = tmp_path / "out"
        host = subprocess.Popen(command() + ["run", str(host_cfg), "--out", str(out)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        csv = out / "response.csv"
        while host.poll() is None and not (csv.exists() and len(csv.read_text().splitlines()) >= 2):
            time.sleep(0.02)
        assert host.poll() is None, host.communicate()[1]
        os.kill(host.pid, signal.SIGKILL)  # no finally, no zero setpoint: only the drive can make itself safe
        host.communicate(timeout=60)
        assert tripped.wait(60), "".join(lines)
    finally:
        os.killpg(drive.pid, signal.SIGINT)
        drive.wait(timeout=30)
    return _drive_events("".join(lines)), lines[-1]


@pytest.mark.slow
@pytest.mark.parametrize("bench, pattern", [(SERIAL_BENCH, r'port = "([^"]+)"'), (CAN_BENCH, r'channel = "([^"]+)"')],
                         ids=["serial", "can-slcan"])
def test_kill_9_of_the_host_leaves_the_drive_zeroed_and_disabled(tmp_path: Path, bench: str, pattern: str) -> None:
    """On a serial line, and on CAN through python-can's slcan interface to a simulated adapter (the host's
    heartbeat then goes out by python-can's periodic send); the drive in another process."""
    events, last = _kill_host_mid_sweep(
        tmp_path, bench.format(freqs="[3]", port="", simulator=WATCHDOG_TOML + "[simulator]"),
        lambda path: bench.format(freqs="[15, 3, 4, 5, 6, 7, 8, 9, 10]", port=path, simulator=WATCHDOG_TOML),
        pattern)
    trip = next(i for i, e in enumerate(events) if e.startswith("watchdog trip"))
    # enabled and fed while the host lived; nobody sent a disable: the watchdog tripped once and did it
    assert events[0] == "enabled (enable frame)" and not any("disabled" in e for e in events[:trip]), events
    assert sum(e.startswith("watchdog trip") for e in events) == 1, events
    assert events[trip + 1:] == [e for e in events[trip + 1:] if e.startswith("setpoint zeroed")] + \
        ["disabled (watchdog)"]
    assert last.rstrip().endswith("last setpoint 0, disabled")


def _paused_sweep(frames: dict, channel: str, resume: bool) -> tuple[int, int, list[str]]:
    """A lockstep sweep on the virtual bus, paused for four drive watchdog times in its first point (then resumed,
    or aborted), against a simulated drive served in this process; (drive watchdog trips, heartbeat frames on the
    bus, drive events)."""
    data = config(can={"channel": channel}, frames=frames, simulator=None)
    data["excitation"]["frequencies_hz"] = [8.0]
    case = parse_config(data, "watchdog.toml").cases[0]
    layout = Layout.from_mapping(frames)
    events: list[str] = []
    serving = serve_can(simulator_spec(parse_config(config(can={"channel": channel}, frames=frames),
                                                    "watchdog.toml").cases[0]))
    serving.controller.on_event = events.append
    recorder = can.Bus(interface="virtual", channel=channel)
    holder: dict[str, BenchSession] = {}
    paused: list[bool] = []

    def listener(event: object) -> None:
        if isinstance(event, PointProgress) and event.periods >= 1 and not paused:
            paused.append(True)
            holder["s"].controls.set_paused(True)
            then = (lambda: holder["s"].controls.set_paused(False)) if resume else holder["s"].controls.request_abort
            threading.Timer(4 * layout.drive_watchdog_s, then).start()

    try:
        session = holder["s"] = BenchSession(case, plan_link(case), None, listener)
        if resume:
            session.run()
        else:
            with pytest.raises(SessionError, match="abort"):
                session.run()
    finally:
        serving.close()
    beats = 0
    while (msg := recorder.recv(0.05)) is not None:
        beats += msg.arbitration_id == 0x700
    recorder.shutdown()
    return serving.controller.watchdog_trips, beats, events


@pytest.mark.slow
def test_the_heartbeat_keeps_a_paused_sweep_from_tripping_the_drive() -> None:
    trips, beats, events = _paused_sweep(CAN_FRAMES, "watchdog-fed", resume=True)
    assert trips == 0, events
    assert beats >= 4  # python-can's periodic send went on while no setpoint did
    assert events[0] == "enabled (enable frame)" and events[-1] == "disabled (disable frame)"


def test_without_a_heartbeat_a_paused_sweep_trips_the_drive() -> None:
    frames = {k: v for k, v in CAN_FRAMES.items() if k != "heartbeat"}
    trips, beats, events = _paused_sweep(frames, "watchdog-starved", resume=False)
    assert trips == 1 and beats == 0
    assert any(e.startswith("watchdog trip") for e in events) and "disabled (watchdog)" in events


def test_a_host_silent_longer_than_the_drives_watchdog_ends_the_sweep_instead_of_measuring_a_tripped_drive() -> None:
    """No heartbeat, the sweep paused for four drive watchdog times, then resumed: the drive tripped meanwhile (it says
    so), and the host, which knows how long it was silent, ends the sweep with a line saying why at its next
    setpoint, instead of integrating what a zeroed, disabled drive answers."""
    frames = {k: v for k, v in CAN_FRAMES.items() if k != "heartbeat"}
    with pytest.raises(SessionError) as raised:
        _paused_sweep(frames, "watchdog-host-silent", resume=True)
    assert raised.value.kind == "watchdog"
    assert "the host sent the drive nothing for" in str(raised.value) and "drive_watchdog_s = 0.5" in str(raised.value)
