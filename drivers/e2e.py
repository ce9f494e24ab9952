"""End-to-end protection of a frame's payload: a CRC-8 in the frame itself (drivers/PROTOCOL.md section 6).

A message with a signal named ``crc`` (uint8, scale 1, offset 0) carries CRC-8/SAE-J1850 of every other byte of
its payload, in payload order: polynomial 0x1D, initial value 0xFF, no reflection, final XOR 0xFF (the CRC of
AUTOSAR E2E profile 1). Check value: CRC("123456789") = 0x4B. Together with the rolling ``counter`` it lets the
receiver reject plausible garbage (another node on the bus, a corrupted frame) before it becomes data.
"""

from __future__ import annotations

from .codec import CRC, Codec
from .errors import LayoutError
from .serial_framing import crc_table

__all__ = ["crc8_sae_j1850", "crc_byte", "intact", "seal"]


_TABLE = crc_table(0x1D, 8)


def crc8_sae_j1850(data: bytes | bytearray | memoryview) -> int:
    """CRC-8/SAE-J1850 of ``data`` (poly 0x1D, init 0xFF, no reflection, xorout 0xFF)."""
    crc = 0xFF
    table = _TABLE
    for byte in data:
        crc = table[crc ^ byte]
    return crc ^ 0xFF


def crc_byte(message: Codec) -> int | None:
    """Offset of the ``crc`` byte in ``message``'s payload (found through the codec itself, so a DBC message
    works the same), None when the message has no ``crc`` signal; LayoutError when it is not one whole byte."""
    if CRC not in message.signal_names:
        return None
    if message.integer_modulus(CRC) != 256:
        raise LayoutError(f"message {message.name!r} signal \"crc\": must be uint8 with scale 1 and offset 0")
    values = message.decode(bytes(message.length))
    low = message.encode({**values, CRC: 0})
    high = message.encode({**values, CRC: 0xFF})
    changed = [i for i, (a, b) in enumerate(zip(low, high, strict=True)) if a != b]
    if len(changed) != 1 or low[changed[0]] != 0 or high[changed[0]] != 0xFF:
        raise LayoutError(f"message {message.name!r} signal \"crc\": must fill exactly one byte")
    return changed[0]


def seal(payload: bytes, at: int) -> bytes:
    """``payload`` with its byte ``at`` set to the CRC of all the others."""
    body = bytearray(payload)
    body[at] = crc8_sae_j1850(body[:at] + body[at + 1:])
    return bytes(body)


def intact(payload: bytes, at: int) -> bool:
    """Whether byte ``at`` of ``payload`` is the CRC of all the others."""
    return len(payload) > at and payload[at] == crc8_sae_j1850(payload[:at] + payload[at + 1:])
