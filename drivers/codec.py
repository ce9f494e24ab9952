"""Messages and signals: the codecs of frame payloads (pure, no I/O).

A ``Signal`` is a value at a byte offset of a payload, stored as a fixed-size integer or IEEE float; its physical
value is ``raw * scale + offset``. A ``Message`` is a frame id plus either signals or a fixed payload. ``Codec`` is
what a layout needs from a message; ``Message`` implements it, and so does ``drivers.dbc.DbcMessage``. Both ends of
the link (the instrument and a simulated controller) share these codecs. The signal names with a role (setpoint,
counter, timestamp, setpoint echo, CRC) are defined here too.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol, TypeGuard, runtime_checkable

import numpy as np

from .errors import LayoutError

__all__ = [
    "COUNTER",
    "CRC",
    "MAX_PAYLOAD",
    "SETPOINT",
    "SETPOINT_ECHO",
    "SIGNAL_TYPES",
    "TIMESTAMP",
    "Codec",
    "Message",
    "Signal",
    "carried_values",
    "carries_lines",
]

SETPOINT = "setpoint"
"""Name of the setpoint signal of the setpoint message."""
COUNTER = "counter"
"""Name of the rolling sample counter signal (setpoint and feedback messages)."""
TIMESTAMP = "timestamp_us"
"""Name of the optional controller time signal of the feedback messages (microseconds, rolling)."""
SETPOINT_ECHO = "setpoint_echo"
"""Name of the feedback channel carrying the setpoint the drive applied (the two-channel reference of choice)."""
CRC = "crc"
"""Name of the optional CRC-8 byte of a feedback message (drivers.e2e; drivers/PROTOCOL.md section 6)."""


def carries_lines(channel: str) -> bool:
    """Whether feedback ``channel`` can carry a disturbance line (mains hum): every measured signal can; the
    drive's echo of the setpoint it applied is a number, and carries none."""
    return channel != SETPOINT_ECHO


def carried_values(values: np.ndarray, scale: float, offset: float, integer: bool, bits: int) -> np.ndarray:
    """The physical ``values`` as a signal of ``scale`` and ``offset`` carries them: its raw value rounded to a
    whole step where ``integer``, to a float32's precision where it is a 32-bit float; no range check."""
    raw = (np.asarray(values, dtype=np.float64) - offset) / scale
    if integer:
        raw = np.round(raw)
    elif bits == 32:
        raw = raw.astype(np.float32).astype(np.float64)
    return raw * scale + offset


# type name -> (struct code, size in bytes, is integer, is signed)
_TYPES: dict[str, tuple[str, int, bool, bool]] = {
    "int8": ("b", 1, True, True),
    "uint8": ("B", 1, True, False),
    "int16": ("h", 2, True, True),
    "uint16": ("H", 2, True, False),
    "int32": ("i", 4, True, True),
    "uint32": ("I", 4, True, False),
    "float32": ("f", 4, False, True),
    "float64": ("d", 8, False, True),
}
SIGNAL_TYPES: tuple[str, ...] = tuple(_TYPES)
"""Accepted signal type names."""
_ENDIANS = ("little", "big")
MAX_PAYLOAD = 64
"""Largest payload of any supported transport (serial, CAN FD), bytes."""


def show(value: object) -> str:
    """Render a configuration value for an error message (strings in double quotes)."""
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


def is_int(value: object) -> TypeGuard[int]:
    """An integer that is not a bool."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_number(value: object) -> TypeGuard[int | float]:
    """An integer or float that is not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def is_finite(value: object) -> TypeGuard[int | float]:
    """A finite number (an integer too large for a float is not)."""
    try:
        return is_number(value) and math.isfinite(value)
    except OverflowError:
        return False


def signal_problem(field_name: str, value: object) -> str | None:
    """Describe what is wrong with one signal field value, or return None when it is acceptable."""
    if field_name == "name":
        if not isinstance(value, str) or not value:
            return f"a non-empty string, got {show(value)}"
    elif field_name == "byte":
        if not is_int(value) or not 0 <= value < MAX_PAYLOAD:
            return f"an integer byte offset 0..{MAX_PAYLOAD - 1}, got {show(value)}"
    elif field_name == "type":
        if not isinstance(value, str) or value not in _TYPES:
            return f"one of {', '.join(SIGNAL_TYPES)}, got {show(value)}"
    elif field_name == "endian":
        if not isinstance(value, str) or value not in _ENDIANS:
            return f'one of "little", "big", got {show(value)}'
    elif field_name == "scale":
        if not is_finite(value) or value == 0:
            return f"a finite non-zero number, got {show(value)}"
    elif field_name == "offset" and not is_finite(value):
        return f"a finite number, got {show(value)}"
    return None


