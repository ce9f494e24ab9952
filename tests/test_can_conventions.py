"""python-can's conventions: [can] values left to python-can's own configuration, CAN FD layouts, bus logs read back
with python-can's LogReader (and the serial byte log deframed), and ``bodebench ports``."""

from __future__ import annotations

import json
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

import can
import can.util
import pytest
from helpers import FrameRecorder

from bodebench.bench.procedure import SweepProcedure
from bodebench.drivers.ports import ByteLog
from bodebench.drivers.serial_framing import BinaryDeframer
from bodebench.io.config import ConfigError, load_config, parse_config
from bodebench.io.results import load_response

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def python_can_home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty home and working directory, no CAN_* variables: python-can's configuration is what the test puts
    there."""
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(tmp_path)
    for name in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(name, raising=False)
    return home


def bench(can_table: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {
        "plant": {"model": "lag", "time_constant": 0.01},
        "excitation": {"amplitude": 0.01, "frequencies_hz": [5.0, 20.0]},
        "analysis": {"tolerance_percent": 0.1},
        "bench": {"transport": "can", "rate_hz": 1000.0, "clock": "lockstep"},
        "can": can_table,
        "safety": {"max_amplitude": 0.02},
        **extra,
    }


def test_interface_channel_and_bitrate_come_from_canrc_and_the_environment(
        python_can_home: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (python_can_home / ".canrc").write_text("[default]\ninterface = virtual\nchannel = rc-chan\nbitrate = 250000\n"
                                            "[rig2]\ninterface = virtual\nchannel = rig2-chan\n")
    case = parse_config(bench({}), "x.toml").cases[0]
    assert case.can is not None
    expected = can.util.load_config()
    assert (case.can.interface, case.can.channel, case.can.bitrate) == (
        expected["interface"], expected["channel"], expected["bitrate"]) == ("virtual", "rc-chan", 250000)
    assert case.raw["can"]["channel"] == "rc-chan" and case.raw["can"]["bitrate"] == 250000  # recorded
    bus = can.Bus()  # what python-can itself opens with no arguments
    try:
        assert bus.channel_info == f"Virtual bus channel {case.can.channel}"
    finally:
        bus.shutdown()
    # a section by name, and what the file gives is overridden by [can] and by the environment, in that order
    case = parse_config(bench({"context": "rig2"}), "x.toml").cases[0]
    assert case.can is not None and case.can.channel == "rig2-chan"
    monkeypatch.setenv("CAN_CHANNEL", "env-chan")
    monkeypatch.setenv("CAN_BITRATE", "500000")
    case = parse_config(bench({}), "x.toml").cases[0]
    assert case.can is not None and (case.can.channel, case.can.bitrate) == ("env-chan", 500000)
    assert can.util.load_config()["channel"] == "env-chan"
    case = parse_config(bench({"channel": "mine"}), "x.toml").cases[0]
    assert case.can is not None and (case.can.interface, case.can.channel) == ("virtual", "mine")


@pytest.mark.slow
def test_a_bench_sweep_on_the_resolved_bus(python_can_home: Path, tmp_path: Path) -> None:
    channel = f"canrc-{uuid.uuid4().hex[:8]}"
    (python_can_home / ".canrc").write_text(f"[default]\ninterface = virtual\nchannel = {channel}\n")
    config = parse_config(bench({}, simulator={}), "x.toml")  # the simulated drive keeps its own channel
    assert config.cases[0].can is not None and config.cases[0].can.channel == ""
    outcome = SweepProcedure(config, tmp_path / "out").run()[0]
    assert [p.status for p in outcome.response] == ["converged", "converged"]


def test_nothing_to_resolve_is_a_one_line_error(python_can_home: Path) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(bench({}), "x.toml")
    assert str(info.value) == ("x.toml: can.interface: missing: not in the file, nor in python-can's configuration "
                               "(CAN_INTERFACE, ~/.canrc)")
    with pytest.raises(ConfigError, match=r'x.toml: can.interface: Unknown interface type "nope"'):
        parse_config(bench({"interface": "nope", "channel": "a"}), "x.toml")
    with pytest.raises(ConfigError, match=r"x.toml: can.channel: missing: not in the file, nor in python-can"):
        parse_config(bench({"interface": "virtual"}), "x.toml")


def fd_frames(length: int) -> dict[str, Any]:
    """A layout whose feedback frame is ``length`` bytes: position and its echo as float64, the counter, the CRC in
    the last byte; the setpoint frame is 12 bytes."""
    return {
        "setpoint": {"id": 0x201, "signals": [{"name": "setpoint", "byte": 0, "type": "float64"},
                                               {"name": "counter", "byte": 10, "type": "uint16"}]},
        "feedback": [{"id": 0x181, "signals": [
            {"name": "position", "byte": 0, "type": "float64"},
            {"name": "setpoint_echo", "byte": 8, "type": "float64"},
            {"name": "counter", "byte": 16, "type": "uint16"},
            {"name": "crc", "byte": length - 1, "type": "uint8"}]}],
        "enable": {"id": 0x10, "data": [1]},
        "disable": {"id": 0x10, "data": [0]},
    }


@pytest.mark.slow
def test_can_fd_frames_on_the_virtual_bus(tmp_path: Path) -> None:
    channel = f"fd-{uuid.uuid4().hex[:8]}"
    data = bench({"interface": "virtual", "channel": channel, "fd": True}, simulator={}, frames=fd_frames(24))
    recorder = FrameRecorder(channel)
    try:
        outcome = SweepProcedure(parse_config(data, "fd.toml"), tmp_path).run()[0]
    finally:
        frames = recorder.frames_seen()
    feedback = [m for m in frames if m.arbitration_id == 0x181]
    setpoints = [m for m in frames if m.arbitration_id == 0x201]
    assert feedback and all(m.is_fd and m.dlc == 24 and len(m.data) == 24 for m in feedback)
    assert setpoints and all(m.is_fd and len(m.data) == 12 for m in setpoints)
    # the FD frames carry what the same drive gives called in-process, without a bus
    direct = SweepProcedure(parse_config(data, "fd.toml"), tmp_path / "direct", direct=True).run()[0]
    assert len(outcome.response) == len(direct.response) == 2
    for p, d in zip(outcome.response, direct.response, strict=True):
        assert p.status == d.status == "converged"
        assert abs(complex(p.p, p.q) - complex(d.p, d.q)) <= 1e-9 * abs(complex(d.p, d.q))
    with pytest.raises(ConfigError, match="payload of 12 bytes exceeds 8 for can"):
        parse_config(bench({"interface": "virtual", "channel": "a"}, frames=fd_frames(24)), "fd.toml")
    with pytest.raises(ConfigError, match="payload of 22 bytes is not a CAN FD length .* fills it to 24"):
        parse_config(bench({"interface": "virtual", "channel": "a", "fd": True}, frames=fd_frames(22)), "fd.toml")


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log"])  # .csv holds no direction
def test_the_bus_log_holds_the_sessions_traffic(tmp_path: Path, suffix: str) -> None:
    # python-can reads a channel number off a name's trailing digits: here one too big for BLF's 16-bit field
    channel = f"log-{uuid.uuid4().hex[:8]}-{70000 + uuid.uuid4().int % 10000}"
    raw = load_config(ROOT / "configs" / "sim_can.toml")
    data = json.loads(json.dumps(raw.cases[0].raw))
    data["can"] = {"interface": "virtual", "channel": channel}
    data["excitation"]["frequencies_hz"] = [10.0, 20.0]
    data["analysis"]["harmonics"] = [1]
    data["analysis"]["tolerance_percent"] = 0.1
    log = tmp_path / f"bus{suffix}"
    recorder = FrameRecorder(channel)
    try:
        outcome = SweepProcedure(parse_config(data, "sim_can.toml"), tmp_path / "out", log_bus=log).run()[0]
    finally:
        frames = recorder.frames_seen()
    assert outcome.result is not None and outcome.result.health is not None
    health = outcome.result.health.bus
    logged = list(can.LogReader(log))
    host_ids = {0x201, 0x010, 0x700}
    sent = [m for m in logged if not m.is_rx]
    received = [m for m in logged if m.is_rx]
    # every frame the host put on the bus, in order, and every frame it read, in order
    on_bus_from_host = [(m.arbitration_id, bytes(m.data)) for m in frames if m.arbitration_id in host_ids]
    on_bus_to_host = [(m.arbitration_id, bytes(m.data)) for m in frames if m.arbitration_id not in host_ids]
    assert [(m.arbitration_id, bytes(m.data)) for m in sent] == on_bus_from_host
    # the drive's last replies may come after the host stopped reading: what it read is the start of them
    assert [(m.arbitration_id, bytes(m.data)) for m in received] == on_bus_to_host[:len(received)]
    # the session's counters were read before the ramp out, the zero setpoint and the disable frame
    assert len(sent) > health.frames_out and len(received) >= health.frames_in
    layout = outcome.case.on_bench.layout
    last_setpoint = [m for m in sent if m.arbitration_id == layout.setpoint.id][-1]
    assert layout.setpoint.decode(bytes(last_setpoint.data))["setpoint"] == 0.0
    assert (sent[-1].arbitration_id, bytes(sent[-1].data)) == (layout.disable.id, bytes(layout.disable.data))
    assert any(m.arbitration_id == 0x700 for m in sent)  # the heartbeat too
    # received frames carry the interface's time stamps, sent frames the time of sending: each in order
    for direction in (sent, received):
        stamps = [m.timestamp for m in direction]
        late = [i for i in range(1, len(stamps)) if stamps[i] < stamps[i - 1]]
        assert not late, f"{len(late)} stamps out of order, first at {late[0]}: {stamps[late[0] - 1:late[0] + 1]}"


@pytest.mark.parametrize("number, logged", [("-12", 12), ("-65534", 65534), ("-65535", 0), ("-1234567", 0),
                                            ("-rig", 0)])
def test_a_blf_log_takes_any_channel_name(tmp_path: Path, number: str, logged: int) -> None:
    """BLF keeps channel + 1 in 16 bits, the channel python-can reads off a name's trailing digits: a channel whose
    number does not fit is logged as the writer's default (python-can reads that, channel 1, back as 0)."""
    from bodebench.drivers.ports import CanPort, Frame

    name = f"blf{uuid.uuid4().hex[:8]}x{number}"
    peer = can.Bus(interface="virtual", channel=name)
    port = CanPort(can.Bus(interface="virtual", channel=name), log=tmp_path / "bus.blf")
    port.send(Frame(0x201, b"\x01\x02", False, 0.0))
    peer.send(can.Message(arbitration_id=0x181, data=b"\x03", is_extended_id=False))
    assert [f.id for f in port.recv(1.0)] == [0x181]
    port.close()
    peer.shutdown()
    assert not port.log_failure
    read = list(can.LogReader(tmp_path / "bus.blf"))
    assert [(m.arbitration_id, m.is_rx, m.channel) for m in read] == [(0x201, False, logged), (0x181, True, logged)]


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_a_bus_log_that_cannot_be_written_leaves_the_sweep_going(tmp_path: Path, suffix: str,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """The log is a record, not the measurement: on a full disk (the log file on /dev/full) it stops recording
    and the sweep goes on to its end; the failure is stated once in the output and in the run's record."""
    from bodebench.apps.cli import main

    channel = f"full-{uuid.uuid4().hex[:8]}"
    raw = load_config(ROOT / "configs" / "sim_can.toml")
    text = (ROOT / "configs" / "sim_can.toml").read_text()
    text = text.replace('channel = "bodebench"', f'channel = "{channel}"')
    text = text.replace("frequencies_hz = [2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 15, 20, 30, 50]",
                        "frequencies_hz = [10, 20]")
    text = text.replace("harmonics = [1, 3]", "harmonics = [1]").replace("tolerance_percent = 0.01",
                                                                          "tolerance_percent = 0.1")
    assert raw.cases[0].can is not None and text.count(channel) == 1
    cfg = tmp_path / "full.toml"
    cfg.write_text(text)
    log = tmp_path / f"bus{suffix}"
    log.symlink_to("/dev/full")
    recorder = FrameRecorder(channel)
    try:
        status = main(["run", str(cfg), "--out", str(tmp_path / "out"), "--log-bus", str(log), "--plots", "none",
                       "--quiet"])
    finally:
        frames = recorder.frames_seen()
    out = capsys.readouterr().out
    assert status == 0, out
    failed = [line for line in out.splitlines() if "bus log failed" in line]
    assert len(failed) == 1 and f"{log}: No space left on device" in failed[0], out
    case_line = next(line for line in out.splitlines() if line.startswith("full: "))
    assert case_line.startswith("full: 2 points, 0 not converged"), out
    assert case_line.endswith("; drive left at setpoint 0, disabled"), out
    # the drive's last setpoint on the bus was zero, the disable frame went out after it
    layout = parse_config(json.loads(json.dumps(raw.cases[0].raw)), "sim_can.toml").cases[0].on_bench.layout
    host = [m for m in frames if m.arbitration_id in (layout.setpoint.id, layout.disable.id)]
    setpoints = [m for m in host if m.arbitration_id == layout.setpoint.id]
    assert layout.setpoint.decode(bytes(setpoints[-1].data))["setpoint"] == 0.0
    assert (host[-1].arbitration_id, bytes(host[-1].data)) == (layout.disable.id, bytes(layout.disable.data))
    runs = json.loads((tmp_path / "out" / "response.json").read_text())["runs"]
    assert runs[-1]["completed"] and runs[-1]["bus_log_failure"] in failed[0]
    assert len(load_response(tmp_path / "out").points) == 2


def test_a_serial_byte_log_on_a_full_disk_stops_recording_and_says_why() -> None:
    log = ByteLog("/dev/full")  # opens; every write fails, as on a full disk
    log.write("TX", b"\x01\x02")
    log.write("RX", b"\x03")
    log.close()
    assert log.failure.startswith("/dev/full: No space left on device; nothing logged after "), log.failure


@pytest.mark.slow
def test_a_serial_session_leaves_a_raw_byte_log(tmp_path: Path) -> None:
    config = load_config(ROOT / "configs" / "sim_serial.toml")
    data = json.loads(json.dumps(config.cases[0].raw))
    data["excitation"]["frequencies_hz"] = [10.0]
    data["analysis"]["harmonics"] = [1]
    data["analysis"]["tolerance_percent"] = 0.1
    log = tmp_path / "line.log"
    outcome = SweepProcedure(parse_config(data, "sim_serial.toml"), tmp_path / "out", log_bus=log).run()[0]
    assert outcome.result is not None and outcome.result.health is not None
    health = outcome.result.health.bus
    entries = ByteLog.read(log)
    assert log.read_text().startswith("# bodebench serial byte log")
    assert [e[0] for e in entries] == sorted(e[0] for e in entries)
    tx, rx = BinaryDeframer(), BinaryDeframer()
    sent = [f for _, d, b in entries if d == "TX" for f in tx.feed(b)]
    received = [f for _, d, b in entries if d == "RX" for f in rx.feed(b)]
    # the session's counters were read before the ramp out, the zero setpoint and the disable frame
    assert len(sent) > health.frames_out and len(received) >= health.frames_in
    layout = outcome.case.on_bench.layout
    last_setpoint = [data for frame_id, data in sent if frame_id == layout.setpoint.id][-1]
    assert layout.setpoint.decode(bytes(last_setpoint))["setpoint"] == 0.0
    assert (sent[-1][0], bytes(sent[-1][1])) == (layout.disable.id, bytes(layout.disable.data))
    assert tx.crc_errors == rx.crc_errors == 0 and tx.bytes_discarded == rx.bytes_discarded == 0
    setpoint_id = outcome.case.on_bench.layout.setpoint.id
    assert sum(1 for frame_id, _ in sent if frame_id == setpoint_id) > 100


def test_ports_lists_serial_ports_and_can_configurations() -> None:
    import serial.tools.list_ports

    done = subprocess.run([sys.executable, "-m", "bodebench", "ports", "--can", "virtual", "--json"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    listed = json.loads(done.stdout)
    assert [p["port"] for p in listed["serial"]] == sorted(p.device for p in serial.tools.list_ports.comports())
    assert listed["can"] and all(c["interface"] == "virtual" for c in listed["can"])
    done = subprocess.run([sys.executable, "-m", "bodebench", "ports", "--can", "virtual"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and 'interface = "virtual", channel = "' in done.stdout
    assert done.stdout.startswith("serial ports (pyserial):")


def test_log_bus_makes_its_directory_and_names_what_it_cannot_use(tmp_path: Path) -> None:
    """``--log-bus results/x.asc`` on a fresh checkout makes ``results`` (as ``--out`` makes its directory); a
    directory, or a path under a file, is one line naming the option's value."""
    from bodebench.apps.commands.run import _log_bus
    from bodebench.io.results import ResultsError

    log = tmp_path / "results" / "deeper" / "bus.asc"
    assert _log_bus(str(log)) == log and log.parent.is_dir() and not log.exists()
    with pytest.raises(ResultsError, match=r"^--log-bus .*results: is a directory$"):
        _log_bus(str(tmp_path / "results"))
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(ResultsError, match=r"^--log-bus .*a_file/bus.asc: cannot make its directory .*a_file: "):
        _log_bus(str(blocker / "bus.asc"))
