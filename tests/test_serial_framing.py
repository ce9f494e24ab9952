"""Tests of drivers.serial_framing: CRC, binary frames and ASCII lines, and their incremental deframers."""

from __future__ import annotations

import binascii
import functools
import math
import operator
import random
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodebench.drivers import LayoutError, Message, Signal, default_layout
from bodebench.drivers.serial_framing import (
    AsciiDeframer,
    BinaryDeframer,
    ascii_line,
    ascii_payload,
    crc16_ccitt_false,
    encode_ascii,
    encode_binary,
    format_value,
)


# --------------------------------------------------------------------------------------------------------------
# CRC
def bitwise_crc(data: bytes) -> int:
    """CRC-16/CCITT-FALSE, one bit at a time, straight from the definition."""
    crc = 0xFFFF
    for byte in data:
        for bit in range(7, -1, -1):
            feedback = ((crc >> 15) & 1) ^ ((byte >> bit) & 1)
            crc = (crc << 1) & 0xFFFF
            if feedback:
                crc ^= 0x1021
    return crc


def test_crc_check_value() -> None:
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    assert crc16_ccitt_false(b"") == 0xFFFF


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=80))
def test_crc_matches_references(data: bytes) -> None:
    expected = bitwise_crc(data)
    assert crc16_ccitt_false(data) == expected
    assert binascii.crc_hqx(data, 0xFFFF) == expected
    # chaining over a split gives the same value
    half = len(data) // 2
    assert crc16_ccitt_false(data[half:], crc16_ccitt_false(data[:half])) == expected


# --------------------------------------------------------------------------------------------------------------
# binary frames
def test_encode_binary_layout() -> None:
    payload = bytes([0x00, 0x00, 0xC0, 0x3F, 0x02, 0x01])
    frame = encode_binary(0x21, payload)
    body = bytes([0x21, 6]) + payload
    assert frame == b"\xaa\x55" + body + struct.pack(">H", bitwise_crc(body))
    assert frame.hex() == "aa552106 0000c03f0201 80d3".replace(" ", "")  # the example in PROTOCOL.md
    assert encode_binary(0x05, b"") == b"\xaa\x55\x05\x00" + struct.pack(">H", bitwise_crc(b"\x05\x00"))


def test_encode_binary_limits() -> None:
    with pytest.raises(LayoutError, match=r"id"):
        encode_binary(256, b"")
    with pytest.raises(LayoutError, match=r"65 bytes"):
        encode_binary(1, bytes(65))
    assert len(encode_binary(255, bytes(64))) == 70


def frames_strategy() -> st.SearchStrategy[list[tuple[int, bytes]]]:
    return st.lists(st.tuples(st.integers(0, 255), st.binary(max_size=64)), max_size=12)


def split(data: bytes, rng: random.Random) -> list[bytes]:
    """Cut ``data`` into random-sized pieces (including empty ones)."""
    pieces = []
    pos = 0
    while pos < len(data):
        size = rng.choice([0, 1, 1, 2, 3, 7, 20, 100])
        pieces.append(data[pos : pos + size])
        pos += size
    return pieces


def feed_all(deframer: BinaryDeframer | AsciiDeframer, pieces: list[bytes]) -> list:
    out = []
    for piece in pieces:
        out.extend(deframer.feed(piece))
    return out


@settings(max_examples=150, deadline=None)
@given(
    frames=frames_strategy(),
    gaps=st.lists(st.binary(max_size=30).map(lambda b: b.replace(b"\xaa", b"")), min_size=13, max_size=13),
    seed=st.integers(0, 2**32 - 1),
)
def test_binary_recovers_frames_between_garbage_without_aa(
    frames: list[tuple[int, bytes]], gaps: list[bytes], seed: int
) -> None:
    stream = b"".join(gaps[i] + encode_binary(fid, payload) for i, (fid, payload) in enumerate(frames))
    stream += gaps[len(frames)]
    deframer = BinaryDeframer()
    assert feed_all(deframer, split(stream, random.Random(seed))) == frames
    assert deframer.frames == len(frames)
    assert deframer.crc_errors == 0
    assert deframer.bytes_discarded == sum(len(g) for g in gaps[: len(frames) + 1])
    assert deframer.resyncs == sum(1 for g in gaps[: len(frames) + 1] if g)
    assert deframer.pending == 0