@dataclass(frozen=True)
class Signal:
    """One value in a payload: ``physical = raw * scale + offset``.

    ``byte`` is the offset of the first byte (0-based); ``type`` one of ``SIGNAL_TYPES``; ``endian`` "little" or
    "big". Integer signals round to the nearest raw value when encoding and refuse values that do not fit the type
    and non-finite values; float signals store ``(physical - offset) / scale`` as IEEE float.
    """

    name: str
    byte: int
    type: str
    endian: str = "little"
    scale: float = 1.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        for name in ("name", "byte", "type", "endian", "scale", "offset"):
            problem = signal_problem(name, getattr(self, name))
            if problem is not None:
                raise LayoutError(f"signal {show(self.name)}: {name}: {problem}")

    @property
    def size(self) -> int:
        """Size of the stored value in bytes."""
        return _TYPES[self.type][1]

    @property
    def end(self) -> int:
        """Offset one past the last byte of the signal."""
        return self.byte + self.size

    @property
    def is_integer(self) -> bool:
        """True for the integer types."""
        return _TYPES[self.type][2]

    @property
    def raw_range(self) -> tuple[int, int] | None:
        """Smallest and largest raw value of an integer type; None for float types."""
        _, size, is_int, signed = _TYPES[self.type]
        if not is_int:
            return None
        bits = 8 * size
        return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)

    @property
    def _format(self) -> str:
        return ("<" if self.endian == "little" else ">") + _TYPES[self.type][0]

    def encode_into(self, buffer: bytearray, value: float, message: str) -> None:
        """Write the physical ``value`` into ``buffer``; LayoutError (naming ``message`` and signal) if it does not
        fit."""
        def where() -> str:  # only built for an error message
            return f"message {show(message)} signal {show(self.name)}"

        if not is_number(value):
            raise LayoutError(f"{where()}: value must be a number, got {show(value)}")
        raw_float = (float(value) - self.offset) / self.scale
        limits = self.raw_range
        if limits is not None:
            if not math.isfinite(raw_float):
                raise LayoutError(f"{where()}: cannot encode non-finite value {value!r} as {self.type}")
            raw = round(raw_float)
            if not limits[0] <= raw <= limits[1]:
                raise LayoutError(
                    f"{where()}: value {value!r} gives raw {raw}, outside {self.type} range {limits[0]}..{limits[1]}"
                )
            struct.pack_into(self._format, buffer, self.byte, raw)
        else:
            try:
                struct.pack_into(self._format, buffer, self.byte, raw_float)
            except (OverflowError, struct.error) as exc:
                raise LayoutError(f"{where()}: value {value!r} does not fit {self.type}") from exc

    def carried(self, values: np.ndarray) -> np.ndarray:
        """The physical values this signal's frames carry for ``values``, as :meth:`encode_into` then
        :meth:`decode_from` give them (:func:`carried_values`)."""
        return carried_values(values, self.scale, self.offset, self.is_integer, _TYPES[self.type][1] * 8)

    def decode_from(self, payload: bytes) -> float:
        """Physical value of this signal in ``payload`` (which must be long enough)."""
        (raw,) = struct.unpack_from(self._format, payload, self.byte)
        if self.scale == 1.0 and self.offset == 0.0:
            return float(raw)
        return float(raw) * self.scale + self.offset


@dataclass(frozen=True)
class _PackPlan:
    """How a signal message packs in one struct call: ``format`` (None when the signals mix byte orders or there are
    none), and per signal in byte order (name, is integer, unit scale and zero offset, scale, offset, raw low, raw
    high) for packing, in layout order (name, index in the unpacked tuple, unit, scale, offset) for unpacking."""

    format: str | None
    packing: tuple[tuple[str, bool, bool, float, float, int, int], ...]
    unpacking: tuple[tuple[str, int, bool, float, float], ...]


