"""Frame ports: send and receive frames over CAN (python-can) or a serial line (pyserial).

``FramePort`` does the shared work (counting, closed-state checks, mapping vendor exceptions to ``DriverError``
subclasses, batching received frames); a backend fills ``_send``, ``_recv`` and ``_close``. Both the instrument's
``Driver`` and a simulated controller use these ports.
"""

from __future__ import annotations

import importlib
import io
import os
import select
import struct
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol

from .codec import Codec
from .errors import DriverError, DriverInitError, DriverOperationError, DriverTimeoutError, LayoutError
from .extras import MissingDependency, missing
from .layout import Layout
from .serial_framing import (
    AsciiDeframer,
    BinaryDeframer,
    ascii_line,
    ascii_payload,
    encode_ascii,
    encode_binary,
)

try:  # POSIX: a tty's descriptor is read and written directly
    import fcntl
    import termios
except ImportError:  # Windows: pyserial's own read and write
    _DIRECT_FD = False
else:
    _DIRECT_FD = os.name == "posix"

if TYPE_CHECKING:  # python-can is imported where a CAN port is made
    import can
    from can.typechecking import Channel

__all__ = ["INTERFACE_NEEDS", "MAX_BATCH", "ByteLog", "CanPort", "CanSearch", "Frame", "FramePort", "SerialLine",
           "SerialPort", "detect_can", "interface_missing", "resolve_can_config"]

ErrorTypes = tuple[type[BaseException], ...]

MAX_BATCH = 256
"""Most frames one ``recv`` call returns; the rest wait for the next call."""


@dataclass(frozen=True)
class Frame:
    """One frame: ``id``, payload ``data``, 29-bit flag, reception ``timestamp`` (s; interface time where the
    interface provides one, else ``time.time()`` at reception; 0 for frames not yet sent) and error-frame flag."""

    id: int
    data: bytes
    extended: bool = False
    timestamp: float = 0.0
    is_error: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.id, int) or isinstance(self.id, bool) or self.id < 0:
            raise ValueError(f"Frame.id must be a non-negative integer, got {self.id!r}")
        if not isinstance(self.data, bytes):
            if isinstance(self.data, (bytearray, memoryview)):
                object.__setattr__(self, "data", bytes(self.data))
            else:
                raise ValueError(f"Frame.data must be bytes, got {type(self.data).__name__}")


