"""Tests of drivers.ports and drivers.driver over python-can's virtual bus and a real pseudo-terminal."""

from __future__ import annotations

import os
import random
import re
import select
import struct
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodebench.drivers import (
    BusHealth,
    CanPort,
    Driver,
    DriverInitError,
    DriverOperationError,
    DriverTimeoutError,
    FeedbackSample,
    Frame,
    Layout,
    LayoutError,
    SerialPort,
    Unwrapper,
    default_layout,
)
from bodebench.drivers.serial_framing import AsciiDeframer, BinaryDeframer, ascii_line, encode_binary

F32 = struct.Struct("<f")


def f32(x: float) -> float:
    """The float32 nearest to ``x`` (what a float32 signal carries)."""
    return F32.unpack(F32.pack(x))[0]


# --------------------------------------------------------------------------------------------------------------
# Unwrapper
@settings(max_examples=200, deadline=None)
@given(
    bits=st.sampled_from([2, 8, 16, 32]),
    start=st.integers(0, 2**32 - 1),
    steps=st.lists(st.integers(-(2**31), 2**31), max_size=40),
)
def test_unwrapper_follows_true_count(bits: int, start: int, steps: list[int]) -> None:
    modulus = 2**bits
    limit = modulus // 2 - 1  # steps strictly smaller than half the modulus are unambiguous
    steps = [max(-limit, min(limit, s)) for s in steps]
    true = start % modulus
    unwrapper = Unwrapper(modulus)
    assert unwrapper.unwrap(true) == true
    for step in steps:
        true += step
        assert unwrapper.unwrap(true % modulus) == true


def test_unwrapper_examples() -> None:
    u = Unwrapper(65536)
    assert [u.unwrap(r) for r in (65534, 65535, 2, 1, 3)] == [65534, 65535, 65538, 65537, 65539]
    with pytest.raises(ValueError, match=r"0..65535"):
        u.unwrap(65536)
    with pytest.raises(ValueError, match=r"modulus"):
        Unwrapper(1)


def test_bus_health_snapshot_is_a_copy() -> None:
    health = BusHealth(frames_in=3)
    copy = health.snapshot()
    health.frames_in = 5
    assert copy.frames_in == 3 and copy is not health


# --------------------------------------------------------------------------------------------------------------
# virtual CAN bus
@pytest.fixture()
def can_pair() -> Iterator[tuple[CanPort, can.BusABC]]:
    channel = f"bodebench-{uuid.uuid4()}"
    port = CanPort(can.Bus(interface="virtual", channel=channel))
    peer = can.Bus(interface="virtual", channel=channel)
    try:
        yield port, peer
    finally:
        port.close()
        peer.shutdown()


def collect(driver: Driver, count: int, limit_s: float = 5.0) -> list[FeedbackSample]:
    """Receive until ``count`` samples arrived (or give up after ``limit_s``), then take what else is queued."""
    samples: list[FeedbackSample] = []
    give_up = time.monotonic() + limit_s
    while len(samples) < count and time.monotonic() < give_up:
        samples.extend(driver.receive(0.2))
    samples.extend(driver.receive(0.05))
    return samples


PeerSend = Callable[[int, int, float], None]  # (feedback index, raw counter, value)


