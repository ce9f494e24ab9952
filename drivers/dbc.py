"""Messages defined by a DBC file (via cantools), adapted to the ``Codec`` protocol of drivers.codec.

``DbcMessage`` maps our signal names (setpoint, counter, channel names) to DBC signal names; values are physical
(cantools applies each signal's scale and offset). DBC signals that are not mapped are sent with their initial value
from the DBC file (0 when it gives none, moved into the signal's [minimum, maximum] when 0 is outside it).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from .codec import Codec, Message, Signal, carried_values, is_number, show
from .errors import LayoutError
from .tables import FRAMES_KEYS, Roles, TableReader

if TYPE_CHECKING:  # cantools is imported where a DBC file is read
    from cantools.database.can import Message as DbcDefinition
    from cantools.database.can import Signal as DbcSignal

    from .layout import Layout

__all__ = ["DbcMessage", "SignalSpec", "layout_database", "read_dbc_frames", "signal_specs"]

_SIGNAL_LINE = re.compile(r"\s*SG_\s+(?P<name>\w+)\s*[^:]*:\s*\d+\|\d+@(?P<order>.)(?P<sign>.)")
"""A DBC signal line up to its byte order and sign (``SG_ Name : start|length@1-``)."""


class DbcMessage:
    """A DBC message seen through a mapping ``our name -> DBC signal name`` (physical values in both directions)."""

    def __init__(self, db_message: DbcDefinition, signals: Mapping[str, str] | None = None) -> None:
        """``db_message`` is a ``cantools.database.can.Message``; ``signals`` maps our names to its signal names
        (default: every DBC signal under its own name, in DBC order)."""
        self._msg = db_message
        where = f"DBC message {show(db_message.name)}"
        if db_message.is_multiplexed():
            raise LayoutError(f"{where}: multiplexed messages are not supported")
        by_name = {sig.name: sig for sig in db_message.signals}
        mapping = dict(signals) if signals is not None else {name: name for name in by_name}
        if not mapping:
            raise LayoutError(f"{where}: no signals mapped")
        targets: set[str] = set()
        for ours, theirs in mapping.items():
            if theirs not in by_name:
                raise LayoutError(
                    f"{where}: has no signal {show(theirs)} (for {show(ours)}); it has {', '.join(by_name)}"
                )
            if theirs in targets:
                raise LayoutError(f"{where}: signal {show(theirs)} is mapped twice")
            targets.add(theirs)
        for sig in db_message.signals:
            if not sig.is_float and (not math.isfinite(float(sig.scale)) or sig.scale == 0):
                raise LayoutError(f"{where}: signal {show(sig.name)} has scale {sig.scale!r}: every raw value "
                                  "would read the same (a finite non-zero scale is needed)")
        self._map = mapping
        self._sig = {ours: by_name[theirs] for ours, theirs in mapping.items()}
        self._defaults = {name: _default_value(sig) for name, sig in by_name.items() if name not in targets}

    def __repr__(self) -> str:
        return f"DbcMessage({self._msg.name!r}, id=0x{self.id:X}, signals={self._map!r})"

    @property
    def name(self) -> str:
        """DBC message name."""
        return str(self._msg.name)

    @property
    def id(self) -> int:
        """Frame id."""
        return int(self._msg.frame_id)

    @property
    def extended(self) -> bool:
        """True for a 29-bit id."""
        return bool(self._msg.is_extended_frame)

    @property
    def data(self) -> bytes | None:
        """Always None: a DBC message is a signal message."""
        return None

    @property
    def length(self) -> int:
        """Payload length in bytes (DBC message length)."""
        return int(self._msg.length)

    @property
    def signal_names(self) -> tuple[str, ...]:
        """Our signal names, in mapping order."""
        return tuple(self._map)

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Payload for the physical ``values``; LayoutError naming message and signal when missing or out of range."""
        dbc_values: dict[str, float] = dict(self._defaults)
        for ours, sig in self._sig.items():
            where = f"message {show(self.name)} signal {show(ours)} ({show(sig.name)})"
            if ours not in values:
                raise LayoutError(f"message {show(self.name)}: missing value for signal {show(ours)}")
            value = values[ours]
            if not is_number(value):
                raise LayoutError(f"{where}: value must be a number, got {show(value)}")
            if not sig.is_float:
                if not math.isfinite(value):
                    raise LayoutError(f"{where}: cannot encode non-finite value {value!r} as an integer")
                raw = round((float(value) - sig.offset) / sig.scale)
                lo, hi = _raw_limits(sig)
                if not lo <= raw <= hi:
                    raise LayoutError(f"{where}: value {value!r} gives raw {raw}, outside {lo}..{hi}")
            dbc_values[sig.name] = value
        try:
            return bytes(self._msg.encode(dbc_values, scaling=True, strict=True))
        except Exception as exc:  # cantools raises EncodeError, OverflowError, ValueError
            raise LayoutError(f"message {show(self.name)}: {exc}") from exc

    def carried(self, name: str, values: np.ndarray) -> np.ndarray:
        """The physical values our signal ``name``'s frames carry for ``values``: an integer signal's rounding to
        its scale, a 32-bit float's to its precision."""
        sig = self._sig[name]
        return carried_values(values, float(sig.scale), float(sig.offset), not sig.is_float, sig.length)

    def decode(self, payload: bytes) -> dict[str, float]:
        """Physical value of every mapped signal; LayoutError naming the message on a short payload."""
        if len(payload) < self.length:
            raise LayoutError(
                f"message {show(self.name)} (id 0x{self.id:X}): payload is {len(payload)} bytes, needs {self.length}"
            )
        try:
            decoded = self._msg.decode(bytes(payload[: self.length]), decode_choices=False, scaling=True)
        except Exception as exc:  # cantools DecodeError and friends
            raise LayoutError(f"message {show(self.name)}: {exc}") from exc
        if not isinstance(decoded, dict):  # a container message (DBC files define none)
            raise LayoutError(f"message {show(self.name)}: not a message of signals")
        values: dict[str, float] = {}
        for ours, sig in self._sig.items():
            value = decoded[sig.name]
            if not isinstance(value, (int, float)):  # a value name (decode_choices=False gives none)
                raise LayoutError(f"message {show(self.name)} signal {show(ours)}: {value!r} is not a number")
            values[ours] = float(value)
        return values

    def dbc_signal(self, name: str) -> DbcSignal:
        """The DBC signal (``cantools.database.can.Signal``) that carries our signal ``name``."""
        if name not in self._sig:
            raise LayoutError(f"message {show(self.name)} has no signal {show(name)}")
        return self._sig[name]

    def integer_modulus(self, name: str) -> int | None:
        """``2**bits`` when our signal ``name`` is an unsigned integer with unit scale and zero offset, else None."""
        if name not in self._sig:
            raise LayoutError(f"message {show(self.name)} has no signal {show(name)}")
        sig = self._sig[name]
        if sig.is_float or sig.is_signed or sig.scale != 1 or sig.offset != 0:
            return None
        return 1 << int(sig.length)