def reference_deframe(stream: bytes) -> list[tuple[int, int, bytes]]:
    """Whole-stream deframer by definition: at each position, a valid frame is taken whole, else move one byte.
    Returns (position, id, payload)."""
    out = []
    i = 0
    while i + 6 <= len(stream):
        if stream[i : i + 2] == b"\xaa\x55" and stream[i + 3] <= 64:
            end = i + 6 + stream[i + 3]
            if end <= len(stream) and binascii.crc_hqx(stream[i + 2 : end - 2], 0xFFFF) == int.from_bytes(
                stream[end - 2 : end], "big"
            ):
                out.append((i, stream[i + 2], stream[i + 4 : end - 2]))
                i = end
                continue
        i += 1
    return out


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(
    frames=frames_strategy(),
    gaps=st.lists(
        st.lists(st.sampled_from([0xAA, 0x55, 0x00, 0x40, 0x41, 0x07]) | st.integers(0, 255), max_size=30).map(bytes),
        min_size=13,
        max_size=13,
    ),
    seed=st.integers(0, 2**32 - 1),
)
def test_binary_arbitrary_garbage(frames: list[tuple[int, bytes]], gaps: list[bytes], seed: int) -> None:
    starts = []
    stream = b""
    for i, (fid, payload) in enumerate(frames):
        stream += gaps[i]
        starts.append(len(stream))
        stream += encode_binary(fid, payload)
    # a tail without 0xAA longer than any frame settles every candidate frame start
    stream += gaps[len(frames)] + bytes(70)
    deframer = BinaryDeframer()
    got = feed_all(deframer, split(stream, random.Random(seed)))
    reference = reference_deframe(stream)
    assert got == [(fid, payload) for _, fid, payload in reference]
    # every real frame is recovered, unless garbage happened to form a valid frame that covers its start
    taken = {pos for pos, _, _ in reference}
    spans = [(pos, pos + 6 + len(payload)) for pos, _, payload in reference]
    for start in starts:
        assert start in taken or any(lo < start < hi for lo, hi in spans)
    assert deframer.frames == len(reference)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=50), max_size=20))
def test_binary_never_raises(pieces: list[bytes]) -> None:
    deframer = BinaryDeframer()
    for piece in pieces:
        for fid, payload in deframer.feed(piece):
            assert 0 <= fid <= 255 and len(payload) <= 64
    assert deframer.pending <= 70


def test_binary_partial_frame_waits() -> None:
    frame = encode_binary(3, b"abc")
    deframer = BinaryDeframer()
    for byte in frame[:-1]:
        assert deframer.feed(bytes([byte])) == []
    assert deframer.feed(frame[-1:]) == [(3, b"abc")]
    assert deframer.bytes_discarded == 0


def test_binary_bad_frame_does_not_swallow_the_next_one() -> None:
    good = encode_binary(7, b"\x01\x02\x03")
    # a frame whose header claims 20 bytes but is cut short: its claimed payload covers the good frame
    truncated = b"\xaa\x55\x09\x14\x00\x00"
    deframer = BinaryDeframer()
    assert deframer.feed(truncated + good + bytes(20)) == [(7, b"\x01\x02\x03")]
    assert deframer.crc_errors == 1


def test_binary_sync_inside_bad_payload() -> None:
    inner = encode_binary(5, b"xy")
    bad = bytearray(encode_binary(4, b"\x00" + inner + b"\x00"))
    bad[-1] ^= 0xFF  # break the outer CRC
    after = encode_binary(6, b"z")
    deframer = BinaryDeframer()
    assert deframer.feed(bytes(bad) + after) == [(5, b"xy"), (6, b"z")]
    assert deframer.crc_errors == 1


def test_binary_length_above_64_is_skipped() -> None:
    deframer = BinaryDeframer()
    good = encode_binary(1, b"q")
    assert deframer.feed(b"\xaa\x55\x01\x41" + good) == [(1, b"q")]
    assert deframer.crc_errors == 0 and deframer.bytes_discarded == 4 and deframer.resyncs == 1


