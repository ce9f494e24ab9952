"""Frames prove themselves before they become data (drivers/PROTOCOL.md section 6): CRC-8 against published check
values, exact lengths, counter continuity, a second node on the virtual CAN channel sending random feedback frames,
valid-CRC random and truncated frames on a serial pty, and points that cannot be physical refused."""

from __future__ import annotations

import math
import os
import threading
import tomllib
import warnings
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from test_bench_e2e import SERIAL_FRAMES, compare, config

from bodebench.bench.connection import plan_link
from bodebench.bench.events import BusStatus
from bodebench.bench.session import BenchSession, _absurd_point
from bodebench.core.response import ResponsePoint
from bodebench.drivers.driver import Driver
from bodebench.drivers.e2e import crc8_sae_j1850, crc_byte, intact, seal
from bodebench.drivers.errors import LayoutError
from bodebench.drivers.layout import Layout
from bodebench.drivers.ports import CanPort, SerialPort
from bodebench.drivers.serial_framing import encode_binary
from bodebench.io.config import parse_config
from bodebench.sim.pty_link import Pty

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
FIRST = {"harmonics": [1], "tolerance_percent": 0.05}


# published check values of CRC-8/SAE-J1850 (the AUTOSAR CRC library's table of examples and the CRC catalogue)
@pytest.mark.parametrize("data, crc", [
    (b"123456789", 0x4B),
    (bytes.fromhex("00000000"), 0x59),
    (bytes.fromhex("F20183"), 0x37),
    (bytes.fromhex("0FAA0055"), 0x79),
    (bytes.fromhex("00FF5511"), 0xB8),
    (bytes.fromhex("332255AABBCCDDEEFF"), 0xCB),
    (bytes.fromhex("926B55"), 0x8C),
    (bytes.fromhex("FFFFFFFF"), 0x74),
])
def test_crc8_sae_j1850_check_values(data: bytes, crc: int) -> None:
    assert crc8_sae_j1850(data) == crc


def _crc_layout() -> Layout:
    return Layout.from_mapping(_crc_layout_mapping())


def test_the_crc_byte_is_found_sealed_and_checked() -> None:
    fb = _crc_layout().feedback[0]
    at = crc_byte(fb)
    assert at == 6
    payload = seal(fb.encode({"position": -0.25, "counter": 258, "crc": 0}), at)
    assert payload.hex() == "000080be0201a7"  # the example of drivers/PROTOCOL.md section 6
    assert intact(payload, at)
    for i in range(len(payload)):  # any one byte changed is caught
        assert not intact(payload[:i] + bytes([payload[i] ^ 0x10]) + payload[i + 1:], at)


def test_a_crc_signal_wider_than_a_byte_is_refused() -> None:
    frames: dict[str, Any] = _crc_layout_mapping()
    frames["feedback"][0]["signals"][2] = {"name": "crc", "byte": 6, "type": "uint16"}
    with pytest.raises(LayoutError, match="crc.*uint8"):
        Layout.from_mapping(frames)


def _crc_layout_mapping() -> dict[str, Any]:
    """The [frames] table of the shipped CAN configuration."""
    return tomllib.loads((CONFIGS / "sim_can.toml").read_text())["frames"]


def test_wrong_crc_wrong_length_and_a_stray_counter_are_rejected_by_cause() -> None:
    layout = _crc_layout()
    peer = can.Bus(interface="virtual", channel="checks-unit")
    port = CanPort(can.Bus(interface="virtual", channel="checks-unit"))
    driver = Driver(port, layout)
    at = crc_byte(layout.feedback[0])
    assert at is not None

    def frames(counter: int) -> list[can.Message]:
        return [can.Message(arbitration_id=m.id, is_extended_id=False,
                            data=seal(m.encode({**dict.fromkeys(m.signal_names, 0.0), "counter": counter}), at))
                for m in layout.feedback]

    try:
        for msg in frames(10) + frames(11):
            peer.send(msg)
        good = frames(12)
        bad_crc = bytearray(good[0].data)
        bad_crc[0] ^= 1
        peer.send(can.Message(arbitration_id=0x181, is_extended_id=False, data=bytes(bad_crc)))
        peer.send(can.Message(arbitration_id=0x181, is_extended_id=False, data=bytes(good[0].data) + b"\0"))
        peer.send(frames(9000)[0])  # a valid frame from elsewhere: its counter is far from the count
        for msg in good + frames(13):
            peer.send(msg)
        samples = []
        for _ in range(50):
            samples += driver.receive(0.1)
            if len(samples) >= 4:
                break
        assert [s.counter for s in samples] == [10, 11, 12, 13]
        h = driver.health.snapshot()
        assert h.rejected == {"length": 1, "crc": 1, "counter": 1}
        assert h.lost_samples == 0 and h.counter_restarts == 0
    finally:
        driver.close()
        peer.shutdown()


