"""Frame layouts: messages made of fixed-position signals, and the set of messages a bench uses (pure, no I/O).

A ``Signal`` is a value at a byte offset of a payload, stored as a fixed-size integer or IEEE float; its physical
value is ``raw * scale + offset``. A ``Message`` is a frame id plus either signals or a fixed payload. A ``Layout``
names the roles: the setpoint message sent to the controller, the feedback messages that make up one sample, and the
optional enable, disable and heartbeat messages. Both ends of the link (the instrument and a simulated controller)
share these codecs.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn, Protocol, runtime_checkable

from .errors import LayoutError

__all__ = [
    "COUNTER",
    "CRC",
    "SETPOINT",
    "SETPOINT_ECHO",
    "SIGNAL_TYPES",
    "TIMESTAMP",
    "Codec",
    "Layout",
    "Message",
    "Signal",
    "default_layout",
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
_MAX_PAYLOAD = 64  # bytes; the largest payload of any supported transport (serial, CAN FD)
_TRANSPORTS = {
    # transport -> (largest payload in bytes, largest standard id, largest extended id)
    "can": (8, 0x7FF, 0x1FFFFFFF),
    "serial-binary": (64, 0xFF, 0xFF),
    "serial-ascii": (64, 0xFFF, 0xFFF),
}


def _show(value: object) -> str:
    """Render a configuration value for an error message (strings in double quotes)."""
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_finite(value: object) -> bool:
    """A finite number (an integer too large for a float is not)."""
    try:
        return _is_number(value) and math.isfinite(value)  # type: ignore[arg-type]
    except OverflowError:
        return False


def _signal_problem(field_name: str, value: object) -> str | None:
    """Describe what is wrong with one signal field value, or return None when it is acceptable."""
    if field_name == "name":
        if not isinstance(value, str) or not value:
            return f"a non-empty string, got {_show(value)}"
    elif field_name == "byte":
        if not _is_int(value) or not 0 <= value < _MAX_PAYLOAD:  # type: ignore[operator]
            return f"an integer byte offset 0..{_MAX_PAYLOAD - 1}, got {_show(value)}"
    elif field_name == "type":
        if not isinstance(value, str) or value not in _TYPES:
            return f"one of {', '.join(SIGNAL_TYPES)}, got {_show(value)}"
    elif field_name == "endian":
        if not isinstance(value, str) or value not in _ENDIANS:
            return f'one of "little", "big", got {_show(value)}'
    elif field_name == "scale":
        if not _is_finite(value) or value == 0:
            return f"a finite non-zero number, got {_show(value)}"
    elif field_name == "offset":
        if not _is_finite(value):
            return f"a finite number, got {_show(value)}"
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
            problem = _signal_problem(name, getattr(self, name))
            if problem is not None:
                raise LayoutError(f"signal {_show(self.name)}: {name}: {problem}")

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
        """Write the physical ``value`` into ``buffer``; LayoutError (naming ``message`` and signal) if it does not fit."""
        def where() -> str:  # only built for an error message
            return f"message {_show(message)} signal {_show(self.name)}"

        if not _is_number(value):
            raise LayoutError(f"{where()}: value must be a number, got {_show(value)}")
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

    def decode_from(self, payload: bytes) -> float:
        """Physical value of this signal in ``payload`` (which must be long enough)."""
        (raw,) = struct.unpack_from(self._format, payload, self.byte)
        if self.scale == 1.0 and self.offset == 0.0:
            return float(raw)
        return float(raw) * self.scale + self.offset


@dataclass(frozen=True)
class _PackPlan:
    """How a signal message packs in one struct call: ``format`` (None when the signals mix byte orders), and per
    signal in byte order (name, is integer, unit scale and zero offset, scale, offset, raw low, raw high) for
    packing, in layout order (name, index in the unpacked tuple, unit, scale, offset) for unpacking."""

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

    def __post_init__(self) -> None:
        where = f"message {_show(self.name)}"
        if not isinstance(self.name, str) or not self.name:
            raise LayoutError(f"message name must be a non-empty string, got {_show(self.name)}")
        if not isinstance(self.extended, bool):
            raise LayoutError(f"{where}: extended must be true or false, got {_show(self.extended)}")
        limit = 0x1FFFFFFF if self.extended else 0x7FF
        if not _is_int(self.id) or not 0 <= self.id <= limit:
            kind = "extended (29-bit)" if self.extended else "standard (11-bit)"
            raise LayoutError(f"{where}: id must be a {kind} id 0..0x{limit:X}, got {_show(self.id)}")
        if not isinstance(self.signals, tuple):
            object.__setattr__(self, "signals", tuple(self.signals))
        if self.data is not None:
            if isinstance(self.data, (bytearray, list, tuple)):
                try:
                    object.__setattr__(self, "data", bytes(self.data))
                except (TypeError, ValueError) as exc:
                    raise LayoutError(f"{where}: data must be bytes 0..255, got {_show(self.data)}") from exc
            if not isinstance(self.data, bytes):
                raise LayoutError(f"{where}: data must be bytes, got {_show(self.data)}")
            if self.signals:
                raise LayoutError(f"{where}: has both signals and fixed data; give one of them")
            if len(self.data) > _MAX_PAYLOAD:
                raise LayoutError(f"{where}: data is {len(self.data)} bytes, more than {_MAX_PAYLOAD}")
        elif not self.signals:
            raise LayoutError(f"{where}: needs signals or fixed data")
        seen: dict[str, Signal] = {}
        for sig in self.signals:
            if not isinstance(sig, Signal):
                raise LayoutError(f"{where}: signals must be Signal objects, got {_show(sig)}")
            if sig.name in seen:
                raise LayoutError(f"{where}: signal name {_show(sig.name)} appears twice")
            if sig.end > _MAX_PAYLOAD:
                raise LayoutError(f"{where} signal {_show(sig.name)}: ends at byte {sig.end}, beyond {_MAX_PAYLOAD}")
            for other in seen.values():
                if sig.byte < other.end and other.byte < sig.end:
                    raise LayoutError(
                        f"{where}: signals {_show(other.name)} (bytes {other.byte}..{other.end - 1}) and "
                        f"{_show(sig.name)} (bytes {sig.byte}..{sig.end - 1}) overlap"
                    )
            seen[sig.name] = sig
        # derived once (plain data, so the message still pickles): length, names and the packing plan
        object.__setattr__(self, "_length", len(self.data) if self.data is not None
                           else max(sig.end for sig in self.signals))
        object.__setattr__(self, "_names", tuple(sig.name for sig in self.signals))
        object.__setattr__(self, "_plan", _pack_plan(self.signals) if self.data is None else None)

    @property
    def length(self) -> int:
        """Payload length in bytes."""
        return self._length  # type: ignore[attr-defined, no-any-return]

    @property
    def signal_names(self) -> tuple[str, ...]:
        """Signal names in layout order."""
        return self._names  # type: ignore[attr-defined, no-any-return]

    def signal(self, name: str) -> Signal:
        """The signal called ``name``; LayoutError when there is none."""
        for sig in self.signals:
            if sig.name == name:
                return sig
        raise LayoutError(f"message {_show(self.name)} has no signal {_show(name)}")

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Payload for the physical ``values``; a fixed-data message ignores ``values`` and returns its data.

        Raises LayoutError naming the message and signal when a value is missing, out of range or not finite for an
        integer type. Extra keys in ``values`` are ignored.
        """
        if self.data is not None:
            return self.data
        plan: _PackPlan = self._plan  # type: ignore[attr-defined]
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
                raise LayoutError(f"message {_show(self.name)}: missing value for signal {_show(sig.name)}")
            sig.encode_into(buffer, values[sig.name], self.name)
        return bytes(buffer)

    def decode(self, payload: bytes) -> dict[str, float]:
        """Physical value of every signal (empty for a fixed-data message); LayoutError on a short payload."""
        if len(payload) < self._length:  # type: ignore[attr-defined]
            raise LayoutError(
                f"message {_show(self.name)} (id 0x{self.id:X}): payload is {len(payload)} bytes, "
                f"needs {self.length}"
            )
        plan: _PackPlan | None = self._plan  # type: ignore[attr-defined]
        if plan is None:
            return {}
        if plan.format is None:
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