def _pack_plan(signals: tuple[Signal, ...]) -> _PackPlan:
    """The one-call packing plan of non-overlapping ``signals`` (gaps between them are zero pad bytes)."""
    if len({sig.endian for sig in signals}) != 1:
        return _PackPlan(None, (), ())
    ordered = sorted(signals, key=lambda sig: sig.byte)
    parts = ["<" if ordered[0].endian == "little" else ">"]
    position = 0
    packing = []
    for sig in ordered:
        if sig.byte > position:
            parts.append(f"{sig.byte - position}x")
        parts.append(_TYPES[sig.type][0])
        position = sig.end
        low, high = sig.raw_range or (0, 0)
        packing.append((sig.name, sig.is_integer, sig.scale == 1.0 and sig.offset == 0.0, sig.scale, sig.offset,
                        low, high))
    index = {sig.name: i for i, sig in enumerate(ordered)}
    unpacking = tuple((sig.name, index[sig.name], sig.scale == 1.0 and sig.offset == 0.0, sig.scale, sig.offset)
                      for sig in signals)
    return _PackPlan("".join(parts), tuple(packing), unpacking)


@runtime_checkable
class Codec(Protocol):
    """What a layout needs from a message: identity, payload size, signal names, and the two conversions.

    ``Message`` implements it; so does ``drivers.dbc.DbcMessage`` (signals defined by a DBC file).
    """

    @property
    def name(self) -> str:
        """Message name, used in error messages."""
        ...

    @property
    def id(self) -> int:
        """Frame id (CAN arbitration id; the id byte or number on a serial line)."""
        ...

    @property
    def extended(self) -> bool:
        """True for a 29-bit CAN id."""
        ...

    @property
    def data(self) -> bytes | None:
        """Fixed payload of a command message without signals, else None."""
        ...

    @property
    def length(self) -> int:
        """Payload length in bytes."""
        ...

    @property
    def signal_names(self) -> tuple[str, ...]:
        """Signal names in layout order."""
        ...

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Payload for the physical ``values`` (every signal required); LayoutError naming the signal otherwise."""
        ...

    def decode(self, payload: bytes) -> dict[str, float]:
        """Physical value of every signal; LayoutError naming the message when ``payload`` is too short."""
        ...

    def integer_modulus(self, name: str) -> int | None:
        """``2**bits`` when signal ``name`` is an unsigned integer with unit scale and zero offset, else None."""
        ...

    def carried(self, name: str, values: np.ndarray) -> np.ndarray:
        """The physical values signal ``name``'s frames carry for ``values`` (rounded as the frame rounds them)."""
        ...


