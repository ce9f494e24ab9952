"""Reading the ``[frames]`` table of a configuration into messages by role (see drivers/PROTOCOL.md).

``TableReader`` checks configuration values with errors that name the source file and the key path of the fault;
``read_frames`` reads a table that defines its messages itself (``drivers.dbc.read_dbc_frames`` reads one whose
messages come from a DBC file). Both give ``Roles``, from which ``drivers.layout.Layout`` is built.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from typing import Any, NamedTuple, NoReturn, TypeVar

from .codec import Codec, Message, Signal, is_finite, is_int, show, signal_problem
from .errors import LayoutError

__all__ = ["FRAMES_KEYS", "Roles", "TableReader", "read_frames"]

FRAMES_KEYS = frozenset({"setpoint", "feedback", "enable", "disable", "heartbeat", "drive_watchdog_s"})
"""Keys of a ``[frames]`` table besides ``dbc``."""
_SIGNAL_KEYS = ("name", "byte", "type", "endian", "scale", "offset")
_REQUIRED_SIGNAL_KEYS = ("name", "byte", "type")

_T = TypeVar("_T")


class Roles(NamedTuple):
    """The messages of a layout by role, in the order of ``Layout``'s fields; periods in s."""

    setpoint: Codec
    feedback: tuple[Codec, ...]
    enable: Codec | None
    disable: Codec | None
    heartbeat: Codec | None
    heartbeat_period_s: float
    drive_watchdog_s: float


class TableReader:
    """Checks configuration values; every error is a LayoutError naming ``source`` (a file name, or "") and the key
    path of the fault."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, path: str, problem: str) -> NoReturn:
        """Raise LayoutError: ``problem`` at key ``path``."""
        prefix = f"{self.source}: " if self.source else ""
        raise LayoutError(f"{prefix}{path}: {problem}")

    def table(self, value: object, path: str) -> Mapping[str, object]:
        """``value`` when it is a table (a mapping)."""
        if not isinstance(value, Mapping):
            self.fail(path, f"a table, got {show(value)}")
        return value

    def known(self, table: Mapping[str, object], path: str, allowed: Collection[str]) -> None:
        """Refuse keys of ``table`` outside ``allowed``."""
        unknown = sorted(str(k) for k in table if k not in allowed)
        if unknown:
            self.fail(path, f"unknown key(s) {', '.join(unknown)} (allowed: {', '.join(sorted(allowed))})")

    def require(self, table: Mapping[str, object], path: str, key: str) -> object:
        """``table[key]``, which must be there."""
        if key not in table:
            self.fail(f"{path}.{key}", "missing")
        return table[key]

    def number(self, value: object, path: str) -> float:
        """``value`` as a float when it is a finite number."""
        if not is_finite(value):
            self.fail(path, f"a finite number, got {show(value)}")
        return float(value)

    def build(self, make: Callable[[], _T]) -> _T:
        """``make()``, its LayoutError reported at key ``frames``."""
        try:
            return make()
        except LayoutError as exc:
            self.fail("frames", str(exc))

    def feedback_tables(self, table: Mapping[str, object]) -> Sequence[object]:
        """The entries of ``frames.feedback``: one table, or a non-empty list of them."""
        entries = self.require(table, "frames", "feedback")
        if isinstance(entries, Mapping):
            return [entries]
        if not isinstance(entries, Sequence) or isinstance(entries, (str, bytes)) or not entries:
            self.fail("frames.feedback", f"a non-empty list of tables, got {show(entries)}")
        return entries

    def signal(self, value: object, path: str) -> Signal:
        """A signal from its table (``name``, ``byte``, ``type``; optional ``endian``, ``scale``, ``offset``)."""
        table = self.table(value, path)
        self.known(table, path, set(_SIGNAL_KEYS))
        kwargs: dict[str, Any] = {}  # checked by signal_problem: str, int, str, str, float, float
        for key in _SIGNAL_KEYS:
            if key not in table:
                if key in _REQUIRED_SIGNAL_KEYS:
                    self.fail(f"{path}.{key}", "missing")
                continue
            problem = signal_problem(key, table[key])
            if problem is not None:
                self.fail(f"{path}.{key}", problem)
            kwargs[key] = table[key]
        for key in ("scale", "offset"):
            if key in kwargs:
                kwargs[key] = float(kwargs[key])
        return Signal(**kwargs)

    def message(self, value: object, path: str, name: str) -> Message:
        """A message from its table (``id``, ``extended``, ``signals`` or ``data``, optional ``name``; ``name`` is
        the default name)."""
        table = self.table(value, path)
        self.known(table, path, {"id", "extended", "signals", "data", "name"})
        msg_id = self.require(table, path, "id")
        if not is_int(msg_id) or msg_id < 0:
            self.fail(f"{path}.id", f"a non-negative integer, got {show(msg_id)}")
        extended = table.get("extended", False)
        if not isinstance(extended, bool):
            self.fail(f"{path}.extended", f"true or false, got {show(extended)}")
        if "name" in table:
            given = table["name"]
            if not isinstance(given, str) or not given:
                self.fail(f"{path}.name", f"a non-empty string, got {show(given)}")
            name = given
        signals: tuple[Signal, ...] = ()
        if "signals" in table:
            raw = table["signals"]
            if not isinstance(raw, Sequence) or isinstance(raw, (str, bytes)):
                self.fail(f"{path}.signals", f"a list of tables, got {show(raw)}")
            signals = tuple(self.signal(item, f"{path}.signals[{i}]") for i, item in enumerate(raw))
        data: bytes | None = None
        if "data" in table:
            raw = table["data"]
            if isinstance(raw, (bytes, bytearray)):
                data = bytes(raw)
            elif isinstance(raw, Sequence) and not isinstance(raw, str):
                for i, item in enumerate(raw):
                    if not is_int(item) or not 0 <= item <= 255:
                        self.fail(f"{path}.data[{i}]", f"a byte 0..255, got {show(item)}")
                data = bytes(raw)
            else:
                self.fail(f"{path}.data", f"a list of bytes 0..255, got {show(raw)}")
        if data is not None and signals:
            self.fail(path, "give either signals or data, not both")
        if data is None and not signals:
            self.fail(path, "needs signals or data")
        try:
            return Message(name, msg_id, extended, signals, data)
        except LayoutError as exc:
            self.fail(path, str(exc))


def read_frames(reader: TableReader, table: Mapping[str, object]) -> Roles:
    """The messages a ``[frames]`` table without ``dbc`` defines (``table`` is that table, checked by ``reader``)."""
    reader.known(table, "frames", FRAMES_KEYS)
    watchdog = reader.number(table["drive_watchdog_s"], "frames.drive_watchdog_s") if "drive_watchdog_s" in table \
        else 0.0
    setpoint = reader.message(reader.require(table, "frames", "setpoint"), "frames.setpoint", "setpoint")
    feedback = tuple(
        reader.message(item, f"frames.feedback[{i}]", f"feedback[{i}]")
        for i, item in enumerate(reader.feedback_tables(table))
    )
    optional: dict[str, Message | None] = {}
    period = 0.0
    for role in ("enable", "disable", "heartbeat"):
        if role in table:
            sub = reader.table(table[role], f"frames.{role}")
            if role == "heartbeat" and "period_s" in sub:
                period = reader.number(sub["period_s"], "frames.heartbeat.period_s")
                sub = {k: v for k, v in sub.items() if k != "period_s"}
            optional[role] = reader.message(sub, f"frames.{role}", role)
        else:
            optional[role] = None
    return Roles(setpoint, feedback, optional["enable"], optional["disable"], optional["heartbeat"], period,
                 watchdog)