def test_an_over_long_serial_frame_with_a_valid_crc_is_rejected() -> None:
    frames = dict(SERIAL_FRAMES)
    layout = Layout.from_mapping(frames)
    fb = layout.feedback[0]
    pty = Pty()
    port = SerialPort.open(pty.path, 1_000_000, "binary", layout)
    driver = Driver(port, layout)
    try:
        ok = fb.encode({"position": 0.5, "setpoint_echo": 0.25, "counter": 7, "timestamp_us": 70})
        os.write(pty.master, encode_binary(fb.id, ok + b"\x01\x02") + encode_binary(fb.id, ok))
        samples = []
        for _ in range(50):
            samples += driver.receive(0.1)
            if samples:
                break
        assert [s.counter for s in samples] == [7]
        assert driver.health.rejected["length"] == 1
    finally:
        driver.close()
        pty.close()


class Adversary:
    """A second node on the virtual channel: the feedback id with random bytes, DLC 8 and the layout's own length,
    ``count`` frames (seeded)."""

    def __init__(self, channel: str, frame_id: int, length: int, count: int = 2000) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.rng = np.random.default_rng(7)
        self.sent = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(frame_id, length, count), daemon=True)
        self.thread.start()

    def _run(self, frame_id: int, length: int, count: int) -> None:
        while not self.stop.wait(0.0005) and self.sent < count:
            size = 8 if self.sent % 2 else length
            self.bus.send(can.Message(arbitration_id=frame_id, is_extended_id=False,
                                      data=bytes(self.rng.integers(0, 256, size, dtype=np.uint8))))
            self.sent += 1

    def close(self) -> int:
        self.stop.set()
        self.thread.join()
        self.bus.shutdown()
        return self.sent


def _run(data: dict[str, Any]) -> tuple[BenchSession, Any]:
    case = parse_config(data, "checks.toml").cases[0]
    last: dict[str, Any] = {}
    session = BenchSession(case, plan_link(case), None,
                           lambda e: last.__setitem__("h", e.health) if isinstance(e, BusStatus) else None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        session.run()
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]
    return session, last["h"]


def _offline(data: dict[str, Any]):  # type: ignore[no-untyped-def]
    case = parse_config(data, "checks.toml").cases[0]
    session = BenchSession(case, plan_link(case, direct=True))
    session.run()
    return session.response


@pytest.mark.slow
def test_a_second_node_sending_random_feedback_frames_is_rejected_and_the_sweep_is_right() -> None:
    frames = _crc_layout_mapping()
    data = config(can={"channel": "checks-adversary"}, frames=frames, analysis=FIRST,
                  safety={"feedback_limits": {"position": [-0.5, 0.5]}})
    offline = _offline(data)
    adversary = Adversary("checks-adversary", 0x181, 7)
    try:
        session, health = _run(data)
    finally:
        sent = adversary.close()
    compare(session.response, offline, 0.05, 0.2)
    assert sent > 0 and health.bus.rejected["length"] > 0 and health.bus.rejected["crc"] > 0
    assert health.bus.lost_samples <= health.bus.rejected["counter"]  # never millions lost to one stray counter
    assert not session.refused


def _serial(faults: dict[str, Any]) -> dict[str, Any]:
    frames = dict(SERIAL_FRAMES)
    frames["feedback"] = [{"id": 0x81, "signals": [*SERIAL_FRAMES["feedback"][0]["signals"],
                                                   {"name": "crc", "byte": 14, "type": "uint8"}]}]
    return config(bench={"transport": "serial"}, can=None, serial={"framing": "binary"}, frames=frames,
                  analysis=FIRST, simulator={"faults": {"seed": 5, **faults}},
                  safety={"feedback_limits": {"position": [-0.5, 0.5]}})


@pytest.mark.slow
def test_valid_crc_random_serial_frames_are_rejected_and_the_sweep_is_right() -> None:
    offline = _offline(_serial({}))
    session, health = _run(_serial({"forged": 0.02}))
    compare(session.response, offline, 0.05, 0.2)
    assert health.bus.rejected["crc"] > 0


@pytest.mark.slow
def test_truncated_serial_frames_cost_a_sample_each_and_the_sweep_is_right() -> None:
    offline = _offline(_serial({}))
    session, health = _run(_serial({"truncated": 0.02}))
    compare(session.response, offline, 0.05, 0.2)
    assert health.bus.broken_frames > 0 and health.bus.errors >= health.bus.broken_frames
    # each costs its own sample at most, none unaccounted: a cut frame is dropped as such, or (its header cut
    # too) discarded as bytes between frames
    assert health.bus.lost_samples <= health.bus.errors + health.bus.resyncs


def _point(p: float, q: float) -> ResponsePoint:
    return ResponsePoint(5.0, 1, "position", 0.01, p, q, 10, True, "converged")


def test_a_point_that_cannot_be_physical_is_refused_with_its_reason() -> None:
    assert _absurd_point(_point(0.004, -0.001), (-0.5, 0.5)) == ""
    assert _absurd_point(_point(1e5, 0.0), None) == ""  # no window: nothing to judge the size against
    reason = _absurd_point(_point(300.0, 400.0), (-0.5, 0.5))
    assert reason.startswith("5 Hz position harmonic 1: response amplitude 500 (+94.0 dB) exceeds half")
    assert "safety.feedback_limits.position = [-0.5, 0.5]" in reason
    assert "not finite" in _absurd_point(_point(math.nan, 0.0), (-0.5, 0.5))
