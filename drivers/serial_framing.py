"""Framing of messages on a serial line (pure: bytes in, frames out; see drivers/PROTOCOL.md).

Binary framing::

    0xAA 0x55 | id (1 byte) | len (1 byte, 0..64) | payload (len bytes) | CRC-16/CCITT-FALSE (2 bytes, big-endian)

with the CRC (poly 0x1021, init 0xFFFF, no reflection, xorout 0) taken over id, len and payload.

ASCII-line framing::

    $<id, 2-3 hex digits>,<v1>,<v2>,...*<checksum, 2 hex digits>\\r\\n

where the checksum is the XOR of the characters between ``$`` and ``*``, the values are the message's signals in
layout order as physical decimal numbers, and a fixed-data message carries its payload as one hex field.

The deframers accept arbitrary bytes in arbitrary pieces and never raise; they count what they reject.
"""

from __future__ import annotations

import binascii
import math
from collections.abc import Mapping, Sequence

from .codec import Codec
from .errors import LayoutError

__all__ = [
    "ASCII_MAX_ID",
    "ASCII_MAX_LINE",
    "BINARY_MAX_ID",
    "BINARY_MAX_PAYLOAD",
    "SYNC",
    "AsciiDeframer",
    "BinaryDeframer",
    "ascii_checksum",
    "ascii_line",
    "ascii_payload",
    "crc16_ccitt_false",
    "encode_ascii",
    "encode_binary",
    "format_value",
]

SYNC = b"\xaa\x55"
"""Start-of-frame pattern of the binary framing."""
BINARY_MAX_PAYLOAD = 64
"""Largest payload of a binary frame (bytes)."""
BINARY_MAX_ID = 0xFF
"""Largest id of a binary frame (one byte)."""
ASCII_MAX_ID = 0xFFF
"""Largest id of an ASCII line (three hex digits)."""
ASCII_MAX_LINE = 256
"""Longest accepted ASCII line in characters, ``$`` through ``\\n`` included."""


def crc_table(poly: int, bits: int) -> tuple[int, ...]:
    """Byte-wise lookup table of a ``bits``-wide CRC with polynomial ``poly``, not reflected (most significant bit
    first)."""
    top, mask = 1 << (bits - 1), (1 << bits) - 1
    table = []
    for byte in range(256):
        crc = byte << (bits - 8)
        for _ in range(8):
            crc = ((crc << 1) ^ poly) if crc & top else (crc << 1)
            crc &= mask
        table.append(crc)
    return tuple(table)


def crc16_ccitt_false(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF, no reflection, xorout 0); pass ``crc`` to chain.
    The standard library's ``binascii.crc_hqx`` computes this CRC; with init 0xFFFF it is this variant."""
    return binascii.crc_hqx(data, crc)


def encode_binary(frame_id: int, payload: bytes) -> bytes:
    """Binary frame for ``frame_id`` (0..255) and ``payload`` (0..64 bytes); LayoutError when either does not fit."""
    if not isinstance(frame_id, int) or isinstance(frame_id, bool) or not 0 <= frame_id <= BINARY_MAX_ID:
        raise LayoutError(f"binary serial framing: id must be 0..0x{BINARY_MAX_ID:X}, got {frame_id!r}")
    if len(payload) > BINARY_MAX_PAYLOAD:
        raise LayoutError(
            f"binary serial framing: payload of id 0x{frame_id:02X} is {len(payload)} bytes, "
            f"more than {BINARY_MAX_PAYLOAD}"
        )
    body = bytes((frame_id, len(payload))) + bytes(payload)
    return SYNC + body + crc16_ccitt_false(body).to_bytes(2, "big")


class _Counters:
    """Counters shared by both deframers."""

    def __init__(self) -> None:
        self.frames = 0
        """Frames accepted."""
        self.crc_errors = 0
        """Frames rejected for a wrong CRC (binary) or checksum (ASCII)."""
        self.bytes_discarded = 0
        """Bytes dropped while looking for the start of a frame (garbage, rejected frames)."""
        self.resyncs = 0
        """Times frame alignment was lost: runs of discarded bytes between two accepted frames."""
        self._in_gap = False
        self._buf = bytearray()  # the bytes of a frame not yet complete

    def _discard(self, count: int) -> None:
        if count > 0:
            self.bytes_discarded += count
            if not self._in_gap:
                self.resyncs += 1
                self._in_gap = True

    def _accept(self) -> None:
        self.frames += 1
        self._in_gap = False

    def drop_pending(self) -> int:
        """Discard the bytes held for an unfinished frame (one that will never be finished); returns how many."""
        buf = self._buf
        count = len(buf)
        self._discard(count)
        buf.clear()
        return count