class FramePort(ABC):
    """Base of all frame transports. Counts ``frames_in``, ``frames_out`` and ``errors`` (error frames and
    rejected input), remembers ``last_error`` (text), and is a context manager that closes the port.

    ``transport`` is the ``Layout.validate`` transport name of the port. Backends list their vendor exception types
    in ``_library_errors`` and implement ``_send``, ``_recv`` and ``_close``.
    """

    def __init__(self, name: str, transport: str) -> None:
        """``name`` describes the interface in error messages (e.g. "CAN socketcan:can0", "serial /dev/ttyUSB0");
        ``transport`` is "can", "serial-binary" or "serial-ascii"."""
        self.name = name
        self.transport = transport
        self._vendor_errors, self._timeout_errors = self._library_errors()
        self.frames_in = 0
        self.frames_out = 0
        self.errors = 0
        self.last_error = ""
        self.log_failure = ""
        """Why the traffic log stopped recording before the port closed ("" while it records, or without a log)."""
        self._closed = False
        self._queue: deque[Frame] = deque()

    @staticmethod
    def _library_errors() -> tuple[ErrorTypes, ErrorTypes]:
        """The backend library's exception types: (operation errors, timeout errors), imported when a port is
        made, so that importing this module loads neither python-can nor pyserial."""
        return (OSError,), ()

    # ----------------------------------------------------------------------------------------------------------
    # public API
    @property
    def closed(self) -> bool:
        """True after ``close()``."""
        return self._closed

    def send(self, frame: Frame) -> None:
        """Send one frame; DriverOperationError (DriverTimeoutError on a timeout) naming the port on failure."""
        if self._closed:
            raise DriverOperationError(f"{self.name}: port is closed")
        with self._vendor("send"):
            self._send(frame)
        self.frames_out += 1

    def recv(self, timeout: float) -> list[Frame]:
        """Wait up to ``timeout`` s for a first frame, then also take what is immediately available (at most
        ``MAX_BATCH`` frames in all). Returns [] when nothing arrived in time. Error frames are included (flagged
        ``is_error``) and counted in ``errors``."""
        if not isinstance(timeout, (int, float)) or not timeout >= 0:
            raise ValueError(f"recv timeout must be a number >= 0 s, got {timeout!r}")
        if self._closed:
            raise DriverOperationError(f"{self.name}: port is closed")
        if not self._queue:
            with self._vendor("receive"):
                self._queue.extend(self._recv(float(timeout), MAX_BATCH))
        batch: list[Frame] = []
        while self._queue and len(batch) < MAX_BATCH:
            batch.append(self._queue.popleft())
        for frame in batch:
            if frame.is_error:
                self._note_error(f"error frame 0x{frame.id:X} data {frame.data.hex()}")
        self.frames_in += len(batch)
        return batch

    def close(self) -> None:
        """Release the interface; further send/recv raise DriverOperationError. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        with self._vendor("close"):
            self._close()

    def end_log(self) -> None:
        """Stop recording the traffic: the log, if any, is completed and closed (the port stays open); a failure to
        complete it goes to ``log_failure``. Safe to call twice."""
        self._end_log()

    def send_periodic(self, frame: Frame, period_s: float) -> bool:
        """Have the interface repeat ``frame`` every ``period_s`` s on its own until ``close()``; False where the
        port cannot (the caller then sends it on time itself)."""
        if self._closed:
            raise DriverOperationError(f"{self.name}: port is closed")
        with self._vendor("periodic send"):
            return self._send_periodic(frame, period_s)

    def bus_state(self) -> str:
        """"active", "passive", "bus-off" or "unknown"."""
        if self._closed:
            return "unknown"
        try:
            return self._bus_state()
        except Exception:  # a backend that cannot tell
            return "unknown"

    def __enter__(self) -> FramePort:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"

    # ----------------------------------------------------------------------------------------------------------
    # shared helpers for backends
    def _note_error(self, text: str) -> None:
        """Count one error and remember its description."""
        self.errors += 1
        self.last_error = text

    @contextmanager
    def _vendor(self, action: str) -> Iterator[None]:
        """Re-raise vendor exceptions as DriverTimeoutError / DriverOperationError naming the port."""
        try:
            yield
        except DriverError:
            raise
        except self._timeout_errors as exc:
            self.last_error = f"{action} timed out: {exc}"
            raise DriverTimeoutError(f"{self.name}: {action} timed out: {exc}") from exc
        except self._vendor_errors as exc:
            self.last_error = f"{action} failed: {exc}"
            raise DriverOperationError(f"{self.name}: {action} failed: {exc}") from exc

    # ----------------------------------------------------------------------------------------------------------
    # backend hooks
    def _end_log(self) -> None:  # noqa: B027 - a hook: ports without a log have nothing to do
        """Complete and close the traffic log (ports without one: nothing to do)."""

    @abstractmethod
    def _send(self, frame: Frame) -> None:
        """Transmit ``frame``."""

    @abstractmethod
    def _recv(self, timeout: float, limit: int) -> list[Frame]:
        """Wait up to ``timeout`` s for a first frame, then return it plus up to ``limit`` - 1 frames available
        without waiting (more is allowed; the base class queues the excess)."""

    @abstractmethod
    def _close(self) -> None:
        """Release the interface."""

    def _bus_state(self) -> str:
        return "unknown"

    def _send_periodic(self, frame: Frame, period_s: float) -> bool:
        return False


# ----------------------------------------------------------------------------------------------------------------
# CAN
def resolve_can_config(interface: str = "", channel: str = "", bitrate: int | None = None,
                       context: str = "") -> dict[str, Any]:
    """python-can's bus configuration for these arguments, as ``can.Bus(interface=..., channel=..., bitrate=...,
    config_context=...)`` resolves it: the values given (empty: not given) first, then ``can.rc``, the environment
    (CAN_INTERFACE, CAN_CHANNEL, CAN_BITRATE, CAN_CONFIG) and the configuration files (``~/.canrc`` and the others
    ``can.util.load_config`` reads, section ``context`` before [default]). ValueError when no interface results
    or it is not one python-can knows."""
    import can
    import can.util

    given: dict[str, Any] = {}
    if interface:
        given["interface"] = interface
    if channel:
        given["channel"] = channel
    if bitrate is not None:
        given["bitrate"] = bitrate
    try:
        return dict(can.util.load_config(config=given, context=context or None))
    except can.CanInterfaceNotImplementedError as exc:
        if not interface and "None" in str(exc):
            raise ValueError("missing: not in the file, nor in python-can's configuration (CAN_INTERFACE, "
                             "~/.canrc)") from None
        raise ValueError(f"{exc} (python-can knows: {', '.join(sorted(can.VALID_INTERFACES))})") from None


INTERFACE_NEEDS: dict[str, str] = {"udp_multicast": "msgpack"}
"""python-can interfaces that need a package python-can does not install with itself -> that module
(:data:`bodebench.drivers.extras.EXTRAS` names the extra of bodebench that installs it)."""


def interface_missing(interface: str) -> MissingDependency | None:
    """Why python-can's ``interface`` cannot open here for want of a package (None when nothing is missing)."""
    module = INTERFACE_NEEDS.get(interface)
    if module is None:
        return None
    try:
        importlib.import_module(module)
    except ImportError:
        return missing(module, f"python-can's {interface} interface")
    return None