@dataclass(frozen=True)
class Message:
    """A frame: ``id`` (CAN arbitration id or serial id), either ``signals`` or a fixed ``data`` payload.

    The payload length is ``max(signal.byte + signal.size)`` for a signal message and ``len(data)`` for a fixed one.
    Bytes no signal covers are sent as zero.
    """

    name: str
    id: int
    extended: bool = False
    signals: tuple[Signal, ...] = ()
    data: bytes | None = None
    # derived at construction (plain data, so the message still pickles)
    _length: int = field(init=False, repr=False, compare=False)
    _names: tuple[str, ...] = field(init=False, repr=False, compare=False)
    _plan: _PackPlan = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        where = f"message {show(self.name)}"
        if not isinstance(self.name, str) or not self.name:
            raise LayoutError(f"message name must be a non-empty string, got {show(self.name)}")
        if not isinstance(self.extended, bool):
            raise LayoutError(f"{where}: extended must be true or false, got {show(self.extended)}")
        limit = 0x1FFFFFFF if self.extended else 0x7FF
        if not is_int(self.id) or not 0 <= self.id <= limit:
            kind = "extended (29-bit)" if self.extended else "standard (11-bit)"
            raise LayoutError(f"{where}: id must be a {kind} id 0..0x{limit:X}, got {show(self.id)}")
        if not isinstance(self.signals, tuple):
            object.__setattr__(self, "signals", tuple(self.signals))
        if self.data is not None:
            if isinstance(self.data, (bytearray, list, tuple)):
                try:
                    object.__setattr__(self, "data", bytes(self.data))
                except (TypeError, ValueError) as exc:
                    raise LayoutError(f"{where}: data must be bytes 0..255, got {show(self.data)}") from exc
            if not isinstance(self.data, bytes):
                raise LayoutError(f"{where}: data must be bytes, got {show(self.data)}")
            if self.signals:
                raise LayoutError(f"{where}: has both signals and fixed data; give one of them")
            if len(self.data) > MAX_PAYLOAD:
                raise LayoutError(f"{where}: data is {len(self.data)} bytes, more than {MAX_PAYLOAD}")
        elif not self.signals:
            raise LayoutError(f"{where}: needs signals or fixed data")
        seen: dict[str, Signal] = {}
        for sig in self.signals:
            if not isinstance(sig, Signal):
                raise LayoutError(f"{where}: signals must be Signal objects, got {show(sig)}")
            if sig.name in seen:
                raise LayoutError(f"{where}: signal name {show(sig.name)} appears twice")
            if sig.end > MAX_PAYLOAD:
                raise LayoutError(f"{where} signal {show(sig.name)}: ends at byte {sig.end}, beyond {MAX_PAYLOAD}")
            for other in seen.values():
                if sig.byte < other.end and other.byte < sig.end:
                    raise LayoutError(
                        f"{where}: signals {show(other.name)} (bytes {other.byte}..{other.end - 1}) and "
                        f"{show(sig.name)} (bytes {sig.byte}..{sig.end - 1}) overlap"
                    )
            seen[sig.name] = sig
        # derived once: length, names and the packing plan (a fixed-data message has no signals to pack)
        object.__setattr__(self, "_length", len(self.data) if self.data is not None
                           else max(sig.end for sig in self.signals))
        object.__setattr__(self, "_names", tuple(sig.name for sig in self.signals))
        object.__setattr__(self, "_plan", _pack_plan(self.signals))

    @property
    def length(self) -> int:
        """Payload length in bytes."""
        return self._length

    @property
    def signal_names(self) -> tuple[str, ...]:
        """Signal names in layout order."""
        return self._names

    def signal(self, name: str) -> Signal:
        """The signal called ``name``; LayoutError when there is none."""
        for sig in self.signals:
            if sig.name == name:
                return sig
        raise LayoutError(f"message {show(self.name)} has no signal {show(name)}")

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Payload for the physical ``values``; a fixed-data message ignores ``values`` and returns its data.

        Raises LayoutError naming the message and signal when a value is missing, out of range or not finite for an
        integer type. Extra keys in ``values`` are ignored.
        """
        if self.data is not None:
            return self.data
        plan = self._plan
        if plan.format is not None:
            # one struct call for the whole payload; anything unusual takes the signal-by-signal way below,
            # which encodes the same bytes or raises the error naming the signal
            raws: list[float | int] = []
            try:
                for name, is_int, unit, scale, offset, low, high in plan.packing:
                    value = values[name]
                    kind = type(value)
                    if kind is not float and kind is not int:
                        break
                    raw = float(value) if unit else (float(value) - offset) / scale
                    if is_int:
                        if raw != raw or raw in (math.inf, -math.inf):
                            break
                        raw = round(raw)
                        if not low <= raw <= high:
                            break
                    raws.append(raw)
                else:
                    return struct.pack(plan.format, *raws)
            except (KeyError, OverflowError, struct.error):
                pass
        buffer = bytearray(self.length)
        for sig in self.signals:
            if sig.name not in values:
                raise LayoutError(f"message {show(self.name)}: missing value for signal {show(sig.name)}")
            sig.encode_into(buffer, values[sig.name], self.name)
        return bytes(buffer)

    def decode(self, payload: bytes) -> dict[str, float]:
        """Physical value of every signal (empty for a fixed-data message); LayoutError on a short payload."""
        if len(payload) < self._length:
            raise LayoutError(
                f"message {show(self.name)} (id 0x{self.id:X}): payload is {len(payload)} bytes, "
                f"needs {self.length}"
            )
        plan = self._plan
        if plan.format is None:  # mixed byte orders, or a fixed-data message (no signals)
            return {sig.name: sig.decode_from(payload) for sig in self.signals}
        raws = struct.unpack_from(plan.format, payload, 0)
        return {name: float(raws[i]) if unit else float(raws[i]) * scale + offset
                for name, i, unit, scale, offset in plan.unpacking}

    def integer_modulus(self, name: str) -> int | None:
        """``2**bits`` when signal ``name`` is an unsigned integer with unit scale and zero offset, else None."""
        sig = self.signal(name)
        limits = sig.raw_range
        if limits is None or limits[0] != 0 or sig.scale != 1.0 or sig.offset != 0.0:
            return None
        return limits[1] + 1

    def carried(self, name: str, values: np.ndarray) -> np.ndarray:
        """The physical values signal ``name``'s frames carry for ``values`` (:meth:`Signal.carried`)."""
        return self.signal(name).carried(values)