class BinaryDeframer(_Counters):
    """Incremental binary deframer: ``feed(bytes) -> [(id, payload), ...]``; never raises.

    A partial frame waits for more data. On a CRC failure only the first sync byte is dropped and the scan resumes
    from the next byte, so a good frame that a bad frame's claimed length covered is still found. A sync pattern
    followed by a length above 64 is not a frame start and is skipped the same way.
    """

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[tuple[int, bytes]]:
        """Consume ``data``; return the frames completed by it as ``(id, payload)`` in stream order."""
        buf = self._buf
        try:
            buf += data
        except TypeError:
            return []
        out: list[tuple[int, bytes]] = []
        pos = 0
        n = len(buf)
        while True:
            start = buf.find(SYNC, pos)
            if start < 0:
                keep = 1 if n > pos and buf[n - 1] == SYNC[0] else 0  # maybe the first half of a sync pattern
                self._discard(n - keep - pos)
                pos = n - keep
                break
            self._discard(start - pos)
            pos = start
            if n - pos < 4:
                break
            length = buf[pos + 3]
            if length > BINARY_MAX_PAYLOAD:
                self._discard(1)
                pos += 1
                continue
            end = pos + 6 + length
            if end > n:
                break
            if crc16_ccitt_false(memoryview(buf)[pos + 2 : end - 2]) == (buf[end - 2] << 8 | buf[end - 1]):
                out.append((buf[pos + 2], bytes(buf[pos + 4 : end - 2])))
                self._accept()
                pos = end
            else:
                self.crc_errors += 1
                self._discard(1)
                pos += 1
        del buf[:pos]
        return out


def format_value(value: float) -> str:
    """Decimal text of a physical value: integral values without a decimal point, others (and -0.0) as Python
    ``repr`` (the shortest text that reads back to the same double)."""
    v = float(value)
    if v == v and abs(v) < 2.0**53 and v == int(v) and not (v == 0 and math.copysign(1.0, v) < 0):
        return str(int(v))
    return repr(v)


def ascii_checksum(text: str) -> int:
    """XOR of the character codes of ``text`` (the characters between ``$`` and ``*``)."""
    result = 0
    for ch in text.encode("ascii"):
        result ^= ch
    return result


def ascii_line(frame_id: int, fields: Sequence[str]) -> bytes:
    """ASCII line for ``frame_id`` (0..0xFFF) with the given field texts; LayoutError when it does not fit."""
    if not isinstance(frame_id, int) or isinstance(frame_id, bool) or not 0 <= frame_id <= ASCII_MAX_ID:
        raise LayoutError(f"ASCII serial framing: id must be 0..0x{ASCII_MAX_ID:X}, got {frame_id!r}")
    for text in fields:
        if any(ch in text for ch in "$*,\r\n") or not text.isascii():
            raise LayoutError(f"ASCII serial framing: field {text!r} of id 0x{frame_id:X} holds a reserved character")
    body = ",".join([f"{frame_id:02X}" if frame_id <= 0xFF else f"{frame_id:03X}", *fields])
    line = f"${body}*{ascii_checksum(body):02X}\r\n"
    if len(line) > ASCII_MAX_LINE:
        raise LayoutError(
            f"ASCII serial framing: line for id 0x{frame_id:X} is {len(line)} characters, more than {ASCII_MAX_LINE}"
        )
    return line.encode("ascii")


def encode_ascii(message: Codec, values: Mapping[str, float] | None = None) -> bytes:
    """ASCII line for ``message``: its signals in layout order as physical numbers, or its fixed data as hex.

    The values are first encoded with the message's codec (LayoutError when missing or out of range) and the
    quantized values (as the binary payload holds them) are written, so both framings carry the same numbers.
    """
    if message.data is not None:
        return ascii_line(message.id, [message.data.hex().upper()])
    decoded = message.decode(message.encode(values if values is not None else {}))
    return ascii_line(message.id, [format_value(decoded[name]) for name in message.signal_names])