def test_binary_trailing_aa_is_kept() -> None:
    deframer = BinaryDeframer()
    frame = encode_binary(2, b"")
    assert deframer.feed(b"\x10\x20" + frame[:1]) == []
    assert deframer.feed(frame[1:]) == [(2, b"")]
    assert deframer.bytes_discarded == 2


# --------------------------------------------------------------------------------------------------------------
# ASCII lines
def xor(text: str) -> int:
    return functools.reduce(operator.xor, text.encode(), 0)


def test_ascii_checksum_and_examples() -> None:
    layout = default_layout()
    line = encode_ascii(layout.setpoint, {"setpoint": 1.5, "counter": 258})
    assert line == f"$201,1.5,258*{xor('201,1.5,258'):02X}\r\n".encode()
    assert line == b"$201,1.5,258*26\r\n"
    assert layout.enable is not None
    assert encode_ascii(layout.enable) == f"$10,01*{xor('10,01'):02X}\r\n".encode()
    # float32 values are sent as the payload holds them
    fb = encode_ascii(layout.feedback[0], {"position": 0.1, "counter": 1})
    assert fb.split(b",")[1] == repr(struct.unpack("<f", struct.pack("<f", 0.1))[0]).encode()


def test_ascii_errors() -> None:
    layout = default_layout()
    with pytest.raises(LayoutError, match=r"counter"):
        encode_ascii(layout.setpoint, {"setpoint": 1.0, "counter": 70000})
    with pytest.raises(LayoutError, match=r"id"):
        ascii_line(0x1000, [])
    with pytest.raises(LayoutError, match=r"more than 256"):
        ascii_line(1, ["1" * 300])
    with pytest.raises(LayoutError, match=r"expected 2 fields"):
        ascii_payload(layout.setpoint, ["1.0"])
    with pytest.raises(LayoutError, match=r"not a number"):
        ascii_payload(layout.setpoint, ["one", "2"])


@pytest.mark.parametrize("value", [0.0, -0.0, 1.0, -3.0, 0.1, 1e-300, 123456789.125, -2.5e20])
def test_format_value_reads_back(value: float) -> None:
    back = float(format_value(value))
    assert back == value and math.copysign(1.0, back) == math.copysign(1.0, value)


def ascii_messages() -> list[Message]:
    return [
        Message("a", 0x12, signals=(Signal("x", 0, "float64"), Signal("n", 8, "int16"))),
        Message("b", 0x3A0, signals=(Signal("y", 0, "int32", scale=0.001),)),
        Message("c", 0x05, data=b"\x01\xfe"),
    ]


@st.composite
def ascii_items(draw: st.DrawFn) -> tuple[Message, dict[str, float]]:
    msg = draw(st.sampled_from(ascii_messages()))
    if msg.name == "a":
        return msg, {"x": draw(st.floats(allow_nan=False, allow_infinity=False)), "n": draw(st.integers(-32768, 32767))}
    if msg.name == "b":
        return msg, {"y": draw(st.integers(-(2**31), 2**31 - 1)) * 0.001}
    return msg, {}


@settings(max_examples=150, deadline=None)
@given(
    items=st.lists(ascii_items(), max_size=10),
    gaps=st.lists(st.binary(max_size=30).map(lambda b: b.replace(b"$", b"")), min_size=11, max_size=11),
    seed=st.integers(0, 2**32 - 1),
)
def test_ascii_recovers_lines_between_garbage_without_dollar(
    items: list[tuple[Message, dict[str, float]]], gaps: list[bytes], seed: int
) -> None:
    stream = b"".join(gaps[i] + encode_ascii(msg, values) for i, (msg, values) in enumerate(items))
    stream += gaps[len(items)]
    deframer = AsciiDeframer()
    got = feed_all(deframer, split(stream, random.Random(seed)))
    assert [fid for fid, _ in got] == [msg.id for msg, _ in items]
    for (msg, values), (_, fields) in zip(items, got, strict=False):
        payload = ascii_payload(msg, fields)
        assert payload == msg.encode(values)  # the line carries exactly what the binary payload holds
    assert deframer.frames == len(items)
    assert deframer.crc_errors == 0 and deframer.format_errors == 0
    assert deframer.bytes_discarded == sum(len(g) for g in gaps[: len(items) + 1])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=60) | st.sampled_from([b"$", b"*", b"\r\n", b"$1,2*03\r\n", b"$AB*"]), max_size=30))