def _key(codec: Codec) -> tuple[int, bool]:
    return (codec.id, codec.extended)


@dataclass(frozen=True)
class Layout:
    """The messages of one bench and their roles.

    ``setpoint`` carries the signal "setpoint" and optionally a rolling "counter" (uint8/uint16). ``feedback`` is one
    or more messages that together make one sample; when there are several, every one carries "counter" (so frames of
    one sample can be joined). A feedback message may carry "timestamp_us" (controller time in microseconds, unsigned
    rolling). Every other feedback signal is a channel. ``enable``, ``disable`` and ``heartbeat`` are fixed-data
    messages; ``heartbeat_period_s`` (s) is how often the instrument sends the heartbeat (0 without one).
    ``drive_watchdog_s`` (s): the drive zeroes its setpoint and disables itself when no valid setpoint or heartbeat
    has arrived for this long (0: the drive has no such watchdog); a heartbeat must come at least twice that often.

    Construction checks everything that does not depend on the transport; ``validate(transport)`` adds the payload
    size and id limits of a transport.
    """

    setpoint: Codec
    feedback: tuple[Codec, ...]
    enable: Codec | None = None
    disable: Codec | None = None
    heartbeat: Codec | None = None
    heartbeat_period_s: float = 0.0
    drive_watchdog_s: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.feedback, tuple):
            object.__setattr__(self, "feedback", tuple(self.feedback))
        self._check_structure()

    # ----------------------------------------------------------------------------------------------------------
    # derived properties
    @property
    def messages(self) -> tuple[Codec, ...]:
        """All messages: setpoint, feedback..., then enable, disable, heartbeat where present."""
        extra = tuple(m for m in (self.enable, self.disable, self.heartbeat) if m is not None)
        return (self.setpoint, *self.feedback, *extra)

    @property
    def channels(self) -> tuple[str, ...]:
        """Feedback channel names (every feedback signal but counter, timestamp_us and crc), in order of appearance."""
        return tuple(
            name for msg in self.feedback for name in msg.signal_names if name not in (COUNTER, TIMESTAMP, CRC)
        )

    @property
    def has_counter(self) -> bool:
        """True when the feedback messages carry a sample counter."""
        return any(COUNTER in msg.signal_names for msg in self.feedback)

    @property
    def has_setpoint_counter(self) -> bool:
        """True when the setpoint message carries a counter."""
        return COUNTER in self.setpoint.signal_names

    @property
    def has_timestamp(self) -> bool:
        """True when a feedback message carries timestamp_us."""
        return any(TIMESTAMP in msg.signal_names for msg in self.feedback)

    @property
    def counter_modulus(self) -> int | None:
        """Number of distinct counter values (``2**bits``), None when no message carries a counter."""
        for msg in (*self.feedback, self.setpoint):
            if COUNTER in msg.signal_names:
                return msg.integer_modulus(COUNTER)
        return None

    @property
    def timestamp_modulus(self) -> int | None:
        """Number of distinct timestamp_us values (``2**bits``), None without a timestamp."""
        for msg in self.feedback:
            if TIMESTAMP in msg.signal_names:
                return msg.integer_modulus(TIMESTAMP)
        return None

    # ----------------------------------------------------------------------------------------------------------
    # checks
    def _check_structure(self) -> None:
        for role, msg in (("setpoint", self.setpoint), ("enable", self.enable), ("disable", self.disable),
                          ("heartbeat", self.heartbeat)):
            if msg is not None and not isinstance(msg, Codec):
                raise LayoutError(f"{role}: expected a message, got {_show(msg)}")
        if not self.feedback:
            raise LayoutError("feedback: needs at least one message")
        for msg in self.feedback:
            if not isinstance(msg, Codec):
                raise LayoutError(f"feedback: expected messages, got {_show(msg)}")
        sp = self.setpoint
        if SETPOINT not in sp.signal_names:
            raise LayoutError(f"setpoint message {_show(sp.name)}: needs a signal named \"setpoint\"")
        for msg in self.feedback:
            if msg.data is not None or not msg.signal_names:
                raise LayoutError(f"feedback message {_show(msg.name)}: needs signals, not fixed data")
        for role, msg in (("enable", self.enable), ("disable", self.disable), ("heartbeat", self.heartbeat)):
            if msg is not None and msg.data is None:
                raise LayoutError(f"{role} message {_show(msg.name)}: must be a fixed-data message")
        # counters: unsigned integers with unit scale, one width everywhere
        moduli: dict[str, int] = {}
        for msg in (sp, *self.feedback):
            if COUNTER in msg.signal_names:
                modulus = msg.integer_modulus(COUNTER)
                if modulus is None or modulus > 1 << 16:
                    raise LayoutError(
                        f"message {_show(msg.name)} signal \"counter\": must be uint8 or uint16 with scale 1 and "
                        "offset 0"
                    )
                moduli[msg.name] = modulus
        if len(set(moduli.values())) > 1:
            detail = ", ".join(f"{_show(n)}: {m.bit_length() - 1} bits" for n, m in moduli.items())
            raise LayoutError(f"counter signals must all have the same width ({detail})")
        if len(self.feedback) > 1:
            for msg in self.feedback:
                if COUNTER not in msg.signal_names:
                    raise LayoutError(
                        f"feedback message {_show(msg.name)}: needs a \"counter\" signal when a sample spans "
                        f"{len(self.feedback)} feedback messages"
                    )
        for msg in self.feedback:
            if TIMESTAMP in msg.signal_names and msg.integer_modulus(TIMESTAMP) is None:
                raise LayoutError(
                    f"message {_show(msg.name)} signal \"timestamp_us\": must be an unsigned integer with scale 1 "
                    "and offset 0"
                )
        from .e2e import crc_byte

        for msg in self.feedback:
            crc_byte(msg)  # a crc signal must fill exactly one byte (LayoutError naming the message)
        seen_channels: dict[str, str] = {}
        for msg in self.feedback:
            for name in msg.signal_names:
                if name in (COUNTER, TIMESTAMP, CRC):
                    continue
                if name in seen_channels:
                    raise LayoutError(
                        f"channel {_show(name)} appears in feedback messages {_show(seen_channels[name])} and "
                        f"{_show(msg.name)}"
                    )
                seen_channels[name] = msg.name
        for name in sp.signal_names:
            if name not in (SETPOINT, COUNTER):
                raise LayoutError(
                    f"setpoint message {_show(sp.name)}: unexpected signal {_show(name)} (only \"setpoint\" and "
                    "\"counter\")"
                )
        # ids: feedback ids distinct from each other and from every command id; the setpoint id distinct from the
        # fixed-data command ids. Fixed-data commands may share an id (e.g. enable/disable told apart by content).
        owners: dict[tuple[int, bool], str] = {}
        for msg in (sp, *self.feedback):
            if _key(msg) in owners:
                raise LayoutError(
                    f"messages {_show(owners[_key(msg)])} and {_show(msg.name)} share id 0x{msg.id:X}"
                )
            owners[_key(msg)] = msg.name
        for msg in (self.enable, self.disable, self.heartbeat):
            if msg is not None and _key(msg) in owners:
                raise LayoutError(
                    f"messages {_show(owners[_key(msg)])} and {_show(msg.name)} share id 0x{msg.id:X}"
                )
        commands = [(role, m) for role, m in (("enable", self.enable), ("disable", self.disable),
                                               ("heartbeat", self.heartbeat)) if m is not None]
        for i, (role, msg) in enumerate(commands):
            for other_role, other in commands[i + 1:]:
                if _key(msg) == _key(other) and msg.data == other.data:
                    raise LayoutError(f"{role} and {other_role} are the same frame (id 0x{msg.id:X}, data "
                                      f"{bytes(msg.data or b'').hex() or 'empty'}): the drive could not tell them "
                                      "apart")
        period = self.heartbeat_period_s
        if not _is_finite(period) or period < 0:
            raise LayoutError(f"heartbeat_period_s: a finite number >= 0 s, got {_show(period)}")
        if self.heartbeat is not None and period <= 0:
            raise LayoutError("heartbeat_period_s: must be > 0 s when a heartbeat message is given")
        if self.heartbeat is None and period > 0:
            raise LayoutError("heartbeat_period_s: given without a heartbeat message")
        watchdog = self.drive_watchdog_s
        if not _is_finite(watchdog) or watchdog < 0:
            raise LayoutError(f"drive_watchdog_s: a finite number >= 0 s, got {_show(watchdog)}")
        if watchdog > 0 and period > watchdog / 2:
            raise LayoutError(f"heartbeat period_s: {period:g} s is more than half of drive_watchdog_s "
                              f"({watchdog:g} s): the drive would trip between heartbeats")

    def validate(self, transport: str = "can") -> None:
        """Check the layout for ``transport``: "can" (payload <= 8 bytes, 11/29-bit ids), "serial-binary" (payload
        <= 64 bytes, id <= 0xFF) or "serial-ascii" (payload <= 64 bytes, id <= 0xFFF; 29-bit ids not allowed).

        Structural rules (unique ids, no overlaps, counters, channel names) are checked at construction and again
        here. Raises LayoutError naming the offending message.
        """
        if transport not in _TRANSPORTS:
            raise LayoutError(f"transport: one of {', '.join(_TRANSPORTS)}, got {_show(transport)}")
        self._check_structure()
        max_payload, max_std, max_ext = _TRANSPORTS[transport]
        for msg in self.messages:
            if msg.length > max_payload:
                raise LayoutError(
                    f"message {_show(msg.name)}: payload of {msg.length} bytes exceeds {max_payload} for {transport}"
                )
            limit = max_ext if msg.extended else max_std
            if msg.id > limit:
                raise LayoutError(f"message {_show(msg.name)}: id 0x{msg.id:X} exceeds 0x{limit:X} for {transport}")
        if transport != "can":
            # a serial line carries no extended flag: ids must be distinct as numbers
            owners: dict[int, Codec] = {}
            for msg in self.messages:
                other = owners.get(msg.id)
                if other is not None and not (other.data is not None and msg.data is not None):
                    raise LayoutError(
                        f"messages {_show(other.name)} and {_show(msg.name)} share id 0x{msg.id:X} on {transport}"
                    )
                owners.setdefault(msg.id, msg)

    # ----------------------------------------------------------------------------------------------------------
    # construction from configuration tables
    @classmethod
    def from_mapping(cls, d: Mapping[str, Any], source: str = "") -> Layout:
        """Build a layout from the ``[frames]`` table of a configuration (see drivers/PROTOCOL.md).

        ``d`` is the content of ``[frames]`` (a mapping with ``frames`` as its only key is unwrapped). With a ``dbc``
        key the messages come from that DBC file (relative paths are taken relative to the directory of
        ``source``). Raises LayoutError naming ``source`` and the key path of the fault.
        """
        if isinstance(d, Mapping) and set(d) == {"frames"} and isinstance(d["frames"], Mapping):
            d = d["frames"]
        ctx = _Ctx(source)
        table = ctx.table(d, "frames")
        if "dbc" in table:
            dbc = table["dbc"]
            if not isinstance(dbc, (str, Path)) or not str(dbc):
                ctx.fail("frames.dbc", f"a file path, got {_show(dbc)}")
            path = Path(dbc)
            if not path.is_absolute() and source:
                path = Path(source).parent / path
            rest = {k: v for k, v in table.items() if k != "dbc"}
            return cls.from_dbc(path, rest, source)
        ctx.known(table, "frames", {"setpoint", "feedback", "enable", "disable", "heartbeat", "drive_watchdog_s"})
        watchdog = ctx.number(table["drive_watchdog_s"], "frames.drive_watchdog_s") if "drive_watchdog_s" in table \
            else 0.0
        setpoint = ctx.message(ctx.require(table, "frames", "setpoint"), "frames.setpoint", "setpoint")
        fb_raw = ctx.require(table, "frames", "feedback")
        if isinstance(fb_raw, Mapping):
            fb_raw = [fb_raw]
        if not isinstance(fb_raw, Sequence) or isinstance(fb_raw, (str, bytes)) or not fb_raw:
            ctx.fail("frames.feedback", f"a non-empty list of tables, got {_show(fb_raw)}")
        feedback = tuple(
            ctx.message(item, f"frames.feedback[{i}]", f"feedback[{i}]") for i, item in enumerate(fb_raw)
        )
        optional: dict[str, Message | None] = {}
        period = 0.0
        for role in ("enable", "disable", "heartbeat"):
            if role in table:
                sub = ctx.table(table[role], f"frames.{role}")
                if role == "heartbeat" and "period_s" in sub:
                    period = ctx.number(sub["period_s"], "frames.heartbeat.period_s")
                    sub = {k: v for k, v in sub.items() if k != "period_s"}
                optional[role] = ctx.message(sub, f"frames.{role}", role)
            else:
                optional[role] = None
        return ctx.build(
            lambda: cls(setpoint, feedback, optional["enable"], optional["disable"], optional["heartbeat"], period,
                        watchdog)
        )

    @classmethod
    def from_dbc(cls, path: str | Path, mapping: Mapping[str, Any], source: str = "") -> Layout:
        """Build a layout whose messages are defined in the DBC file ``path``.

        ``mapping`` is the ``[frames]`` table without ``dbc``: ``setpoint`` and each ``feedback`` entry name a DBC
        ``message`` and map our signal names to DBC signal names (``signals = {setpoint = "SetpointPos"}``);
        ``enable``/``disable``/``heartbeat`` name a ``message`` and give DBC signal ``values`` for its fixed payload
        (``heartbeat`` also ``period_s``). Raises LayoutError naming the key path.
        """
        from .dbc import layout_from_dbc  # cantools is only needed for DBC layouts

        return layout_from_dbc(cls, Path(path), mapping, source)