def _raw_limits(sig: DbcSignal) -> tuple[int, int]:
    bits = int(sig.length)
    if sig.is_signed:
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


def _default_value(sig: DbcSignal) -> float:
    """Physical value sent for an unmapped DBC signal: its initial value, else 0 moved into [minimum, maximum]."""
    if sig.raw_initial is not None:
        # the number, also for a signal with value names (whose ``initial`` is the name of the value)
        initial = sig.conversion.raw_to_scaled(sig.raw_initial, decode_choices=False)
        if isinstance(initial, (int, float)):
            return float(initial)
    value = 0.0
    if sig.minimum is not None and value < sig.minimum:
        value = float(sig.minimum)
    if sig.maximum is not None and value > sig.maximum:
        value = float(sig.maximum)
    return value


def read_dbc_frames(reader: TableReader, path: Path, mapping: Mapping[str, object]) -> Roles:
    """The messages of DBC file ``path`` that the ``[frames]`` table ``mapping`` (without ``dbc``) names, by role
    (see ``Layout.from_dbc``); ``reader`` reports the faults."""
    import cantools

    table = reader.table(mapping, "frames")
    reader.known(table, "frames", FRAMES_KEYS)
    watchdog = reader.number(table["drive_watchdog_s"], "frames.drive_watchdog_s") if "drive_watchdog_s" in table \
        else 0.0
    try:
        db = cantools.database.load_file(str(path), database_format="dbc")
        text = path.read_text(encoding="latin-1")
    except Exception as exc:  # missing file, parse errors
        prefix = f"{reader.source}: " if reader.source else ""
        raise LayoutError(f"{prefix}frames.dbc: cannot load {str(path)!r}: {' '.join(str(exc).split())}") from exc
    if not isinstance(db, cantools.database.can.Database):  # what database_format="dbc" loads
        reader.fail("frames.dbc", f"{path.name} is not a CAN database")
    for number, line in enumerate(text.splitlines(), 1):  # what the DBC parser lets through
        found = _SIGNAL_LINE.match(line)
        if found and (found["order"] not in "01" or found["sign"] not in "+-"):
            reader.fail("frames.dbc", f"{path.name} line {number}: signal {show(found['name'])}: "
                                      f"@{found['order']}{found['sign']} is not a byte order (@0 big-endian, @1 "
                                      "little-endian) and sign (+ unsigned, - signed)")

    def find(sub: Mapping[str, object], where: str) -> DbcDefinition:
        name = reader.require(sub, where, "message")
        if not isinstance(name, str):
            reader.fail(f"{where}.message", f"a DBC message name, got {show(name)}")
        try:
            return db.get_message_by_name(name)
        except KeyError:
            names = ", ".join(m.name for m in db.messages)
            reader.fail(f"{where}.message", f"no message {show(name)} in {path.name} (it has {names})")

    def signal_message(value: object, where: str) -> DbcMessage:
        sub = reader.table(value, where)
        reader.known(sub, where, {"message", "signals"})
        db_msg = find(sub, where)
        signals: dict[str, str] | None = None
        given = sub.get("signals")
        if given is not None:
            signals = {}
            for ours, theirs in reader.table(given, f"{where}.signals").items():
                if not isinstance(theirs, str):
                    reader.fail(f"{where}.signals.{ours}", f"a DBC signal name, got {show(theirs)}")
                signals[ours] = theirs
        try:
            return DbcMessage(db_msg, signals)
        except LayoutError as exc:
            reader.fail(where, str(exc))

    def fixed_message(value: object, where: str, role: str) -> tuple[Message, float]:
        sub = reader.table(value, where)
        allowed = {"message", "values", "period_s"} if role == "heartbeat" else {"message", "values"}
        reader.known(sub, where, allowed)
        db_msg = find(sub, where)
        values = reader.table(sub.get("values", {}), f"{where}.values")
        by_name = {sig.name: sig for sig in db_msg.signals}
        full: dict[str, float] = {name: _default_value(sig) for name, sig in by_name.items()}
        for key, val in values.items():
            if key not in by_name:
                reader.fail(f"{where}.values.{key}", f"no signal {show(key)} in DBC message {show(db_msg.name)}")
            full[key] = reader.number(val, f"{where}.values.{key}")
        try:
            payload = bytes(db_msg.encode(full, scaling=True, strict=True))
        except Exception as exc:
            reader.fail(f"{where}.values", f"cannot encode: {exc}")
        period = reader.number(sub["period_s"], f"{where}.period_s") if "period_s" in sub else 0.0
        try:
            msg = Message(str(db_msg.name), int(db_msg.frame_id), bool(db_msg.is_extended_frame), data=payload)
        except LayoutError as exc:
            reader.fail(where, str(exc))
        return msg, period

    setpoint = signal_message(reader.require(table, "frames", "setpoint"), "frames.setpoint")
    feedback = tuple(signal_message(item, f"frames.feedback[{i}]")
                     for i, item in enumerate(reader.feedback_tables(table)))
    optional: dict[str, Message | None] = {"enable": None, "disable": None, "heartbeat": None}
    period = 0.0
    for role in optional:
        if role in table:
            optional[role], p = fixed_message(table[role], f"frames.{role}", role)
            if role == "heartbeat":
                period = p
    return Roles(setpoint, feedback, optional["enable"], optional["disable"], optional["heartbeat"], period,
                 watchdog)