@dataclass(frozen=True)
class CanSearch:
    """What ``bodebench ports`` found: ``configs``, the bus configurations python-can detects on interfaces that can
    open here (dicts as ``can.detect_available_configs`` gives them), and ``unusable``: (interface, why) for each
    interface that cannot (a package missing, a vendor library absent) or, when it was asked for by name, found
    nothing."""

    configs: tuple[dict[str, Any], ...]
    unusable: tuple[tuple[str, str], ...]


def detect_can(interfaces: Sequence[str] | None = None) -> CanSearch:
    """The CAN configurations python-can detects on ``interfaces`` (None: every interface python-can knows), each
    interface that cannot work here with the reason. ValueError naming an interface python-can does not know."""
    import logging

    import can
    from can.interfaces import BACKENDS

    named = interfaces is not None
    names = list(dict.fromkeys(interfaces)) if interfaces is not None else sorted(BACKENDS)
    unknown = [name for name in names if name not in BACKENDS]
    if unknown:
        raise ValueError(f"python-can knows no interface {', '.join(repr(n) for n in unknown)} (it knows: "
                         f"{', '.join(sorted(BACKENDS))})")
    unusable: dict[str, str] = {}
    said: dict[str, list[str]] = {name: [] for name in names}  # what python-can logged of each interface
    loading: list[str] = []  # the interface being loaded

    class Said(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            text = " ".join(record.getMessage().split())
            owners = loading or [n for n in names if n in record.name.split(".")]
            for name in owners:
                said[name].append(text)

    logger = logging.getLogger("can")
    level, propagate = logger.level, logger.propagate
    handler = Said(logging.WARNING)
    loadable = []
    try:
        logger.setLevel(logging.WARNING)
        logger.propagate = False  # python-can's warnings become the reasons given, not log lines
        logger.addHandler(handler)
        for name in names:
            loading[:] = [name]
            try:
                module, attribute = BACKENDS[name]
                getattr(importlib.import_module(module), attribute)
            except Exception as exc:  # noqa: BLE001 - an interface module fails to load in its own ways
                unusable[name] = f"cannot be loaded: {' '.join(str(exc).split())}"
                continue
            finally:
                loading.clear()
            lacking = interface_missing(name)
            if lacking is not None:
                unusable[name] = str(lacking)
                continue
            loadable.append(name)
        found = can.detect_available_configs(interfaces=loadable) if loadable else []
        if named:
            detected = {c.get("interface") for c in found}
            for name in loadable:
                if name not in detected:
                    unusable[name] = _why_none(name, said[name])
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.propagate = propagate
    configs = tuple(dict(c) for c in found)
    return CanSearch(configs, tuple((name, unusable[name]) for name in names if name in unusable))


def _why_none(interface: str, said: Sequence[str]) -> str:
    """Why python-can found no channel of a loadable ``interface``: its vendor library missing, an interface that
    cannot list its channels, or none attached."""
    from can.interfaces import BACKENDS

    if interface == "pcan":  # python-can's PCAN detection returns nothing when PCAN-Basic cannot be loaded
        try:
            from can.interfaces.pcan.basic import PCANBasic

            PCANBasic()
        except OSError as exc:
            return f"the PCAN-Basic library from PEAK-System is not installed here ({exc})"
    module, attribute = BACKENDS[interface]
    try:
        getattr(importlib.import_module(module), attribute)._detect_available_configs()
    except NotImplementedError:
        return ("python-can cannot list its channels: give [can] channel yourself (a serial port for an adapter on "
                "one: bodebench ports lists those)")
    except Exception as exc:  # noqa: BLE001 - a vendor library fails in its own ways
        return f"searching failed: {' '.join(str(exc).split())}"
    told = f": python-can says {'; '.join(dict.fromkeys(said))}" if said else ""
    return f"no channel found (no adapter attached, or its vendor driver not installed){told}"


class CanPort(FramePort):
    """Frames on a python-can bus (any interface). Error frames are returned flagged ``is_error`` and counted."""

    @staticmethod
    def _library_errors() -> tuple[ErrorTypes, ErrorTypes]:
        import can

        return (can.CanError, OSError), (can.CanTimeoutError,)

    def __init__(self, bus: can.BusABC, *, name: str | None = None, send_timeout: float | None = 1.0,
                 owns_bus: bool = True, fd: bool = False, log: str | os.PathLike[str] | None = None) -> None:
        """Wrap the open ``can.BusABC`` ``bus``. ``send_timeout`` (s) bounds each send where the interface supports
        it; with ``owns_bus`` the bus is shut down by ``close()``. ``fd``: CAN FD, frames longer than 8 bytes go as
        FD frames (transport "can-fd"). ``log``: every frame sent and received goes to this file through python-can's
        ``can.Logger`` (its suffix picks the format: .asc, .blf, .log, .csv, ...); heartbeats are then sent by the
        caller rather than by the interface's periodic task, so that they are in the log too."""
        super().__init__(name or f"CAN {getattr(bus, 'channel_info', type(bus).__name__)}", "can-fd" if fd else "can")
        self._bus = bus
        self._send_timeout = send_timeout
        self._owns_bus = owns_bus
        self._fd = fd
        channel = getattr(bus, "channel_id", None) or getattr(bus, "channel", None)
        self._channel = channel if isinstance(channel, (str, int)) else None
        """The channel that sent frames are logged on (received ones carry the interface's)."""
        self._periodic: list[can.broadcastmanager.CyclicSendTaskABC] = []
        self._log: Any = None
        self._log_lock = threading.Lock()
        self._log_path = "" if log is None else os.fspath(log)
        self._log_channels: dict[Any, Any] = {}  # channel of a frame -> the channel its log entry gets
        self._log_short_channels = False  # the format keeps channel numbers in 16 bits
        if log is not None:
            import can as _can

            try:
                self._log = _can.Logger(log)
            except (OSError, ValueError) as exc:
                raise DriverInitError(f"cannot write the bus log {os.fspath(log)!r}: {exc}") from exc
            self._log_short_channels = isinstance(self._log, _can.BLFWriter)

    @classmethod
    def open(cls, interface: str, channel: Channel | None, bitrate: int | None = None,
             options: Mapping[str, Any] | None = None, *, fd: bool = False,
             log: str | os.PathLike[str] | None = None) -> CanPort:
        """Open ``can.Bus(interface=..., channel=..., bitrate=..., **options)``; DriverInitError naming interface and
        channel when that fails (``bitrate`` None leaves it to the interface, an empty ``interface`` or ``channel``
        to python-can's configuration). ``options`` are the interface's own keyword arguments, as python-can takes
        them (untyped). ``fd`` asks the interface for CAN FD (python-can's ``fd=True``); ``log`` as for the
        constructor."""
        import can

        kwargs = dict(options or {})
        if bitrate is not None:
            kwargs["bitrate"] = bitrate
        if fd:
            kwargs["fd"] = True
        name = f"CAN {interface}:{channel}"
        lacking = interface_missing(interface)
        if lacking is not None:
            raise DriverInitError(f"cannot open CAN interface {interface!r} channel {channel!r}: {lacking}")
        try:
            bus = can.Bus(interface=interface or None, channel=channel or None, **kwargs)
        except (can.CanError, OSError, ValueError, TypeError, ImportError, NotImplementedError) as exc:
            raise DriverInitError(f"cannot open CAN interface {interface!r} channel {channel!r}: {exc}") from exc
        try:
            return cls(bus, name=name, fd=fd, log=log)
        except BaseException:
            bus.shutdown()
            raise

    @property
    def bus(self) -> can.BusABC:
        """The wrapped python-can bus."""
        return self._bus

    @staticmethod
    def _message(frame: Frame) -> can.Message:
        import can

        return can.Message(arbitration_id=frame.id, data=frame.data, is_extended_id=frame.extended,
                           is_fd=len(frame.data) > 8, is_error_frame=frame.is_error)

    def _send(self, frame: Frame) -> None:
        msg = self._message(frame)
        self._bus.send(msg, timeout=self._send_timeout)
        if self._log is not None:
            msg.timestamp = time.time()
            msg.is_rx = False
            msg.channel = self._channel
            self._write_log(msg)

    def _logged_channel(self, channel: Any) -> Any:
        """The channel a frame's log entry names. A BLF entry holds the channel number python-can reads off the
        name's trailing digits, plus one, in 16 bits: a name whose digits make a larger number (a virtual channel
        named with a random hex suffix) is logged as the writer's default channel instead."""
        if not self._log_short_channels:
            return channel
        try:
            return self._log_channels[channel]
        except KeyError:
            import can.util

            number = can.util.channel2int(channel)
            logged = None if number is not None and not 0 <= number < 0xFFFF else channel
            self._log_channels[channel] = logged
            return logged
        except TypeError:  # a channel python-can cannot look up by value
            return None

    def _write_log(self, msg: can.Message) -> None:
        """One frame into the bus log. The log is a record, not the measurement: when it cannot take the frame (a
        full disk, a writer's error) it stops there, its failure kept in ``log_failure``, and the traffic goes on."""
        with self._log_lock:
            if self._log is None:
                return
            msg.channel = self._logged_channel(msg.channel)
            try:
                self._log(msg)
            except Exception as exc:  # noqa: BLE001 - any writer failure ends the log, never the session
                self._stop_log(exc)

    def _stop_log(self, exc: BaseException | None) -> None:
        """Close the log (lock held); ``exc``: the failure that ended it early (None: the end of the session)."""
        writer, self._log = self._log, None
        try:
            writer.stop()
        except Exception as error:  # noqa: BLE001 - the file may be what failed
            exc = exc or error
        handle = getattr(writer, "file", None)
        if handle is not None:
            with suppress(Exception):  # closed anyway: nothing left to flush later
                handle.close()
        if exc is not None and not self.log_failure:
            what = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc) or type(exc).__name__
            self.log_failure = f"{self._log_path}: {what}; nothing logged after {time.strftime('%H:%M:%S')}"

    def _end_log(self) -> None:
        with self._log_lock:
            if self._log is not None:
                self._stop_log(None)

    def _send_periodic(self, frame: Frame, period_s: float) -> bool:
        """python-can's periodic send (the kernel's broadcast manager on socketcan, a thread elsewhere); not with a
        bus log, whose file must see every frame sent."""
        if self._log is not None:
            return False
        self._periodic.append(self._bus.send_periodic(self._message(frame), period_s))
        return True

    def _recv(self, timeout: float, limit: int) -> list[Frame]:
        msg = self._bus.recv(timeout)
        out: list[Frame] = []
        while msg is not None:
            if self._log is not None:
                self._write_log(msg)
            out.append(self._to_frame(msg))
            if len(out) >= limit:
                break
            msg = self._bus.recv(0)
        return out

    @staticmethod
    def _to_frame(msg: can.Message) -> Frame:
        stamp = float(msg.timestamp) if msg.timestamp else time.time()
        return Frame(int(msg.arbitration_id), bytes(msg.data), bool(msg.is_extended_id), stamp,
                     bool(msg.is_error_frame))

    def _close(self) -> None:
        for task in self._periodic:
            task.stop()
        self._periodic.clear()
        try:
            if self._owns_bus:
                self._bus.shutdown()
        finally:
            self._end_log()

    def _bus_state(self) -> str:
        import can

        state = self._bus.state
        return {can.BusState.ACTIVE: "active", can.BusState.PASSIVE: "passive",
                can.BusState.ERROR: "bus-off"}.get(state, "unknown")