def run_can_scenario(driver: Driver, send: PeerSend, send_raw: Callable[[int, bool, bytes], None],
                     feedback_ids: list[tuple[int, bool]], quantize: Callable[[int, float], float]) -> None:
    """Peer traffic exercising assembly, loss, duplicates, partial samples, wrap, unknown ids and bad frames.

    Counters start just below the uint16 wrap. Value of channel k of sample with raw counter c:
    (c mod 97 - 40) * (k + 1) / 8.
    """

    def value(k: int, c: int) -> float:
        return (c % 97 - 40) * (k + 1) / 8

    def sample(c: int, parts: tuple[int, ...] = (0, 1)) -> None:
        for k in parts:
            send(k, c, value(k, c))

    sample(65533)
    sample(65534)
    send_raw(0x7EE, False, b"\x01\x02")  # an unknown id: ignored
    sample(65535)
    sample(0)  # wrap
    # two samples with their frames interleaved
    send(0, 1, value(0, 1))
    send(0, 2, value(0, 2))
    send(1, 1, value(1, 1))
    send(1, 2, value(1, 2))
    # counter 3 never sent: lost
    sample(4)
    sample(4)  # duplicate
    sample(5, (0,))  # partial: completed by nothing, dropped when 6 completes
    fid, ext = feedback_ids[1]
    send_raw(fid, ext, b"\x00")  # a feedback frame too short to decode
    sample(6)
    expected_raw = [65533, 65534, 65535, 0, 1, 2, 4, 6]
    samples = collect(driver, len(expected_raw))
    assert [s.counter for s in samples] == [65533, 65534, 65535, 65536, 65537, 65538, 65540, 65542]
    for s, c in zip(samples, expected_raw, strict=False):
        assert s.values == pytest.approx((quantize(0, value(0, c)), quantize(1, value(1, c))), rel=0, abs=1e-9)
        assert s.receive_time > 0
    h = driver.health.snapshot()
    assert h.lost_samples == 1
    assert h.duplicates == 1
    assert h.incomplete_samples == 1
    assert h.errors == 1
    assert f"0x{fid:X}" in h.last_error
    assert h.frames_in == 2 * 9 + 1 + 1 + 1  # 9 full samples sent (incl. duplicate), partial, unknown, short
    assert h.bus_state == "active"


def test_virtual_bus_default_layout(can_pair: tuple[CanPort, can.BusABC]) -> None:
    port, peer = can_pair
    layout = default_layout()
    driver = Driver(port, layout)
    names = ("position", "setpoint_echo")

    def send(k: int, counter: int, value: float) -> None:
        # payload built with struct, independently of the codecs
        peer.send(can.Message(arbitration_id=0x181 + k, is_extended_id=False, data=struct.pack("<fH", value, counter)))

    def send_raw(fid: int, ext: bool, data: bytes) -> None:
        peer.send(can.Message(arbitration_id=fid, is_extended_id=ext, data=data))

    assert layout.channels == names
    run_can_scenario(driver, send, send_raw, [(0x181, False), (0x182, False)], lambda k, v: f32(v))


def test_virtual_bus_commands(can_pair: tuple[CanPort, can.BusABC]) -> None:
    port, peer = can_pair
    driver = Driver(port, default_layout())
    driver.enable()
    driver.send_setpoint(-0.75, 70000)  # counter wraps modulo 65536
    driver.disable()
    got = [peer.recv(1.0) for _ in range(3)]
    assert all(m is not None for m in got)
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [
        (0x010, b"\x01"),
        (0x201, struct.pack("<fH", -0.75, 70000 - 65536)),
        (0x010, b"\x00"),
    ]
    assert driver.health.frames_out == 3
    with pytest.raises(LayoutError, match=r"setpoint"):
        driver.send_setpoint(1e39, 0)  # does not fit float32
    assert driver.health.frames_out == 3


def fb_frames(counter: int, parts: tuple[int, ...] = (0, 1)) -> list[Frame]:
    """Default-layout feedback frames (built with struct) for ``counter``; position = counter, echo = -counter."""
    return [Frame(0x181 + k, struct.pack("<fH", counter * (1 - 2 * k), counter % 65536)) for k in parts]