@dataclass(frozen=True)
class SignalSpec:
    """Where one signal of a message lies, in a DBC file's terms: ``start`` bit (DBC numbering: the least
    significant bit of a little-endian signal, the most significant of a big-endian one, bit b of byte n being 8 n +
    b), ``length`` in bits, ``byte_order`` ("little_endian" or "big_endian"), ``signed``, ``is_float`` (IEEE),
    ``scale`` and ``offset`` (physical = raw * scale + offset)."""

    name: str
    start: int
    length: int
    byte_order: Literal["little_endian", "big_endian"]
    signed: bool
    is_float: bool
    scale: float
    offset: float


def _spec_of_signal(sig: Signal) -> SignalSpec:
    bits = 8 * sig.size
    little = sig.endian == "little"
    start = 8 * sig.byte if little else 8 * sig.byte + 7  # a big-endian signal starts at its first byte's bit 7
    signed = sig.raw_range is None or sig.raw_range[0] < 0  # an IEEE float is signed
    return SignalSpec(sig.name, start, bits, "little_endian" if little else "big_endian", signed,
                      not sig.is_integer, float(sig.scale), float(sig.offset))


def signal_specs(message: Codec) -> tuple[SignalSpec, ...]:
    """The signals of a signal message (a ``Message`` of a [frames] table, or a ``DbcMessage``) under our names, in
    the message's order; () for a fixed-data message."""
    if isinstance(message, DbcMessage):
        specs = []
        for ours in message.signal_names:
            sig = message.dbc_signal(ours)
            order: Literal["little_endian", "big_endian"] = \
                "big_endian" if sig.byte_order == "big_endian" else "little_endian"
            specs.append(SignalSpec(ours, int(sig.start), int(sig.length), order, bool(sig.is_signed),
                                    bool(sig.is_float), float(sig.scale), float(sig.offset)))
        return tuple(specs)
    if isinstance(message, Message):
        return tuple(_spec_of_signal(sig) for sig in message.signals)
    raise LayoutError(f"message {show(message.name)}: not a message of signals bodebench knows")