def ascii_payload(message: Codec, fields: Sequence[str]) -> bytes:
    """Binary payload of ``message`` from the fields of an ASCII line (inverse of ``encode_ascii``).

    Raises LayoutError naming the message when the number of fields is wrong, a field is not a number (hex for
    fixed-data messages) or a value does not fit its signal.
    """
    if message.data is not None:
        if len(fields) != 1:
            raise LayoutError(f"message {message.name!r}: expected 1 hex field, got {len(fields)}")
        try:
            return bytes.fromhex(fields[0])
        except ValueError as exc:
            raise LayoutError(f"message {message.name!r}: field {fields[0]!r} is not hex") from exc
    names = message.signal_names
    if len(fields) != len(names):
        raise LayoutError(f"message {message.name!r}: expected {len(names)} fields, got {len(fields)}")
    values: dict[str, float] = {}
    for name, text in zip(names, fields, strict=True):
        try:
            values[name] = float(text)
        except ValueError as exc:
            raise LayoutError(f"message {message.name!r} signal {name!r}: {text!r} is not a number") from exc
    return message.encode(values)


_HEX = frozenset("0123456789abcdefABCDEF")


class AsciiDeframer(_Counters):
    """Incremental ASCII-line deframer: ``feed(bytes) -> [(id, [field text, ...]), ...]``; never raises.

    Returns the raw field texts after the id (convert them with ``ascii_payload``). A line starts at ``$`` and ends
    at ``\\n`` (a ``\\r`` before it is optional); a ``$`` inside a line restarts the line there. Lines longer than
    ``ASCII_MAX_LINE`` characters are discarded. Besides the shared counters, ``format_errors`` counts terminated
    lines that do not follow the grammar (no ``*``, bad id, non-printable characters, too long).
    """

    def __init__(self) -> None:
        super().__init__()
        self.format_errors = 0

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the end of a line."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[tuple[int, list[str]]]:
        """Consume ``data``; return the lines completed by it as ``(id, fields)`` in stream order."""
        buf = self._buf
        try:
            buf += data
        except TypeError:
            return []
        out: list[tuple[int, list[str]]] = []
        pos = 0
        n = len(buf)
        while pos < n:
            start = buf.find(b"$", pos)
            if start < 0:
                self._discard(n - pos)
                pos = n
                break
            self._discard(start - pos)
            pos = start
            newline = buf.find(b"\n", pos)
            stop = newline if newline >= 0 else n
            last = buf.rfind(b"$", pos, stop)
            if last > pos:  # an unterminated line: the frame starts at the last '$'
                self._discard(last - pos)
                pos = last
            if newline < 0:
                if n - pos > ASCII_MAX_LINE:
                    self.format_errors += 1
                    self._discard(n - pos)
                    pos = n
                break
            line = bytes(buf[pos : newline + 1])
            pos = newline + 1
            parsed = self._parse(line)
            if parsed is None:
                self._discard(len(line))
            else:
                out.append(parsed)
                self._accept()
        del buf[:pos]
        return out

    def _parse(self, line: bytes) -> tuple[int, list[str]] | None:
        if len(line) > ASCII_MAX_LINE:
            self.format_errors += 1
            return None
        text = line.decode("latin-1")[1:].rstrip("\n")
        if text.endswith("\r"):
            text = text[:-1]
        if any(not " " <= ch <= "~" for ch in text):
            self.format_errors += 1
            return None
        star = text.rfind("*")
        if star < 0 or len(text) - star != 3 or not set(text[star + 1 :]) <= _HEX:
            self.format_errors += 1
            return None
        body = text[:star]
        if ascii_checksum(body) != int(text[star + 1 :], 16):
            self.crc_errors += 1
            return None
        fields = body.split(",")
        id_text = fields[0]
        if not 2 <= len(id_text) <= 3 or not set(id_text) <= _HEX:
            self.format_errors += 1
            return None
        return int(id_text, 16), fields[1:]