def test_ascii_never_raises(pieces: list[bytes]) -> None:
    deframer = AsciiDeframer()
    for piece in pieces:
        for fid, fields in deframer.feed(piece):
            assert 0 <= fid <= 0xFFF and all(isinstance(f, str) for f in fields)
    assert deframer.pending <= 257


def test_ascii_rejects_and_recovers() -> None:
    good = ascii_line(0x21, ["1.5", "3"])
    bad_checksum = good.replace(b"1.5", b"1.6")
    deframer = AsciiDeframer()
    stream = (b"$$garbage" + bad_checksum + b"$12,x" + good + b"no-star\n" + b"$21,1.5,3*3G\r\n"
              + good.replace(b"\r", b""))
    assert deframer.feed(stream) == [(0x21, ["1.5", "3"]), (0x21, ["1.5", "3"])]
    assert deframer.crc_errors == 1
    assert deframer.format_errors == 1  # the "*3G" line; "no-star" had no '$' and is plain garbage


def test_ascii_long_line_is_discarded() -> None:
    deframer = AsciiDeframer()
    long_body = "01," + ",".join(["1"] * 200)
    long_line = f"${long_body}*{xor(long_body):02X}\r\n".encode()
    assert len(long_line) > 256
    good = ascii_line(0x01, ["2"])
    assert feed_all(deframer, split(long_line + good, random.Random(1))) == [(1, ["2"])]
    assert deframer.format_errors == 1


def test_ascii_lower_case_hex_accepted() -> None:
    body = "1a,ff"
    line = f"${body}*{xor(body):02x}\n".encode()
    assert AsciiDeframer().feed(line) == [(0x1A, ["ff"])]


def test_a_write_that_stalls_is_retried_until_the_line_takes_it() -> None:
    """The far end stops reading until the pty's buffer is full, then reads again: the send waits and completes
    (within its budget) instead of failing; with no reader at all it fails naming the stall."""
    import os
    import threading

    from test_bench_e2e import SERIAL_FRAMES

    from bodebench.drivers.errors import DriverTimeoutError
    from bodebench.drivers.layout import Layout
    from bodebench.drivers.ports import Frame, SerialPort
    from bodebench.sim.pty_link import Pty

    layout = Layout.from_mapping(SERIAL_FRAMES)
    frame = Frame(0x21, bytes.fromhex("0000c03f0201"))
    for budget, reader in ((30.0, True), (0.2, False)):
        pty = Pty()
        port = SerialPort.open(pty.path, 1_000_000, "binary", layout, send_timeout=budget)
        fd = port._fd
        assert fd is not None
        try:
            # fill the line until it takes not one byte more, also after the kernel has had time to move what
            # it holds on to the far side's buffer (late on a busy machine): three quiet rounds in a row
            quiet = 0
            while quiet < 3:
                took = False
                for chunk in (512, 1):
                    while True:
                        try:
                            os.write(fd, b"\0" * chunk)
                        except BlockingIOError:
                            break
                        took = True
                quiet = 0 if took else quiet + 1
                threading.Event().wait(0.05)
            drained = bytearray()
            frame_bytes = encode_binary(0x21, frame.data)
            if reader:
                def drain(frame_bytes: bytes = frame_bytes, drained: bytearray = drained, pty: Pty = pty) -> None:
                    while frame_bytes not in drained:
                        try:
                            drained.extend(os.read(pty.master, 65536))
                        except BlockingIOError:
                            threading.Event().wait(0.01)
                timer = threading.Timer(0.3, drain)
                timer.start()
                port.send(frame)
                timer.join()
                assert frame_bytes in drained  # it went out whole, after the stall
            else:
                with pytest.raises(DriverTimeoutError, match="stalled for 0.2 s"):
                    port.send(frame)
        finally:
            port.close()
            pty.close()