def test_partial_sample_limit_and_counter_restart(can_pair: tuple[CanPort, can.BusABC]) -> None:
    port, _ = can_pair
    driver = Driver(port, default_layout())
    frames = [f for c in range(100, 170) for f in fb_frames(c, (0,))]  # 70 partial samples
    assert driver.feed(frames) == []
    assert driver.health.incomplete_samples == 70 - 64  # only 64 are held
    samples = driver.feed(fb_frames(170))
    assert [(s.counter, s.values) for s in samples] == [(170, (170.0, -170.0))]
    assert driver.health.incomplete_samples == 70 and driver.health.lost_samples == 0
    # a small step back is a duplicate; a big one is a restart of the controller's counter
    assert driver.feed(fb_frames(160)) == []
    assert driver.health.duplicates == 1 and driver.health.counter_restarts == 0
    # the restart is believed on the third frame in a row that carries it (the two before are rejected): one frame
    # from elsewhere cannot restart the count
    samples = driver.feed(fb_frames(3) + fb_frames(4) + fb_frames(5, (1,)) + fb_frames(6))
    assert [(s.counter, s.values) for s in samples] == [(171, (4.0, -4.0)), (173, (6.0, -6.0))]  # stays monotonic
    assert driver.health.counter_restarts == 1 and driver.health.rejected["counter"] == 2
    assert driver.health.lost_samples == 0 and driver.health.incomplete_samples == 71


def test_error_frames_are_counted(can_pair: tuple[CanPort, can.BusABC]) -> None:
    port, peer = can_pair
    driver = Driver(port, default_layout())
    peer.send(can.Message(arbitration_id=0x20000080, is_error_frame=True, is_extended_id=True, data=bytes(8)))
    peer.send(can.Message(arbitration_id=0x181, is_extended_id=False, data=struct.pack("<fH", 1.0, 9)))
    peer.send(can.Message(arbitration_id=0x182, is_extended_id=False, data=struct.pack("<fH", 2.0, 9)))
    samples = collect(driver, 1)
    assert [s.values for s in samples] == [(1.0, 2.0)]
    assert driver.health.errors == 1 and "error frame" in driver.health.last_error


def test_timestamp_unwrap(can_pair: tuple[CanPort, can.BusABC]) -> None:
    port, peer = can_pair
    layout = Layout.from_mapping(
        {
            "setpoint": {"id": 0x200, "signals": [{"name": "setpoint", "byte": 0, "type": "int32", "scale": 1e-6}]},
            "feedback": {
                "id": 0x180,
                "signals": [
                    {"name": "position", "byte": 0, "type": "int16", "endian": "big", "scale": 0.01},
                    {"name": "timestamp_us", "byte": 2, "type": "uint32"},
                ],
            },
        },
        "t.toml",
    )
    driver = Driver(port, layout)
    stamps = [2**32 - 1500, 2**32 - 500, 500, 1500]
    for i, t in enumerate(stamps):
        data = struct.pack(">h", -i * 100) + struct.pack("<I", t)
        peer.send(can.Message(arbitration_id=0x180, is_extended_id=False, data=data))
    samples = collect(driver, 4)
    assert [s.counter for s in samples] == [None] * 4
    assert [s.values for s in samples] == [(0.0,), (-1.0,), (-2.0,), (-3.0,)]
    first = samples[0].timestamp
    assert first is not None
    assert [s.timestamp - first for s in samples] == pytest.approx([0.0, 1e-3, 2e-3, 3e-3])  # type: ignore[operator]
    driver.send_setpoint(0.25)
    m = peer.recv(1.0)
    assert m is not None and bytes(m.data) == struct.pack("<i", 250000)


def test_can_open_errors() -> None:
    with pytest.raises(DriverInitError, match=r"'nosuchiface'.*'can9'") as info:
        CanPort.open("nosuchiface", "can9", 500000)
    assert isinstance(info.value.__cause__, Exception)
    port = CanPort.open("virtual", f"bodebench-{uuid.uuid4()}", None, {"receive_own_messages": True})
    try:
        port.send(Frame(0x123, b"\x01", False))
        frames = port.recv(1.0)
        assert [(f.id, f.data) for f in frames] == [(0x123, b"\x01")]
        assert port.frames_in == 1 and port.frames_out == 1
    finally:
        port.close()
    with pytest.raises(DriverOperationError, match=r"closed"):
        port.send(Frame(1, b""))
    port.close()  # twice is fine