# ----------------------------------------------------------------------------------------------------------------
# serial
_FRAMINGS = ("binary", "ascii")


class SerialLine(Protocol):
    """What ``SerialPort`` needs of a serial line: a pyserial ``Serial`` opened with ``timeout=0``, or any object
    that reads what is there without waiting. A ``fileno()`` method, where there is one, gives the descriptor that
    ``SerialPort`` reads and writes directly (POSIX); ``port`` and ``baudrate`` attributes are used where present."""

    @property
    def in_waiting(self) -> int:
        """Bytes ready to be read."""
        ...

    def read(self, size: int, /) -> bytes:
        """At most ``size`` bytes, those there now (b"" when none)."""
        ...

    def write(self, data: bytes, /) -> int | None:
        """Send ``data``."""
        ...

    def close(self) -> None:
        """Release the line."""
        ...


class SerialPort(FramePort):
    """Frames on a serial line, binary or ASCII-line framed (drivers/PROTOCOL.md).

    Wraps a pyserial ``Serial`` (or any object with ``read``, ``write``, ``in_waiting``) opened with ``timeout=0``.
    Received frames carry the ``extended`` flag of the layout message with their id. With ASCII framing the layout
    converts between payloads and value fields; lines with ids not in the layout are dropped and counted in
    ``ignored``, lines whose fields do not fit their message count as errors. CRC/checksum failures and malformed
    lines count in ``errors``; ``resyncs`` and ``bytes_discarded`` come from the deframer.
    """

    @staticmethod
    def _library_errors() -> tuple[ErrorTypes, ErrorTypes]:
        import serial

        return (serial.SerialException, OSError), (serial.SerialTimeoutException,)

    _POLL_S = 0.0005  # s, sleep between polls while waiting for the first frame
    _CHUNK = 4096  # bytes read per call at most
    _MAX_READS = 16  # reads per poll at most

    def __init__(self, ser: SerialLine, framing: str, layout: Layout, *, name: str | None = None,
                 send_timeout: float = 1.0, frame_gap_s: float | None = None,
                 log: str | os.PathLike[str] | None = None) -> None:
        """Wrap the open serial object ``ser``; ``framing`` "binary" or "ascii"; ``layout`` is validated for it.
        ``send_timeout`` (s) bounds each send on a line that does not take the bytes; ``frame_gap_s`` (s): silence
        inside a frame after which it is taken as cut short (None: 20 characters' time at the line's baud rate, at
        least 2 ms). ``log``: every byte written and read goes to this file, as :class:`ByteLog` lines."""
        if framing not in _FRAMINGS:
            raise LayoutError(f'serial framing: one of "binary", "ascii", got {framing!r}')
        layout.validate(f"serial-{framing}")
        super().__init__(name or f"serial {getattr(ser, 'port', None) or type(ser).__name__}", f"serial-{framing}")
        self._ser = ser
        self._send_timeout = send_timeout
        self._fd = self._fileno()
        """The line's non-blocking descriptor (POSIX pyserial): read and written directly, since pyserial's
        blocking write waits in select() after every write (up to ms on a busy machine)."""
        if self._fd is not None:
            os.set_blocking(self._fd, False)
        self.framing = framing
        self.layout = layout
        self.ignored = 0
        """ASCII lines dropped because their id is not in the layout."""
        self._deframer: BinaryDeframer | AsciiDeframer = BinaryDeframer() if framing == "binary" else AsciiDeframer()
        self._by_id: dict[int, Codec] = {}
        for msg in layout.messages:
            self._by_id.setdefault(msg.id, msg)
        self._seen_framing_errors = 0
        self.broken_frames = 0
        """Frames cut short: the line went idle inside a frame for ``idle_s``; their bytes are dropped at once."""
        baudrate = getattr(ser, "baudrate", None)
        if frame_gap_s is None:
            frame_gap_s = max(2e-3, 200.0 / baudrate) if isinstance(baudrate, (int, float)) and baudrate > 0 else 2e-3
        self.idle_s = frame_gap_s
        """s of silence inside a frame after which it is taken as cut short."""
        self._last_byte = time.monotonic()
        self._log = ByteLog(log) if log is not None else None

    @classmethod
    def open(cls, port: str, baudrate: int, framing: str, layout: Layout, send_timeout: float = 1.0,
             frame_gap_s: float | None = None, log: str | os.PathLike[str] | None = None) -> SerialPort:
        """Open ``port`` (a device path or a pyserial URL such as "loop://") at ``baudrate`` with ``timeout=0``;
        DriverInitError naming the port when that fails. ``send_timeout`` (s): how long a write that stalls (the
        line's buffer full) is retried before it fails; ``frame_gap_s`` as for the constructor."""
        import serial

        if framing not in _FRAMINGS:
            raise LayoutError(f'serial framing: one of "binary", "ascii", got {framing!r}')
        layout.validate(f"serial-{framing}")
        try:
            ser = serial.serial_for_url(port, baudrate=baudrate, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DriverInitError(f"cannot open serial port {port!r} at {baudrate} baud: {exc}") from exc
        try:
            return cls(ser, framing, layout, name=f"serial {port}", send_timeout=send_timeout,
                       frame_gap_s=frame_gap_s, log=log)
        except BaseException:
            ser.close()
            raise

    @property
    def deframer(self) -> BinaryDeframer | AsciiDeframer:
        """The deframer (its counters: frames, crc_errors, bytes_discarded, resyncs)."""
        return self._deframer

    @property
    def resyncs(self) -> int:
        """Times the deframer lost frame alignment."""
        return self._deframer.resyncs

    @property
    def bytes_discarded(self) -> int:
        """Bytes the deframer dropped."""
        return self._deframer.bytes_discarded

    def wire_bytes(self, frame: Frame) -> bytes:
        """The bytes ``frame`` is on this line (binary frame or ASCII line); LayoutError when it does not fit."""
        if self.framing == "binary":
            return encode_binary(frame.id, frame.data)
        msg = self._by_id.get(frame.id)
        if msg is None or msg.data is not None:
            return ascii_line(frame.id, [frame.data.hex().upper()])
        return encode_ascii(msg, msg.decode(frame.data))

    def _send(self, frame: Frame) -> None:
        if frame.is_error:  # a serial line has no error frames
            return
        wire = self.wire_bytes(frame)
        if self._log is not None:
            self._log.write("TX", wire)
        if self._fd is None:
            self._ser.write(wire)
            return
        view = memoryview(wire)
        deadline = time.monotonic() + self._send_timeout
        while view:
            with suppress(BlockingIOError):
                view = view[os.write(self._fd, view):]
            if view:  # the line's buffer is full: wait until it drains, but not forever
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not select.select([], [self._fd], [], remaining)[1]:
                    raise self._timeout_errors[0](f"write stalled for {self._send_timeout:g} s with {len(view)} "
                                                  f"of {len(wire)} bytes unsent")

    def _read_some(self, readable: bool = False) -> bytes:
        """What the line holds now, at most ``_CHUNK`` bytes (b"" when nothing). ``readable``: select() just said
        so; then no bytes at all means the far end hung up (OSError)."""
        if self._fd is None:
            data = bytes(self._ser.read(min(max(int(self._ser.in_waiting), 1), self._CHUNK)))
            if data and self._log is not None:
                self._log.write("RX", data)
            return data
        size = self._CHUNK
        if not readable:
            # ask the count first: a read (or select) on a tty with nothing queued waits for the kernel's flush
            # worker, which on a busy machine can take milliseconds
            size = min(size, struct.unpack("i", fcntl.ioctl(self._fd, termios.FIONREAD, b"\0\0\0\0"))[0])
            if size <= 0:
                return b""
        try:
            data = os.read(self._fd, size)
        except BlockingIOError:
            return b""
        if readable and not data:
            raise OSError("the line hung up (end of file)")
        if data and self._log is not None:
            self._log.write("RX", data)
        return data

    def _read_available(self, readable: bool = False) -> list[Frame]:
        """Read and deframe what the line holds now (bounded, so a busy line cannot keep the caller here);
        ``readable`` as for ``_read_some``."""
        frames: list[Frame] = []
        for i in range(self._MAX_READS):
            data = self._read_some(readable and i == 0)
            if not data:
                break
            self._last_byte = time.monotonic()
            now = time.time()
            if isinstance(self._deframer, BinaryDeframer):
                for frame_id, payload in self._deframer.feed(data):
                    frames.append(self._frame(frame_id, payload, now))
            else:
                for frame_id, fields in self._deframer.feed(data):
                    msg = self._by_id.get(frame_id)
                    if msg is None:
                        self.ignored += 1
                        continue
                    try:
                        payload = ascii_payload(msg, fields)
                    except LayoutError as exc:
                        self._note_error(f"ASCII line id 0x{frame_id:X}: {exc}")
                        continue
                    frames.append(self._frame(frame_id, payload, now))
            if len(frames) >= MAX_BATCH or len(data) < self._CHUNK:
                break
        self._count_framing_errors()
        return frames

    def _frame(self, frame_id: int, payload: bytes, stamp: float) -> Frame:
        msg = self._by_id.get(frame_id)
        return Frame(frame_id, payload, msg.extended if msg is not None else False, stamp)

    def _count_framing_errors(self) -> None:
        d = self._deframer
        total = d.crc_errors + (d.format_errors if isinstance(d, AsciiDeframer) else 0)
        if total > self._seen_framing_errors:
            kind = "CRC" if isinstance(d, BinaryDeframer) else "checksum/format"
            self.errors += total - self._seen_framing_errors
            self.last_error = f"{kind} error on serial input ({total} so far)"
            self._seen_framing_errors = total

    def _recv(self, timeout: float, limit: int) -> list[Frame]:
        deadline = time.monotonic() + timeout
        fd = self._fd
        readable = False
        while True:
            frames = self._read_available(readable)
            if frames:
                return frames
            if self._deframer.pending:  # a frame has begun: if the line stays quiet, it was cut short
                quiet = time.monotonic() - self._last_byte
                if quiet >= self.idle_s:
                    self._deframer.drop_pending()
                    self.broken_frames += 1
                    self._note_error(f"a frame cut short ({self.broken_frames} so far): the line went quiet in it")
                    return []
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return []
            if self._deframer.pending:
                remaining = min(remaining, max(0.0, self.idle_s - (time.monotonic() - self._last_byte)) + 1e-4)
            if fd is not None:  # wake as soon as bytes arrive
                readable = bool(select.select([fd], [], [], remaining)[0])
            else:
                time.sleep(min(self._POLL_S, remaining))

    def _fileno(self) -> int | None:
        """The line's file descriptor where select() can wait on it (POSIX), else None."""
        fileno = getattr(self._ser, "fileno", None)
        if fileno is None:
            return None
        try:
            fd = fileno()
        except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
            return None
        return fd if isinstance(fd, int) and _DIRECT_FD else None

    def _close(self) -> None:
        try:
            self._ser.close()
        finally:
            self._end_log()

    def _end_log(self) -> None:
        if self._log is not None:
            self._log.close()
            self.log_failure = self._log.failure


class ByteLog:
    """A serial line's raw traffic, one text line per write or read: ``<unix time, s> <TX|RX> <bytes in hex>``,
    after a ``#`` header line. The time is the host's ``time.time()`` just before the write or just after the read;
    the lines are flushed as they are written."""

    HEADER = "# bodebench serial byte log: unix_time_s direction hex_bytes\n"

    def __init__(self, path: str | os.PathLike[str]) -> None:
        try:
            self._file = open(path, "w", encoding="ascii", buffering=1)  # noqa: SIM115 - open for the session
        except OSError as exc:
            raise DriverInitError(f"cannot write the bus log {os.fspath(path)!r}: {exc.strerror or exc}") from exc
        self._path = os.fspath(path)
        self._lock = threading.Lock()
        self.failure = ""
        """Why the log stopped recording early ("" while it records): the line is a record, never stopped by it."""
        self.write_line(self.HEADER)

    def write(self, direction: str, data: bytes) -> None:
        """One line for ``data`` sent ("TX") or received ("RX")."""
        self.write_line(f"{time.time():.6f} {direction} {data.hex()}\n")

    def write_line(self, line: str) -> None:
        """``line`` into the log; a write that fails ends the log there (``failure`` says why)."""
        with self._lock:
            if self._file.closed:
                return
            try:
                self._file.write(line)
            except (OSError, ValueError) as exc:
                self._fail(exc)

    def _fail(self, exc: OSError | ValueError) -> None:
        what = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        self.failure = self.failure or f"{self._path}: {what}; nothing logged after {time.strftime('%H:%M:%S')}"
        with suppress(OSError, ValueError):
            self._file.close()

    def close(self) -> None:
        with self._lock:
            if self._file.closed:
                return
            try:
                self._file.close()
            except (OSError, ValueError) as exc:
                self._fail(exc)

    @staticmethod
    def read(path: str | os.PathLike[str]) -> list[tuple[float, str, bytes]]:
        """The (time, direction, bytes) of every line of a byte log."""
        out: list[tuple[float, str, bytes]] = []
        with open(path, encoding="ascii") as handle:
            for line in handle:
                if line.startswith("#") or not line.strip():
                    continue
                stamp, direction, hexed = line.split()
                out.append((float(stamp), direction, bytes.fromhex(hexed)))
        return out

