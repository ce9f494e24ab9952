"""Frame layouts: the set of messages a bench uses and their roles (pure, no I/O).

A ``Layout`` names the roles: the setpoint message sent to the controller, the feedback messages that make up one
sample, and the optional enable, disable and heartbeat messages. Its messages are codecs (drivers.codec: ``Message``
with fixed-position signals, or ``drivers.dbc.DbcMessage`` from a DBC file); both ends of the link (the instrument
and a simulated controller) share them. ``Layout.from_mapping`` builds a layout from the ``[frames]`` table of a
configuration.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from .codec import (
    COUNTER,
    CRC,
    SETPOINT,
    SETPOINT_ECHO,
    SIGNAL_TYPES,
    TIMESTAMP,
    Codec,
    Message,
    Signal,
    is_finite,
    show,
)
from .e2e import crc_byte
from .errors import LayoutError
from .tables import Roles, TableReader, read_frames

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

CAN_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
"""The payload lengths a CAN FD frame can have (its DLC codes 0 to 15)."""

_TRANSPORTS = {
    # transport -> (largest payload in bytes, largest standard id, largest extended id)
    "can": (8, 0x7FF, 0x1FFFFFFF),
    "can-fd": (64, 0x7FF, 0x1FFFFFFF),
    "serial-binary": (64, 0xFF, 0xFF),
    "serial-ascii": (64, 0xFFF, 0xFFF),
}


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
        """Every rule of a layout, in four parts; LayoutError naming the message or key at fault."""
        self._check_roles()
        self._check_signals()
        self._check_ids()
        self._check_timing()

    def _check_roles(self) -> None:
        """Each role is a message of its kind: signals where samples go, fixed data for the commands."""
        for role, msg in (("setpoint", self.setpoint), ("enable", self.enable), ("disable", self.disable),
                          ("heartbeat", self.heartbeat)):
            if msg is not None and not isinstance(msg, Codec):
                raise LayoutError(f"{role}: expected a message, got {show(msg)}")
        if not self.feedback:
            raise LayoutError("feedback: needs at least one message")
        for msg in self.feedback:
            if not isinstance(msg, Codec):
                raise LayoutError(f"feedback: expected messages, got {show(msg)}")
        sp = self.setpoint
        if SETPOINT not in sp.signal_names:
            raise LayoutError(f"setpoint message {show(sp.name)}: needs a signal named \"setpoint\"")
        for msg in self.feedback:
            if msg.data is not None or not msg.signal_names:
                raise LayoutError(f"feedback message {show(msg.name)}: needs signals, not fixed data")
        for role, msg in (("enable", self.enable), ("disable", self.disable), ("heartbeat", self.heartbeat)):
            if msg is not None and msg.data is None:
                raise LayoutError(f"{role} message {show(msg.name)}: must be a fixed-data message")

    def _check_signals(self) -> None:
        """Counters, time stamps, check bytes and channels: their types, widths and where they may appear."""
        sp = self.setpoint
        # counters: unsigned integers with unit scale, one width everywhere
        moduli: dict[str, int] = {}
        for msg in (sp, *self.feedback):
            if COUNTER in msg.signal_names:
                modulus = msg.integer_modulus(COUNTER)
                if modulus is None or modulus > 1 << 16:
                    raise LayoutError(
                        f"message {show(msg.name)} signal \"counter\": must be uint8 or uint16 with scale 1 and "
                        "offset 0"
                    )
                moduli[msg.name] = modulus
        if len(set(moduli.values())) > 1:
            detail = ", ".join(f"{show(n)}: {m.bit_length() - 1} bits" for n, m in moduli.items())
            raise LayoutError(f"counter signals must all have the same width ({detail})")
        if len(self.feedback) > 1:
            for msg in self.feedback:
                if COUNTER not in msg.signal_names:
                    raise LayoutError(
                        f"feedback message {show(msg.name)}: needs a \"counter\" signal when a sample spans "
                        f"{len(self.feedback)} feedback messages"
                    )
        for msg in self.feedback:
            if TIMESTAMP in msg.signal_names and msg.integer_modulus(TIMESTAMP) is None:
                raise LayoutError(
                    f"message {show(msg.name)} signal \"timestamp_us\": must be an unsigned integer with scale 1 "
                    "and offset 0"
                )
        for msg in self.feedback:
            crc_byte(msg)  # a crc signal must fill exactly one byte (LayoutError naming the message)
        seen_channels: dict[str, str] = {}
        for msg in self.feedback:
            for name in msg.signal_names:
                if name in (COUNTER, TIMESTAMP, CRC):
                    continue
                if name in seen_channels:
                    raise LayoutError(
                        f"channel {show(name)} appears in feedback messages {show(seen_channels[name])} and "
                        f"{show(msg.name)}"
                    )
                seen_channels[name] = msg.name
        for name in sp.signal_names:
            if name not in (SETPOINT, COUNTER):
                raise LayoutError(
                    f"setpoint message {show(sp.name)}: unexpected signal {show(name)} (only \"setpoint\" and "
                    "\"counter\")"
                )
    def _check_ids(self) -> None:
        """Feedback ids distinct from each other and from every command id; the setpoint id distinct from the
        fixed-data command ids. Fixed-data commands may share an id (e.g. enable/disable told apart by content)."""
        sp = self.setpoint
        owners: dict[tuple[int, bool], str] = {}
        for msg in (sp, *self.feedback):
            if _key(msg) in owners:
                raise LayoutError(
                    f"messages {show(owners[_key(msg)])} and {show(msg.name)} share id 0x{msg.id:X}"
                )
            owners[_key(msg)] = msg.name
        for command in (self.enable, self.disable, self.heartbeat):
            if command is not None and _key(command) in owners:
                raise LayoutError(
                    f"messages {show(owners[_key(command)])} and {show(command.name)} share id 0x{command.id:X}"
                )
        commands = [(role, m) for role, m in (("enable", self.enable), ("disable", self.disable),
                                               ("heartbeat", self.heartbeat)) if m is not None]
        for i, (role, msg) in enumerate(commands):
            for other_role, other in commands[i + 1:]:
                if _key(msg) == _key(other) and msg.data == other.data:
                    raise LayoutError(f"{role} and {other_role} are the same frame (id 0x{msg.id:X}, data "
                                      f"{bytes(msg.data or b'').hex() or 'empty'}): the drive could not tell them "
                                      "apart")

    def _check_timing(self) -> None:
        """The heartbeat period and the drive's watchdog, and the one against the other."""
        period = self.heartbeat_period_s
        if not is_finite(period) or period < 0:
            raise LayoutError(f"heartbeat_period_s: a finite number >= 0 s, got {show(period)}")
        if self.heartbeat is not None and period <= 0:
            raise LayoutError("heartbeat_period_s: must be > 0 s when a heartbeat message is given")
        if self.heartbeat is None and period > 0:
            raise LayoutError("heartbeat_period_s: given without a heartbeat message")
        watchdog = self.drive_watchdog_s
        if not is_finite(watchdog) or watchdog < 0:
            raise LayoutError(f"drive_watchdog_s: a finite number >= 0 s, got {show(watchdog)}")
        if watchdog > 0 and period > watchdog / 2:
            raise LayoutError(f"heartbeat period_s: {period:g} s is more than half of drive_watchdog_s "
                              f"({watchdog:g} s): the drive would trip between heartbeats")

    def validate(self, transport: str = "can") -> None:
        """Check the layout for ``transport``: "can" (payload <= 8 bytes, 11/29-bit ids), "can-fd" (a CAN FD length of
        at most 64 bytes: 0 to 8, 12, 16, 20, 24, 32, 48 or 64), "serial-binary" (payload
        <= 64 bytes, id <= 0xFF) or "serial-ascii" (payload <= 64 bytes, id <= 0xFFF; 29-bit ids not allowed).

        Structural rules (unique ids, no overlaps, counters, channel names) are checked at construction and again
        here. Raises LayoutError naming the offending message.
        """
        if transport not in _TRANSPORTS:
            raise LayoutError(f"transport: one of {', '.join(_TRANSPORTS)}, got {show(transport)}")
        self._check_structure()
        max_payload, max_std, max_ext = _TRANSPORTS[transport]
        for msg in self.messages:
            if msg.length > max_payload:
                raise LayoutError(
                    f"message {show(msg.name)}: payload of {msg.length} bytes exceeds {max_payload} for {transport}"
                )
            if transport == "can-fd" and msg.length not in CAN_FD_LENGTHS:
                longer = min(n for n in CAN_FD_LENGTHS if n > msg.length)
                raise LayoutError(f"message {show(msg.name)}: payload of {msg.length} bytes is not a CAN FD length "
                                  f"(0 to 8, 12, 16, 20, 24, 32, 48, 64): a signal up to byte {longer - 1} fills it "
                                  f"to {longer}")
            limit = max_ext if msg.extended else max_std
            if msg.id > limit:
                raise LayoutError(f"message {show(msg.name)}: id 0x{msg.id:X} exceeds 0x{limit:X} for {transport}")
        if not transport.startswith("can"):
            # a serial line carries no extended flag: ids must be distinct as numbers
            owners: dict[int, Codec] = {}
            for msg in self.messages:
                other = owners.get(msg.id)
                if other is not None and not (other.data is not None and msg.data is not None):
                    raise LayoutError(
                        f"messages {show(other.name)} and {show(msg.name)} share id 0x{msg.id:X} on {transport}"
                    )
                owners.setdefault(msg.id, msg)

    # ----------------------------------------------------------------------------------------------------------
    # construction from configuration tables
    @classmethod
    def from_mapping(cls, d: Mapping[str, object], source: str = "") -> Layout:
        """Build a layout from the ``[frames]`` table of a configuration (see drivers/PROTOCOL.md).

        ``d`` is the content of ``[frames]`` (a mapping with ``frames`` as its only key is unwrapped). With a ``dbc``
        key the messages come from that DBC file (relative paths are taken relative to the directory of
        ``source``). Raises LayoutError naming ``source`` and the key path of the fault.
        """
        if isinstance(d, Mapping) and set(d) == {"frames"}:
            inner = d["frames"]
            if isinstance(inner, Mapping):
                d = inner
        reader = TableReader(source)
        table = reader.table(d, "frames")
        if "dbc" in table:
            dbc = table["dbc"]
            if not isinstance(dbc, (str, Path)) or not str(dbc):
                reader.fail("frames.dbc", f"a file path, got {show(dbc)}")
            path = Path(dbc)
            if not path.is_absolute() and source:
                path = Path(source).parent / path
            rest = {k: v for k, v in table.items() if k != "dbc"}
            return cls.from_dbc(path, rest, source)
        return cls._from_roles(reader, read_frames(reader, table))

    @classmethod
    def from_dbc(cls, path: str | Path, mapping: Mapping[str, object], source: str = "") -> Layout:
        """Build a layout whose messages are defined in the DBC file ``path``.

        ``mapping`` is the ``[frames]`` table without ``dbc``: ``setpoint`` and each ``feedback`` entry name a DBC
        ``message`` and map our signal names to DBC signal names (``signals = {setpoint = "SetpointPos"}``);
        ``enable``/``disable``/``heartbeat`` name a ``message`` and give DBC signal ``values`` for its fixed payload
        (``heartbeat`` also ``period_s``). Raises LayoutError naming the key path.
        """
        from .dbc import read_dbc_frames  # cantools is only needed for DBC layouts

        reader = TableReader(source)
        return cls._from_roles(reader, read_dbc_frames(reader, Path(path), mapping))

    @classmethod
    def _from_roles(cls, reader: TableReader, roles: Roles) -> Layout:
        """The layout of ``roles``; its LayoutError reported by ``reader`` at key ``frames``."""
        return reader.build(lambda: cls(*roles))


_DEFAULT_FRAMES: dict[str, object] = {
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