class _FailingBus(can.BusABC):
    """A bus whose send raises a chosen python-can exception."""

    def __init__(self, exc: Exception) -> None:
        self._exc = exc
        self.channel_info = "failing"
        super().__init__(channel="failing")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise self._exc

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        raise can.CanOperationError("receive broke")


def test_vendor_errors_are_mapped() -> None:
    port = CanPort(_FailingBus(can.CanOperationError("tx buffer full")))
    with pytest.raises(DriverOperationError, match=r"failing.*send failed.*tx buffer full") as info:
        port.send(Frame(1, b""))
    assert isinstance(info.value.__cause__, can.CanOperationError)
    with pytest.raises(DriverOperationError, match=r"receive failed") as info2:
        port.recv(0.0)
    assert isinstance(info2.value.__cause__, can.CanOperationError)
    port.close()
    port = CanPort(_FailingBus(can.CanTimeoutError("no ack")))
    with pytest.raises(DriverTimeoutError, match=r"timed out"):
        port.send(Frame(1, b""))
    port.close()


# --------------------------------------------------------------------------------------------------------------
# DBC layout on the virtual bus
DBC_TEXT = """VERSION ""

NS_ :

BS_:

BU_: CTRL INST

BO_ 513 SETPOINT: 8 INST
 SG_ SetpointPos : 0|32@1- (0.001,0) [-100000|100000] "mm" CTRL
 SG_ SeqCnt : 32|16@1+ (1,0) [0|65535] "" CTRL

BO_ 385 FEEDBACK1: 6 CTRL
 SG_ ActPos : 0|32@1- (0.001,0) [-2000000|2000000] "mm" INST
 SG_ SeqCnt : 32|16@1+ (1,0) [0|65535] "" INST

BO_ 2147484034 FEEDBACK2: 4 CTRL
 SG_ Current : 0|16@1- (0.01,0) [-300|300] "A" INST
 SG_ SeqCnt : 16|16@1+ (1,0) [0|65535] "" INST

BO_ 16 CONTROL: 1 INST
 SG_ Enable : 0|1@1+ (1,0) [0|1] "" CTRL
"""


def test_virtual_bus_dbc_layout(can_pair: tuple[CanPort, can.BusABC], tmp_path: Path) -> None:
    (tmp_path / "drive.dbc").write_text(DBC_TEXT)
    frames = {
        "dbc": "drive.dbc",
        "setpoint": {"message": "SETPOINT", "signals": {"setpoint": "SetpointPos", "counter": "SeqCnt"}},
        "feedback": [
            {"message": "FEEDBACK1", "signals": {"position": "ActPos", "counter": "SeqCnt"}},
            {"message": "FEEDBACK2", "signals": {"current": "Current", "counter": "SeqCnt"}},
        ],
        "enable": {"message": "CONTROL", "values": {"Enable": 1}},
    }
    layout = Layout.from_mapping(frames, str(tmp_path / "bench.toml"))
    port, peer = can_pair
    driver = Driver(port, layout)
    scale = (0.001, 0.01)

    def send(k: int, counter: int, value: float) -> None:
        raw = round(value / scale[k])
        if k == 0:
            peer.send(can.Message(arbitration_id=0x181, is_extended_id=False, data=struct.pack("<iH", raw, counter)))
        else:
            peer.send(can.Message(arbitration_id=0x182, is_extended_id=True, data=struct.pack("<hH", raw, counter)))

    def send_raw(fid: int, ext: bool, data: bytes) -> None:
        peer.send(can.Message(arbitration_id=fid, is_extended_id=ext, data=data))

    run_can_scenario(driver, send, send_raw, [(0x181, False), (0x182, True)],
                     lambda k, v: round(v / scale[k]) * scale[k])
    driver.enable()
    driver.send_setpoint(12.345, 65537)
    got = [peer.recv(1.0) for _ in range(2)]
    assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in got if m is not None] == [
        (0x10, False, b"\x01"),
        (0x201, False, struct.pack("<iH", 12345, 1) + b"\x00\x00"),
    ]