def _identifier(text: str) -> str:
    """``text`` as a DBC (C) identifier."""
    name = re.sub(r"\W", "_", text)
    return name if name and not name[0].isdigit() else f"_{name}"


def layout_database(layout: Layout, comment: str = "") -> Any:
    """The setpoint and feedback messages of ``layout`` as a ``cantools.database.can.Database`` (our signal names,
    each with its bit position, length, byte order, sign, scale and offset; the host sends the setpoint, the drive the
    feedback). The fixed-data enable, disable and heartbeat frames have no signals to describe and may share an id:
    they are listed in the database comment after ``comment``."""
    from cantools.database.can import Bus, Database, Node
    from cantools.database.can import Message as DbcDefinition
    from cantools.database.can import Signal as DbcSignal
    from cantools.database.conversion import BaseConversion

    def definition(message: Codec, name: str, sender: str, receiver: str, role: str) -> DbcDefinition:
        signals = [DbcSignal(spec.name, spec.start, spec.length, byte_order=spec.byte_order, is_signed=spec.signed,
                             conversion=BaseConversion.factory(spec.scale, spec.offset, is_float=spec.is_float),
                             receivers=[receiver])
                   for spec in signal_specs(message)]
        return DbcDefinition(message.id, _identifier(name), message.length, signals, senders=[sender],
                             is_extended_frame=message.extended, comment=role)

    several = len(layout.feedback) > 1
    messages = [definition(layout.setpoint, "setpoint", "HOST", "DRIVE", "bodebench setpoint, sent at bench.rate_hz")]
    messages += [definition(m, f"feedback_{i + 1}" if several else "feedback", "DRIVE", "HOST",
                            f"bodebench feedback{f' {i + 1} of {len(layout.feedback)}' if several else ''}, "
                            "once a sample")
                 for i, m in enumerate(layout.feedback)]
    fixed = [f"{role} id 0x{m.id:X}{' (29-bit)' if m.extended else ''} data {bytes(m.data or b'').hex(' ') or 'none'}"
             + (f" every {layout.heartbeat_period_s:g} s" if role == "heartbeat" else "")
             for role, m in (("enable", layout.enable), ("disable", layout.disable), ("heartbeat", layout.heartbeat))
             if m is not None]
    text = "; ".join(filter(None, [comment, *fixed])).replace('"', "'")
    buses = [Bus("bench", comment=text)] if text else []
    return Database(messages, [Node("HOST"), Node("DRIVE")], buses, version="")