class _Ctx:
    """Helpers for reading configuration tables with error messages that name the source and key path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, path: str, problem: str) -> NoReturn:
        prefix = f"{self.source}: " if self.source else ""
        raise LayoutError(f"{prefix}{path}: {problem}")

    def table(self, value: object, path: str) -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            self.fail(path, f"a table, got {_show(value)}")
        return value  # type: ignore[return-value]

    def known(self, table: Mapping[str, Any], path: str, allowed: set[str]) -> None:
        unknown = sorted(str(k) for k in table if k not in allowed)
        if unknown:
            self.fail(path, f"unknown key(s) {', '.join(unknown)} (allowed: {', '.join(sorted(allowed))})")

    def require(self, table: Mapping[str, Any], path: str, key: str) -> Any:
        if key not in table:
            self.fail(f"{path}.{key}", "missing")
        return table[key]

    def number(self, value: object, path: str) -> float:
        if not _is_finite(value):
            self.fail(path, f"a finite number, got {_show(value)}")
        return float(value)  # type: ignore[arg-type]

    def build(self, make: Any) -> Any:
        try:
            return make()
        except LayoutError as exc:
            self.fail("frames", str(exc))

    def signal(self, value: object, path: str) -> Signal:
        table = self.table(value, path)
        self.known(table, path, {"name", "byte", "type", "endian", "scale", "offset"})
        kwargs: dict[str, Any] = {}
        for key in ("name", "byte", "type", "endian", "scale", "offset"):
            if key not in table:
                if key in ("name", "byte", "type"):
                    self.fail(f"{path}.{key}", "missing")
                continue
            problem = _signal_problem(key, table[key])
            if problem is not None:
                self.fail(f"{path}.{key}", problem)
            kwargs[key] = table[key]
        for key in ("scale", "offset"):
            if key in kwargs:
                kwargs[key] = float(kwargs[key])
        return Signal(**kwargs)

    def message(self, value: object, path: str, name: str) -> Message:
        table = self.table(value, path)
        self.known(table, path, {"id", "extended", "signals", "data", "name"})
        msg_id = self.require(table, path, "id")
        if not _is_int(msg_id) or msg_id < 0:
            self.fail(f"{path}.id", f"a non-negative integer, got {_show(msg_id)}")
        extended = table.get("extended", False)
        if not isinstance(extended, bool):
            self.fail(f"{path}.extended", f"true or false, got {_show(extended)}")
        if "name" in table:
            if not isinstance(table["name"], str) or not table["name"]:
                self.fail(f"{path}.name", f"a non-empty string, got {_show(table['name'])}")
            name = table["name"]
        signals: tuple[Signal, ...] = ()
        if "signals" in table:
            raw = table["signals"]
            if not isinstance(raw, Sequence) or isinstance(raw, (str, bytes)):
                self.fail(f"{path}.signals", f"a list of tables, got {_show(raw)}")
            signals = tuple(self.signal(item, f"{path}.signals[{i}]") for i, item in enumerate(raw))
        data: bytes | None = None
        if "data" in table:
            raw = table["data"]
            if isinstance(raw, (bytes, bytearray)):
                data = bytes(raw)
            elif isinstance(raw, Sequence) and not isinstance(raw, str):
                for i, item in enumerate(raw):
                    if not _is_int(item) or not 0 <= item <= 255:
                        self.fail(f"{path}.data[{i}]", f"a byte 0..255, got {_show(item)}")
                data = bytes(raw)
            else:
                self.fail(f"{path}.data", f"a list of bytes 0..255, got {_show(raw)}")
        if data is not None and signals:
            self.fail(path, "give either signals or data, not both")
        if data is None and not signals:
            self.fail(path, "needs signals or data")
        try:
            return Message(name, msg_id, extended, signals, data)
        except LayoutError as exc:
            self.fail(path, str(exc))


_DEFAULT_FRAMES: dict[str, Any] = {
    "setpoint": {
        "id": 0x201,
        "extended": False,
        "signals": [
            {"name": "setpoint", "byte": 0, "type": "float32"},
            {"name": "counter", "byte": 4, "type": "uint16"},
        ],
    },
    "feedback": [
        {
            "id": 0x181,
            "signals": [
                {"name": "position", "byte": 0, "type": "float32"},
                {"name": "counter", "byte": 4, "type": "uint16"},
            ],
        },
        {
            "id": 0x182,
            "signals": [
                {"name": "setpoint_echo", "byte": 0, "type": "float32"},
                {"name": "counter", "byte": 4, "type": "uint16"},
            ],
        },
    ],
    "enable": {"id": 0x010, "data": [1]},
    "disable": {"id": 0x010, "data": [0]},
}


def default_layout() -> Layout:
    """The simulated bench's layout: setpoint 0x201 (float32 setpoint, uint16 counter), feedback 0x181 (position)
    and 0x182 (setpoint_echo), each with the uint16 counter at byte 4; enable/disable 0x010 with data 01/00."""
    return Layout.from_mapping(_DEFAULT_FRAMES, "default_layout")