# --------------------------------------------------------------------------------------------------------------
# serial line over a pseudo-terminal
SERIAL_TABLE: dict[str, Any] = {
    "setpoint": {"id": 0x21, "signals": [{"name": "setpoint", "byte": 0, "type": "float32"},
                                         {"name": "counter", "byte": 4, "type": "uint8"}]},
    "feedback": [
        {"id": 0x11, "signals": [{"name": "position", "byte": 0, "type": "float32"},
                                 {"name": "counter", "byte": 4, "type": "uint8"}]},
        {"id": 0x12, "signals": [{"name": "counter", "byte": 0, "type": "uint8"},
                                 {"name": "pressure_a", "byte": 1, "type": "int16", "endian": "big", "scale": 0.5}]},
    ],
    "enable": {"id": 0x01, "data": [1]},
    "disable": {"id": 0x01, "data": [0]},
}


@pytest.fixture()
def pty_pair() -> Iterator[tuple[int, str]]:
    master, slave = os.openpty()
    try:
        yield master, os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


def wire_frame(framing: str, fid: int, fields: list[str], payload: bytes) -> bytes:
    return encode_binary(fid, payload) if framing == "binary" else ascii_line(fid, fields)


def feedback_wire(framing: str, k: int, counter: int, value: float) -> bytes:
    """Feedback frame k built by hand: struct payloads and hand-formatted ASCII fields."""
    if k == 0:
        return wire_frame(framing, 0x11, [repr(f32(value)), str(counter)], struct.pack("<fB", value, counter))
    raw = round(value / 0.5)
    return wire_frame(framing, 0x12, [str(counter), repr(raw * 0.5)], struct.pack(">Bh", counter, raw))


@pytest.mark.parametrize("framing", ["binary", "ascii"])
def test_serial_over_pty(pty_pair: tuple[int, str], framing: str) -> None:
    master, path = pty_pair
    layout = Layout.from_mapping(SERIAL_TABLE, "serial.toml")
    # the writer below pauses inside frames, for however long a busy machine makes its sleeps: this test is about
    # deframing and resynchronising, so a frame is taken as cut short only after a silence far beyond those pauses
    port = SerialPort.open(path, 115200, framing, layout, frame_gap_s=5.0)
    driver = Driver(port, layout)
    rng = random.Random(7 if framing == "binary" else 8)
    forbidden = 0xAA if framing == "binary" else ord("$")
    n = 40
    corrupt = 17  # the second frame of this sample is damaged: CRC/checksum error, sample incomplete
    skipped = 23  # never sent: lost
    chunks = []
    for i in range(n):
        counter = (200 + i) % 256  # wraps the uint8 counter
        if i == skipped:
            continue
        for k in (0, 1):
            wire = bytearray(feedback_wire(framing, k, counter, (i - 10) * 1.25 * (k + 1)))
            if i == corrupt and k == 1:
                wire[-4] ^= 0x01
            chunks.append(bytes(wire))
            filler = [b for b in range(256) if b != forbidden]
            chunks.append(bytes(rng.choice(filler) for _ in range(rng.randint(0, 9))))
    stream = b"".join(chunks)

    def writer() -> None:
        pos = 0
        while pos < len(stream):
            size = rng.randint(1, 40)
            os.write(master, stream[pos : pos + size])
            pos += size
            time.sleep(0.0005)

    thread = threading.Thread(target=writer)
    thread.start()
    try:
        samples = collect(driver, n - 2)
    finally:
        thread.join()
    expected = [i for i in range(n) if i not in (corrupt, skipped)]
    assert [s.counter for s in samples] == [200 + i for i in expected]
    for s, i in zip(samples, expected, strict=False):
        assert s.values == (f32((i - 10) * 1.25), round((i - 10) * 2.5 / 0.5) * 0.5)
    h = driver.health
    assert h.lost_samples == 1 and h.incomplete_samples == 1 and h.duplicates == 0
    assert h.errors == 1
    assert port.resyncs > 0 and port.bytes_discarded > 0

    # the other direction: read what the driver sends from the master end
    driver.enable()
    driver.send_setpoint(3.5, 300)
    deframer = BinaryDeframer() if framing == "binary" else AsciiDeframer()
    got: list[Any] = []
    give_up = time.monotonic() + 5.0
    while len(got) < 2 and time.monotonic() < give_up:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            got.extend(deframer.feed(os.read(master, 1024)))
    if framing == "binary":
        assert got == [(0x01, b"\x01"), (0x21, struct.pack("<fB", 3.5, 300 % 256))]
    else:
        assert got == [(0x01, ["01"]), (0x21, ["3.5", "44"])]
    driver.close()
    assert port.closed


def test_serial_send_times_out_on_a_line_that_does_not_drain(pty_pair: tuple[int, str]) -> None:
    """Nobody reads the far end: sends go out until the tty's buffer is full, then one waits send_timeout and
    fails with the port's name; once the far end reads, sending works again."""
    import serial

    master, path = pty_pair
    layout = Layout.from_mapping(SERIAL_TABLE, "serial.toml")
    port = SerialPort(serial.Serial(path, 115200, timeout=0), "binary", layout, name=f"serial {path}",
                      send_timeout=0.2)
    frame = Frame(0x21, struct.pack("<fB", 1.0, 1))
    sent = 0
    with pytest.raises(DriverTimeoutError, match=re.escape(path)) as info:
        for _ in range(1_000_000):
            start = time.monotonic()
            port.send(frame)
            sent += 1
    waited = time.monotonic() - start
    assert 0.2 <= waited < 1.0, waited
    assert "unsent" in str(info.value)
    assert port.frames_out == sent > 100
    drained = 0
    while select.select([master], [], [], 0.05)[0]:
        drained += len(os.read(master, 65536))
    assert drained >= sent * len(encode_binary(0x21, frame.data))
    port.send(frame)
    assert port.frames_out == sent + 1
    port.close()


def test_serial_far_end_hanging_up_is_an_error_at_once() -> None:
    """The far end of the line goes away while the port waits for a frame: an operation error naming the port,
    long before the wait would have ended, not a silent spin."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    layout = Layout.from_mapping(SERIAL_TABLE, "serial.toml")
    port = SerialPort.open(path, 115200, "binary", layout)
    os.close(master)
    os.close(slave)
    start = time.monotonic()
    with pytest.raises(DriverOperationError, match=re.escape(path)):
        port.recv(5.0)
    assert time.monotonic() - start < 1.0
    port.close()


def test_serial_ascii_unknown_id_and_bad_fields() -> None:
    layout = Layout.from_mapping(SERIAL_TABLE, "serial.toml")
    port = SerialPort.open("loop://", 115200, "ascii", layout)
    driver = Driver(port, layout)
    try:
        port._ser.write(ascii_line(0x55, ["1"]) + ascii_line(0x11, ["x", "1"]) + ascii_line(0x11, ["1.0", "300"]))
        port._ser.write(feedback_wire("ascii", 0, 5, 2.0) + feedback_wire("ascii", 1, 5, -4.0))
        samples = collect(driver, 1)
        assert [(s.counter, s.values) for s in samples] == [(5, (2.0, -4.0))]
        assert port.ignored == 1
        assert driver.health.errors == 2
        assert "0x11" in driver.health.last_error
    finally:
        driver.close()


def test_serial_open_errors() -> None:
    layout = Layout.from_mapping(SERIAL_TABLE, "serial.toml")
    with pytest.raises(DriverInitError, match=r"/dev/no-such-tty") as info:
        SerialPort.open("/dev/no-such-tty", 9600, "binary", layout)
    assert info.value.__cause__ is not None
    with pytest.raises(LayoutError, match=r"framing"):
        SerialPort.open("loop://", 9600, "hex", layout)
    with pytest.raises(LayoutError, match=r"0x201 exceeds 0xFF"):
        SerialPort.open("loop://", 9600, "binary", default_layout())
