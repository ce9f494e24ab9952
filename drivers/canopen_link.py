"""A CANopen device (a CiA 402 drive or a CiA 408 valve or hydraulic drive) as the instrument's ``Driver``: SDO
configuration, PDOs, SYNC, heartbeat and EMCY over the same python-can bus the other CAN links use (the ``canopen``
package speaks SDO and NMT). What differs between the profiles (modes, state machine, enable and exit steps) is a
``drivers.device_profile.DeviceProfile``.

``CanopenSetup`` is the resolved ``[canopen]`` table (objects looked up in the device's EDS); its ``layout()`` is the
frame layout of the cyclic PDOs, so the sample assembly, counter checks and bus health of ``Driver`` apply to
them unchanged. ``CanopenDriver`` adds the device's life cycle:

- ``enable()``: NMT pre-operational, heartbeat producer time (0x1017); a device in fault refused or reset, one under
  local control refused; the device parameters the scales assumed read and compared; the lost-host protection
  (below); the PDO mapping (RPDO: the setpoint object; TPDO: statusword, actual values, counter; both synchronous);
  the mode (CiA 402: modes of operation 0x6060, checked in 0x6061; CiA 408: device mode 0x6042 = 1 and control mode
  0x6043, each read back); NMT operational, then the profile's enable steps (CiA 402: shutdown, switch on, enable
  operation; CiA 408: DISABLED, HOLD, ACTIVE), each checked in the statusword;
- ``send_setpoint()``: the RPDO, then SYNC (when the host produces it; on the realtime clock with ``timebase``
  "sync", after a gap dated by rhythm, one SYNC is left out, or sent late where the drive watches its SYNC period,
  at a tick where the setpoint hardly moves, to check that the drive still answers within a SYNC period:
  ``drivers.sync_dating``);
- ``receive()``: TPDO samples, dated by the host tick of the SYNC they answer when the host produces SYNC: by the
  drive's sample counter (``timebase`` "counter") or, without one, by the order and receive times of the frames
  (``timebase`` "sync", ``drivers.sync_dating``); an EMCY, a statusword that leaves the running state ("operation
  enabled", ACTIVE), a heartbeat missing for ``heartbeat_timeout_s`` or an NMT state other than operational raise
  ``DriveFaultError``;
- ``disable()``: the profile's exit steps (CiA 402: quick stop, disable voltage; CiA 408: HOLD, DISABLED, no bit),
  the device's 0x1016 and 0x6007 written back, NMT pre-operational; returns whether the device was seen disabled,
  and ``shutdown_account`` says what was done and seen.

The lost-host protection: a host that dies (kill -9, a crash, a pulled cable) sends nothing more, so only the drive
can stop itself. Before enabling, the host becomes a heartbeat producer (node ``host_node_id``, COB-ID 0x700 + it,
every ``host_heartbeat_ms``, sent by python-can's periodic send, which ends with the process) and, where the drive's
EDS has them, writes the drive's heartbeat consumer time 0x1016 (the host's node id and
``drive_heartbeat_timeout_ms``) and its abort connection option code 0x6007 (``abort_connection``), reading the old
values first. ``disable()`` (or ``close()`` when no disable came) writes the old values back. A drive whose EDS has no
0x1016 cannot watch the host: that is logged and said in ``shutdown_account``, and the sweep goes on.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .cia402 import ABORT_CONNECTION_OPTIONS
from .codec import COUNTER, TIMESTAMP, Message, Signal
from .device_profile import PROFILES, DeviceProfile, Step
from .driver import Driver, FeedbackSample
from .errors import DriveFaultError, DriverOperationError, LayoutError
from .layout import Layout
from .ports import Frame, FramePort
from .scheduling import sleep_until
from .sync_dating import SyncMatcher

if TYPE_CHECKING:
    import canopen

__all__ = ["CanopenDriver", "CanopenSetup", "ObjectRef", "load_od", "resolve_object"]

log = logging.getLogger("bodebench.canopen")

STATUSWORD = 0x6041
CONTROLWORD_OBJECT = 0x6040
MODES_OF_OPERATION = 0x6060
MODES_DISPLAY = 0x6061
HEARTBEAT_PRODUCER = 0x1017
HEARTBEAT_CONSUMER = 0x1016
"""Consumer heartbeat time (ARRAY of UNSIGNED32): bits 16-23 the node watched, bits 0-15 the time in ms (0: off)."""
ABORT_CONNECTION = 0x6007
"""Abort connection option code (INTEGER16, CiA 402): ``cia402.ABORT_CONNECTION_OPTIONS``."""
HOST_HEARTBEAT_STATE = 0x05
"""The NMT state the host's heartbeat reports: operational."""
SYNC_COB_ID = 0x80
NMT_OPERATIONAL = 5
_SYNC_MEMORY = 4096
"""SYNCs whose host ticks are remembered (4 s at 1 kHz): a sample answering an older one is dated by the latest."""
NMT_STATES = {0: "boot-up", 4: "stopped", 5: "operational", 127: "pre-operational"}
ANSWER_PROBES = 64
"""SYNCs sent alone before enabling, on the realtime clock with ``timebase = "sync"``, to time the TPDO's answer."""
ANSWER_LIMIT = 0.75
"""The longest answer time, as a fraction of the time between SYNCs, that ``timebase = "sync"`` accepts from nine
answers in ten (``ANSWER_QUANTILE``): runs of answers later than a SYNC period could be dated by the next SYNC."""
ANSWER_QUANTILE = 0.9
"""The share of the timed answers that must come within ``ANSWER_LIMIT`` of the period (the rest: a busy host's
hiccups)."""

CHECK_STEP = 0.2
"""After a gap dated by rhythm, a SYNC is left out to check the answer time (``SyncMatcher.skip``) at the first idle
tick (a ramp, between points: ``Driver.send_setpoint``) whose setpoint step is at most this fraction of the largest
of the last ``CHECK_MEMORY`` steps, so that the setpoint the drive holds one tick longer is close to the one it
misses."""
CHECK_MEMORY = 256
"""Setpoint steps remembered for ``CHECK_STEP``."""
SYNC_PERIOD = 0x1006
"""Communication cycle period (UNSIGNED32, us; CiA 301): where the drive has it set, it watches its SYNC by it."""
CHECK_WATCHED = 1.2
"""The longest time between two SYNCs a check makes, as a multiple of the drive's communication cycle period where
it has one set (a CANopen stack that watches its SYNC reports a timeout at 1.5 times it): the check's SYNC is sent
late, not left out, when two SYNC periods would be longer."""

# CANopen data types (CiA 301) -> signal types of drivers.codec
_SIGNAL_TYPES = {0x2: "int8", 0x3: "int16", 0x4: "int32", 0x5: "uint8", 0x6: "uint16", 0x7: "uint32",
                 0x8: "float32", 0x11: "float64"}
_SIZES = {"int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4, "uint32": 4, "float32": 4, "float64": 8}


def _mapping_text(entries: Sequence[tuple[int, int, int]]) -> str:
    """PDO mapping entries (index, subindex, bits) in words: "[0x6041:00 16 bit, 0x6064:00 32 bit]"."""
    return "[" + ", ".join(f"0x{index:04X}:{subindex:02X} {bits} bit" for index, subindex, bits in entries) + "]"


@dataclass(frozen=True)
class ObjectRef:
    """One object of the device: ``index``, ``subindex``, its EDS ``name`` and signal ``type``."""

    index: int
    subindex: int
    name: str
    type: str

    @property
    def size(self) -> int:
        """Bytes the object takes in a PDO."""
        return _SIZES[self.type]

    @property
    def bits(self) -> int:
        """Bits the object takes in a PDO."""
        return 8 * self.size

    def __str__(self) -> str:
        return f"0x{self.index:04X}:{self.subindex:02X} ({self.name})"


def load_od(path: str | Path, node_id: int) -> canopen.ObjectDictionary:
    """The object dictionary of an EDS or DCF file; ValueError with the reason when it cannot be read."""
    import canopen

    try:
        return canopen.import_od(str(path), node_id)
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"cannot read the EDS {str(path)!r}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - a malformed file raises whatever its parser hits
        raise ValueError(f"cannot read the EDS {str(path)!r}: {type(exc).__name__}: {exc}") from None


def resolve_object(od: canopen.ObjectDictionary, text: str) -> ObjectRef:
    """The object ``text`` names: "0x607A", "0x607A:0" (index:subindex, hex or decimal) or its EDS name (a
    sub-object as "Record name.Sub name"). ValueError saying why when the EDS has no such numeric object."""
    from canopen.objectdictionary import ODArray, ODRecord, ODVariable

    text = text.strip()
    obj: Any
    lookup: Any = od
    head, sep, tail = text.partition(":")
    try:
        index = int(head, 0)
    except ValueError:
        index = None
    if index is not None:
        try:
            subindex = int(tail, 0) if sep else 0
        except ValueError:
            raise ValueError(f"{text!r}: subindex {tail!r} is not a number") from None
        if index not in od:
            raise ValueError(f"{text!r}: the EDS has no object 0x{index:04X}")
        obj = lookup[index]
        if isinstance(obj, (ODRecord, ODArray)):
            if subindex not in obj:
                raise ValueError(f"{text!r}: object 0x{index:04X} has no subindex {subindex}")
            obj = obj[subindex]
        elif sep and subindex != 0:
            raise ValueError(f"{text!r}: object 0x{index:04X} is a variable (subindex 0 only)")
    else:
        record, dot, member = text.partition(".")
        try:
            obj = lookup[text] if text in od or not dot else lookup[record][member]
        except KeyError:
            raise ValueError(f"{text!r}: no object of that name in the EDS") from None
    if not isinstance(obj, ODVariable):
        raise ValueError(f"{text!r}: {obj.name!r} is a record or array: name one of its sub-objects")
    kind = _SIGNAL_TYPES.get(obj.data_type or 0)
    if kind is None:
        raise ValueError(f"{text!r}: {obj.name!r} is not a number a PDO can carry (data type "
                         f"0x{obj.data_type or 0:X})")
    parent = getattr(obj, "parent", None)
    name = f"{parent.name}.{obj.name}" if isinstance(parent, (ODRecord, ODArray)) else obj.name
    return ObjectRef(obj.index, obj.subindex, name, kind)


@dataclass(frozen=True)
class CanopenSetup:
    """A resolved ``[canopen]`` table: everything the host and a simulated drive need, picklable.

    node_id: 1..127; eds: path of the EDS/DCF file; mode: a key of the profile's ``modes``; setpoint: the object the
    RPDO carries, ``setpoint_scale`` setpoint units per count; actual: (channel, object, units per count) in TPDO order
    after the statusword (the channel ``counter`` is the sample counter, ``timestamp_us`` a controller time); rpdo,
    tpdo: PDO numbers 1..4 (COB-IDs of the predefined connection set); sync: "produce" (a SYNC after each setpoint) or
    "consume" (another node produces it); heartbeat_ms: producer heartbeat time written to 0x1017 (0: left as the drive
    has it); heartbeat_timeout_s: a heartbeat missing this long is a fault; state_timeout_s: how long each SDO answer
    and each state change may take; fault_reset: a drive found in fault is reset (the profile's reset) instead of
    refused. The lost-host protection (module docstring): host_node_id: the host's own node id (1..127, not
    ``node_id``); host_heartbeat_ms: its heartbeat period (0: no heartbeat, no
    protection); drive_heartbeat_timeout_ms: the consumer time written to the drive's 0x1016 (longer than
    host_heartbeat_ms); abort_connection: the code written to 0x6007 (1 fault, 2 disable voltage, 3 quick stop), where
    the EDS has it. timebase: as ``[bench] timebase``. sync_period_s: the time between SYNCs when the host sends them
    on its own clock (``[bench] clock = "realtime"``), s; 0 when it waits for each answer (lockstep). profile: "402"
    or "408" (``drivers.device_profile``).
    assumed: (index, subindex, value, what) of device parameters the scales were derived from (a CiA 408 reference
    value or decimal prefix, from the EDS): read at enable, and a device that disagrees is refused. operating_point:
    where the RPDO carries another object than the mode's own target (an offset the drive adds inside its loop, such
    as the torque offset 0x60B2), that target and the actual value it is set to before enabling (None: zero), so the
    drive holds where it stands while the host excites the offset."""

    node_id: int
    eds: str
    mode: str
    setpoint: ObjectRef
    setpoint_scale: float
    actual: tuple[tuple[str, ObjectRef, float], ...]
    rpdo: int = 1
    tpdo: int = 1
    sync: str = "produce"
    heartbeat_ms: int = 100
    heartbeat_timeout_s: float = 0.5
    state_timeout_s: float = 1.0
    fault_reset: bool = False
    host_node_id: int = 127
    host_heartbeat_ms: int = 100
    drive_heartbeat_timeout_ms: int = 500
    abort_connection: int = ABORT_CONNECTION_OPTIONS["quick stop"]
    timebase: str = "counter"
    sync_period_s: float = 0.0
    profile: str = "402"
    assumed: tuple[tuple[int, int, int, str], ...] = ()
    operating_point: tuple[ObjectRef, ObjectRef | None] | None = None

    @property
    def device_profile(self) -> DeviceProfile:
        """The device profile ``profile`` names (``drivers.device_profile``)."""
        return PROFILES[self.profile]

    @property
    def times_answers(self) -> bool:
        """Whether the TPDO's answer to a SYNC is timed before enabling (``CanopenDriver._time_answers``): samples
        dated by SYNC (``timebase = "sync"``, host-produced SYNC) on the host's own clock (realtime)."""
        return self.timebase == "sync" and self.sync == "produce" and self.sync_period_s > 0

    @property
    def host_heartbeat_cob_id(self) -> int:
        """COB-ID of the host's heartbeat."""
        return 0x700 + self.host_node_id

    @property
    def consumer_value(self) -> int:
        """The value of the drive's 0x1016 sub-entry that watches the host: node id << 16 | consumer time in ms."""
        return (self.host_node_id << 16) | self.drive_heartbeat_timeout_ms

    @property
    def rpdo_cob_id(self) -> int:
        """COB-ID of the setpoint RPDO."""
        return 0x200 + 0x100 * (self.rpdo - 1) + self.node_id

    @property
    def tpdo_cob_id(self) -> int:
        """COB-ID of the feedback TPDO."""
        return 0x180 + 0x100 * (self.tpdo - 1) + self.node_id

    @property
    def channels(self) -> tuple[str, ...]:
        """The measured channels of the TPDO (counter and timestamp left out)."""
        return tuple(name for name, _, _ in self.actual if name not in (COUNTER, TIMESTAMP))

    def layout(self) -> Layout:
        """The cyclic PDOs as a frame layout: the RPDO carries "setpoint"; the TPDO the statusword (bytes 0-1, read
        by the driver itself) and then each actual value as a channel. LayoutError naming the problem."""
        setpoint = Message(f"RPDO{self.rpdo}", self.rpdo_cob_id,
                           signals=(Signal("setpoint", 0, self.setpoint.type, scale=self.setpoint_scale),))
        signals = []
        at = 2
        for name, ref, scale in self.actual:
            signals.append(Signal(name, at, ref.type, scale=scale))
            at += ref.size
        if at > 8:
            raise LayoutError(f"TPDO{self.tpdo}: statusword and actual values take {at} bytes, more than 8")
        feedback = Message(f"TPDO{self.tpdo}", self.tpdo_cob_id, signals=tuple(signals))
        layout = Layout(setpoint, (feedback,))
        layout.validate("can")
        return layout


def _port_network(port: FramePort) -> canopen.Network:
    """A canopen network for the SDO client and NMT master that sends through ``port`` (so the port counts every
    frame); received frames are handed to it with ``notify``."""
    import canopen

    class PortNetwork(canopen.Network):
        def send_message(self, can_id: int, data: Any, remote: bool = False) -> None:
            if remote:
                raise DriverOperationError(f"{port.name}: remote frames are not sent")
            port.send(Frame(can_id, bytes(data), can_id > 0x7FF))

        def send_periodic(self, can_id: int, data: Any, period: float, remote: bool = False) -> Any:
            raise DriverOperationError(f"{port.name}: periodic CANopen messages are not sent by the host")

    return PortNetwork(None)


def _same_values(a: FeedbackSample, b: FeedbackSample) -> bool:
    """Whether two TPDO samples carry the same values (a frame received twice, for ``SyncMatcher``)."""
    return a.values == b.values


def _sdo_failure(exc: Exception) -> str:
    """What an SDO transfer that failed without an abort met: no answer in time, or an answer it cannot take."""
    from .sdo_answers import NoSdoAnswer

    return "no SDO answer" if isinstance(exc, NoSdoAnswer) else "an SDO answer out of place"


class CanopenDriver(Driver):
    """A CiA 402 drive behind ``setup`` on ``port`` (a CAN port), with the cyclic PDOs of ``setup.layout()``."""

    def __init__(self, port: FramePort, setup: CanopenSetup, layout: Layout | None = None) -> None:
        from .sdo_answers import MatchingRemoteNode

        super().__init__(port, layout if layout is not None else setup.layout())
        self.setup = setup
        self.profile = setup.device_profile
        self.od = load_od(setup.eds, setup.node_id)
        self.network = _port_network(port)
        self.node = MatchingRemoteNode(setup.node_id, self.od)
        self.node.sdo.RESPONSE_TIMEOUT = setup.state_timeout_s
        self.network.add_node(self.node)
        self.network.subscribe(0x700 + setup.node_id, self._on_heartbeat)
        self.shutdown_account = ""
        self._lock = threading.Lock()
        self._last_heartbeat: float | None = None  # time.monotonic() when the latest heartbeat was taken in
        self._nmt_state: int | None = None
        self._status: int | None = None  # the latest statusword (TPDO or SDO)
        self._left: str | None = None  # why the drive left operation enabled during the sweep
        self._cyclic = False
        self._pump: threading.Thread | None = None
        self._pumping = threading.Event()
        self._pump_error: BaseException | None = None
        self._sync_ticks = [0] * _SYNC_MEMORY  # the host tick of each SYNC sent, by SYNC number modulo the memory
        self._syncs_sent = 0
        self._first_counter: int | None = None
        self._matcher: SyncMatcher[FeedbackSample] = SyncMatcher(_SYNC_MEMORY, same=_same_values)
        self._answer_times: queue.Queue[float] | None = None  # receive times of TPDOs while their answer is timed
        self._check_wanted = False  # a gap was dated by rhythm (or a check left undecided): leave a SYNC out
        self._gaps_checked = 0  # the matcher's by_rhythm + checks_undecided when last looked at
        self._steps: deque[float] = deque(maxlen=CHECK_MEMORY)  # the latest setpoint steps (setpoint units)
        self._last_setpoint = 0.0
        self._taken: list[FeedbackSample] = []  # samples dated while a check was being decided, for ``receive``
        self._check_window = 0.0  # s, the time from a SYNC to the next a check makes (0: two SYNC periods)
        self._last_sync = 0.0  # time.perf_counter() when the latest SYNC was sent
        self.protection = ""
        """What the start did so that the drive stops itself if the host dies, or why it could not (empty before)."""
        self._unprotected = ""  # why the drive cannot protect itself (said again in shutdown_account)
        self._restore: list[tuple[int, int, int, str]] = []  # (index, subindex, old value, what) to write back
        self._beat_started = False
        self._beat_stop = threading.Event()
        self._beat_thread: threading.Thread | None = None

    # ----------------------------------------------------------------------------------------------------------
    # frames in
    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if data:
            with self._lock:
                self._last_heartbeat = time.monotonic()
                self._nmt_state = data[0] & 0x7F

    def _dispatch(self, frame: Frame) -> list[FeedbackSample]:
        """Take one received frame: the TPDO becomes samples (in the cyclic phase); every other frame goes to
        canopen (SDO answers, EMCY, heartbeat)."""
        if frame.is_error:
            return []
        if frame.id == self.setup.tpdo_cob_id and not frame.extended:
            if self._answer_times is not None:
                self._answer_times.put(frame.timestamp)
            if len(frame.data) >= 2:
                word = int.from_bytes(frame.data[:2], "little")
                self._status = word
                state = self.profile.decode(word)
                if self._cyclic and state is not self.profile.running and self._left is None:
                    self._left = f"statusword 0x{word:04X} ({state or 'undefined'})"
            return self._dated(self.feed([frame])) if self._cyclic else []
        self.network.notify(frame.id, bytearray(frame.data), frame.timestamp)
        return []

    def _pump_loop(self) -> None:
        try:
            while self._pumping.is_set():
                for frame in self.port.recv(0.01):
                    self._dispatch(frame)
        except BaseException as exc:  # noqa: BLE001 - reported by the SDO call waiting on it
            self._pump_error = exc

    @contextmanager
    def _pumped(self) -> Iterator[None]:
        """Frames received in a thread of their own while SDO transfers wait for their answers."""
        self._pump_error = None
        self._pumping.set()
        self._pump = threading.Thread(target=self._pump_loop, name="canopen-rx", daemon=True)
        self._pump.start()
        try:
            yield
        finally:
            self._pumping.clear()
            self._pump.join(timeout=2.0)
            self._pump = None

    # ----------------------------------------------------------------------------------------------------------
    # SDO and NMT
    def _where(self) -> str:
        return f"CANopen node {self.setup.node_id}"

    def _variable(self, index: int, subindex: int) -> Any:
        """The object dictionary entry of ``index``:``subindex``."""
        obj: Any = self.od[index]
        return obj[subindex] if not hasattr(obj, "data_type") else obj

    def _sdo_write(self, index: int, subindex: int, value: int | float, what: str) -> None:
        from canopen.sdo import SdoAbortedError, SdoCommunicationError

        try:
            self.node.sdo.download(index, subindex, self._variable(index, subindex).encode_raw(value))
        except SdoAbortedError as exc:
            raise DriveFaultError(f"{self._where()}: writing {what} (0x{index:04X}:{subindex:02X}) = {value!r} "
                                  f"was refused: {exc}") from None
        except SdoCommunicationError as exc:
            raise DriveFaultError(f"{self._where()}: {_sdo_failure(exc)} writing {what} (0x{index:04X}:"
                                  f"{subindex:02X}): {exc}{self._pump_note()}") from None

    def _sdo_read(self, index: int, subindex: int, what: str) -> int | float:
        from canopen.sdo import SdoAbortedError, SdoCommunicationError

        try:
            value = self._variable(index, subindex).decode_raw(self.node.sdo.upload(index, subindex))
        except SdoAbortedError as exc:
            raise DriveFaultError(f"{self._where()}: reading {what} (0x{index:04X}:{subindex:02X}) was refused: "
                                  f"{exc}") from None
        except SdoCommunicationError as exc:
            raise DriveFaultError(f"{self._where()}: {_sdo_failure(exc)} reading {what} (0x{index:04X}:"
                                  f"{subindex:02X}): {exc}{self._pump_note()}") from None
        if not isinstance(value, (int, float)):
            raise DriveFaultError(f"{self._where()}: {what} (0x{index:04X}) is not a number")
        return value

    def _pump_note(self) -> str:
        return f" (receiving failed: {self._pump_error})" if self._pump_error is not None else ""

    def _nmt(self, code: int) -> None:
        self.network.send_message(0, bytes([code, self.setup.node_id]))

    def _read_status(self) -> int:
        word = int(self._sdo_read(STATUSWORD, 0, "statusword"))
        self._status = word
        return word

    def _command(self, step: Step, timeout: float) -> tuple[int, StrEnum | None]:
        """Write the control word of ``step`` and wait up to ``timeout`` s for one of its targets; the last status
        word and its state."""
        self._sdo_write(CONTROLWORD_OBJECT, 0, step.controlword, "controlword")
        deadline = time.monotonic() + timeout
        while True:
            word = self._read_status()
            state = self.profile.decode(word)
            if state in step.targets or time.monotonic() >= deadline:
                return word, state
            time.sleep(0.002)

    def _wait_heartbeat(self, timeout: float, state: int | None = None) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                seen, current = self._last_heartbeat, self._nmt_state
            if seen is not None and (state is None or current == state):
                return True
            time.sleep(0.005)
        return False

    def _write_confirmed(self, index: int, value: int, what: str, timeout: float, shown: int | None = None) -> None:
        """Write ``value`` to ``index`` and wait up to ``timeout`` s until ``shown`` (default: ``index`` itself) reads
        it back; DriveFaultError saying what it read."""
        self._sdo_write(index, 0, value, what)
        shown = index if shown is None else shown
        deadline = time.monotonic() + timeout
        while (read := self._sdo_read(shown, 0, what)) != value:
            if time.monotonic() >= deadline:
                raise DriveFaultError(f"{self._where()} does not take {what} ({value}): 0x{shown:04X} reads {read}")
            time.sleep(0.002)

    def _check_assumed(self) -> None:
        """Read the device parameters the scales were derived from (``CanopenSetup.assumed``); DriveFaultError for
        one the device has otherwise than its EDS."""
        for index, subindex, value, what in self.setup.assumed:
            read = self._sdo_read(index, subindex, what)
            if read != value:
                raise DriveFaultError(f"{self._where()}: {what} 0x{index:04X}:{subindex:02X} reads {read} on the "
                                      f"device, the scales assumed {value} (the EDS's default): give "
                                      "canopen.setpoint_scale and canopen.actual_scale, or the device's own DCF")

    # ----------------------------------------------------------------------------------------------------------
    # the life cycle
    def enable(self) -> None:
        """Configure the drive and bring it to "operation enabled" (the module docstring lists the steps);
        DriveFaultError naming the step and what the drive reported when it does not get there."""
        s = self.setup
        steps: list[str] = []
        with self._pumped():
            self._nmt(0x80)
            steps.append("NMT pre-operational")
            if s.heartbeat_ms:
                self._sdo_write(HEARTBEAT_PRODUCER, 0, s.heartbeat_ms, "producer heartbeat time")
            wait = max(s.heartbeat_timeout_s, 3 * s.heartbeat_ms / 1000)
            if not self._wait_heartbeat(wait):
                raise DriveFaultError(f"{self._where()}: no heartbeat (COB-ID 0x{0x700 + s.node_id:X}) within "
                                      f"{wait:g} s")
            word = self._read_status()
            p = self.profile
            if p.local_bit and word & p.local_bit:
                raise DriveFaultError(f"{self._where()} takes its control word locally (statusword 0x{word:04X}, "
                                      "bit 4): switch it to bus control (object 0x604F = 0 on CiA 408 devices)")
            if p.decode(word) in p.faults:
                if not s.fault_reset:
                    raise DriveFaultError(f"{self._where()} is in fault (statusword 0x{word:04X}, "
                                          f"{p.decode(word)}); clear the cause, or set canopen.fault_reset = true "
                                          "to reset it")
                self._sdo_write(CONTROLWORD_OBJECT, 0, 0, "controlword")
                word, state = self._command(p.reset, s.state_timeout_s)
                if state not in p.reset.targets:
                    raise DriveFaultError(f"{self._where()}: fault reset did not clear the fault (statusword "
                                          f"0x{word:04X}, {state or 'undefined'})")
                steps.append("fault reset")
            self._check_assumed()
            self._protect()
            steps.append(self.protection)
            self._map_pdos()
            steps.append(f"RPDO{s.rpdo} {s.setpoint}, TPDO{s.tpdo} statusword"
                         + "".join(f", {ref}" for _, ref, _ in s.actual) + ", synchronous")
            if p.device_mode is not None:
                index, value, what = p.device_mode
                self._write_confirmed(index, value, what, s.state_timeout_s)
                steps.append(f"{what} 0x{index:04X} = {value}")
            mode = p.modes[s.mode]
            self._write_confirmed(p.mode_object, mode, f"mode {s.mode}", s.state_timeout_s, p.mode_display)
            steps.append(f"mode {s.mode} ({mode})")
            self._sdo_write(s.setpoint.index, s.setpoint.subindex, 0, s.setpoint.name)
            if s.operating_point is not None:
                target, held = s.operating_point
                point = self._sdo_read(held.index, held.subindex, held.name) if held is not None else 0
                self._sdo_write(target.index, target.subindex, point, target.name)
                steps.append(f"operating point {target} = {point}" + (f" ({held.name})" if held is not None else ""))
            self._nmt(0x01)
            if not self._wait_heartbeat(wait, NMT_OPERATIONAL):
                raise DriveFaultError(f"{self._where()}: did not report NMT operational within {wait:g} s")
            steps.append("NMT operational")
            if s.times_answers:
                steps.append(self._time_answers())
                steps.append(self._size_checks())
            for step in p.enable:
                word, state = self._command(step, s.state_timeout_s)
                if state is not step.targets[0]:
                    raise DriveFaultError(f"{self._where()} did not reach '{step.targets[0]}' within "
                                          f"{s.state_timeout_s:g} s of controlword 0x{step.controlword:04X} "
                                          f"({step.name}): statusword 0x{word:04X} ({state or 'undefined'})"
                                          f"{p.stuck(step, state)}")
                steps.append(step.name)
        self.start_account = ", ".join(steps)
        self._left = None
        self._first_counter = None
        self._syncs_sent = 0
        self._matcher = SyncMatcher(_SYNC_MEMORY, same=_same_values)
        self._check_wanted = False
        self._gaps_checked = 0
        self._cyclic = True

    def _time_answers(self) -> str:
        """``timebase = "sync"`` on the realtime clock: how long the drive's TPDO takes to answer a SYNC, as the host
        sees it (its time before sending the SYNC to the receive time of the TPDO), from ``ANSWER_PROBES`` SYNCs sent
        one at a time before the drive is enabled. Dating by SYNC takes a TPDO to come, as a rule, before the next
        SYNC: DriveFaultError when more than one answer in ten takes longer than ``ANSWER_LIMIT`` of the time
        between SYNCs, or when a TPDO is stamped before its SYNC (the interface stamps frames on a clock of its
        own). Returns what was measured, for the start's account."""
        period = self.setup.sync_period_s
        answers: queue.Queue[float] = queue.Queue()
        times = []
        self._answer_times = answers
        wait = max(0.05, 20 * period)
        try:
            for _ in range(ANSWER_PROBES):
                sent = time.time()  # as send_setpoint notes it, before the send
                self.port.send(Frame(SYNC_COB_ID, b""))
                try:
                    times.append(answers.get(timeout=wait) - sent)
                except queue.Empty:  # an answer later still is not taken for the next SYNC's
                    time.sleep(wait)
                else:
                    time.sleep(period)  # a second answer to the same SYNC would come now, and is not timed
                while not answers.empty():
                    answers.get_nowait()
        finally:
            self._answer_times = None
        rate = f"with {period * 1e3:.3g} ms between SYNCs (bench.rate_hz = {1 / period:g})"
        if not times:
            log.warning("%s: its TPDO answered none of %d SYNCs sent before enabling: the time it takes to answer "
                        "is not known", self._where(), ANSWER_PROBES)
            return f"TPDO answer time not measured (no answer to {ANSWER_PROBES} SYNCs before enabling)"
        times.sort()
        median, most, longest = times[len(times) // 2], times[math.ceil(ANSWER_QUANTILE * len(times)) - 1], times[-1]
        measured = (f"TPDO answers its SYNC in {median * 1e3:.3g} ms (median of {len(times)}; "
                    f"{ANSWER_QUANTILE:.0%} within {most * 1e3:.3g} ms, longest {longest * 1e3:.3g} ms) {rate}")
        if times[0] < 0:
            raise DriveFaultError(f"{self._where()}: a TPDO is stamped {-times[0]:.3g} s before the SYNC it answers: "
                                  f"the interface stamps received frames on a clock other than the host's, and "
                                  f'bench.timebase = "sync" needs the host\'s; date by a sample counter the drive '
                                  f'sends (timebase = "counter")')
        if most > ANSWER_LIMIT * period:
            slower = int(ANSWER_LIMIT / most)
            raise DriveFaultError(f"{self._where()}: {measured}: with bench.timebase = \"sync\" its samples could be "
                                  f"dated by the next SYNC; lower bench.rate_hz to {slower} Hz or less, or date by "
                                  f'a sample counter the drive sends (timebase = "counter")')
        return measured

    def _size_checks(self) -> str:
        """How a check of the answer time after a gap will delay its SYNC (``_check_window``): left out (two SYNC
        periods between SYNCs), or sent late where the drive watches its SYNC by a communication cycle period
        (0x1006) that two periods would exceed (``CHECK_WATCHED``); for the start's account."""
        period = self.setup.sync_period_s
        watched = 0.0
        if self._has_variable(SYNC_PERIOD, 0):
            try:
                watched = self._sdo_read(SYNC_PERIOD, 0, "communication cycle period") * 1e-6
            except DriveFaultError as exc:  # the EDS has it, the device does not answer for it: taken as unset
                log.warning("%s", exc)
        if not watched or CHECK_WATCHED * watched >= 2 * period:
            self._check_window = 0.0
            return "answer checks after a gap: one SYNC left out"
        self._check_window = max(CHECK_WATCHED * watched, period)
        return (f"answer checks after a gap: one SYNC sent {(self._check_window - period) * 1e3:.3g} ms late "
                f"(communication cycle period 0x{SYNC_PERIOD:04X} = {watched * 1e6:.0f} us)")

    # ----------------------------------------------------------------------------------------------------------
    # the lost-host protection
    def _protect(self) -> None:
        """Start the host's heartbeat, then (where the EDS has them) write the drive's abort connection option code
        0x6007 and heartbeat consumer time 0x1016, each old value read first and kept for ``_restore_protection``.
        Sets ``protection``; a drive that cannot watch the host is logged as such. DriveFaultError when the drive
        refuses a write or does not answer (the exit sequence then writes back what was changed)."""
        s = self.setup
        if not s.host_heartbeat_ms:
            self._unprotected = ("the drive CANNOT protect itself from a lost host: canopen.host_heartbeat_ms = 0, "
                                 "the host sends no heartbeat for it to watch")
            self.protection = self._unprotected
            log.warning("%s: %s", self._where(), self._unprotected)
            return
        how = self._start_host_heartbeat()
        beat = f"host heartbeat node {s.host_node_id} (COB-ID 0x{s.host_heartbeat_cob_id:X}) every " \
               f"{s.host_heartbeat_ms} ms ({how})"
        sub = self._consumer_subindex()
        if sub is None:
            lacks = "heartbeat consumer time 0x1016" + (
                "" if self._has_variable(ABORT_CONNECTION, 0) else " nor abort connection option code 0x6007")
            self._unprotected = (f"the drive CANNOT protect itself from a lost host: its EDS has no {lacks}, so a "
                                 "host that dies leaves it as it was (configure the drive's own SYNC or RPDO timeout)")
            self.protection = f"{beat}; {self._unprotected}"
            log.warning("%s: %s", self._where(), self._unprotected)
            return
        parts = [beat]
        option = s.abort_connection
        name = next((k for k, v in ABORT_CONNECTION_OPTIONS.items() if v == option), str(option))
        if not self.profile.abort_connection:
            parts.append(f"a lost host is the {self.profile.name} {self.profile.device}'s own fault reaction")
        elif self._has_variable(ABORT_CONNECTION, 0):
            old = int(self._sdo_read(ABORT_CONNECTION, 0, "abort connection option code"))
            self._restore.append((ABORT_CONNECTION, 0, old, "abort connection option code"))
            self._sdo_write(ABORT_CONNECTION, 0, option, "abort connection option code")
            parts.append(f"abort connection option code 0x6007 = {option} ({name}, was {old})")
        else:
            parts.append("no abort connection option code 0x6007 in the EDS: the drive's own reaction to a lost "
                         "host applies")
            log.warning("%s: its EDS has no abort connection option code 0x6007: what it does when the host's "
                        "heartbeat stops is its own default", self._where())
        old = int(self._sdo_read(HEARTBEAT_CONSUMER, sub, "consumer heartbeat time"))
        back = old
        if (old >> 16) & 0xFF == s.host_node_id and old & 0xFFFF:
            # found watching the host already: left so by a session that could not write it back (its host died);
            # written back as off, or every later session would leave the drive watching a host that is gone
            back = 0
            log.warning("%s: its consumer heartbeat time 0x1016:%02X already watched node %d (0x%08X), left by a "
                        "session that ended without writing it back: it is switched off at the end of this one",
                        self._where(), sub, s.host_node_id, old)
        self._restore.append((HEARTBEAT_CONSUMER, sub, back, "consumer heartbeat time"))
        self._sdo_write(HEARTBEAT_CONSUMER, sub, s.consumer_value, "consumer heartbeat time")
        # a consumer watches from the first heartbeat after it was set (CiA 301): one now, so that the drive watches
        # the host before it is enabled, not a period later
        self.port.send(Frame(s.host_heartbeat_cob_id, bytes([HOST_HEARTBEAT_STATE])))
        parts.append(f"consumer heartbeat time 0x1016:{sub:02X} = 0x{s.consumer_value:08X} (node "
                     f"{s.host_node_id}, {s.drive_heartbeat_timeout_ms} ms; was 0x{old:08X})")
        self.protection = "; ".join(parts)

    def _has_variable(self, index: int, subindex: int) -> bool:
        """True when the EDS has ``index``:``subindex`` as a number."""
        from canopen.objectdictionary import ODArray, ODRecord, ODVariable

        if index not in self.od:
            return False
        obj: Any = self.od[index]
        if isinstance(obj, (ODArray, ODRecord)):
            obj = obj.subindices.get(subindex)
        elif subindex != 0:
            return False
        return isinstance(obj, ODVariable) and obj.data_type in _SIGNAL_TYPES

    def _consumer_subindex(self) -> int | None:
        """The sub-entry of the drive's 0x1016 to watch the host with: one already watching the host's node id,
        else the first unused one (node id or time 0), else 1 (another node's watch, given back on exit); None
        when the EDS has no 0x1016 sub-entry."""
        from canopen.objectdictionary import ODArray, ODRecord

        obj = self.od.get(HEARTBEAT_CONSUMER, None)
        if not isinstance(obj, (ODArray, ODRecord)):
            return None
        subs = sorted(i for i in obj.subindices if 1 <= i <= 127 and self._has_variable(HEARTBEAT_CONSUMER, i))
        if not subs:
            return None
        free = None
        for i in subs:
            value = int(self._sdo_read(HEARTBEAT_CONSUMER, i, "consumer heartbeat time"))
            if (value >> 16) & 0xFF == self.setup.host_node_id:
                return i
            if free is None and (not value & 0xFFFF or not (value >> 16) & 0xFF):
                free = i
        return free if free is not None else subs[0]

    def _start_host_heartbeat(self) -> str:
        """The host's heartbeat, from now until ``close()``: python-can's periodic send where the port has it (its
        task ends with the process), else a thread of this driver (a bus log must see every frame). How, in words."""
        s = self.setup
        if self._beat_started:
            return "already running"
        frame = Frame(s.host_heartbeat_cob_id, bytes([HOST_HEARTBEAT_STATE]))
        period = s.host_heartbeat_ms / 1000
        self._beat_started = True
        try:
            if self.port.send_periodic(frame, period):
                return "python-can periodic send"
        except DriverOperationError:
            pass
        self._beat_stop.clear()
        self._beat_thread = threading.Thread(target=self._beat_loop, args=(frame, period), name="canopen-heartbeat",
                                             daemon=True)
        self._beat_thread.start()
        return "sent by a thread of the host"

    def _beat_loop(self, frame: Frame, period: float) -> None:
        due = time.monotonic()
        while not self._beat_stop.wait(max(0.0, due - time.monotonic())):
            try:
                self.port.send(frame)
            except DriverOperationError:
                return  # the port closed: the session is over
            due += period
            if due < time.monotonic():  # fell behind (a stall): the next one a period from now
                due = time.monotonic() + period

    def _restore_protection(self) -> list[str]:
        """Write back the drive's 0x1016 and 0x6007 as they were before ``enable()`` (each tried once, even when an
        earlier one failed); what was done, in words."""
        restore, self._restore = self._restore, []
        done = []
        for index, subindex, old, what in reversed(restore):
            shown = f"0x{old:08X}" if index == HEARTBEAT_CONSUMER else str(old)
            where = f"0x{index:04X}:{subindex:02X}" if index == HEARTBEAT_CONSUMER else f"0x{index:04X}"
            try:
                self._sdo_write(index, subindex, old, what)
                done.append(f"{what} {where} = {shown} restored")
            except DriverOperationError as exc:
                done.append(f"{what} {where} NOT restored to {shown}: {exc}")
        return done

    def _leave_protection_armed(self) -> list[str]:
        """The drive was not seen in a safe state: its 0x1016 and 0x6007 stay as ``enable()`` wrote them, so that
        it stops itself once the host's heartbeat ends (when the session closes); what is left, in words."""
        restore, self._restore = self._restore, []
        return [f"{what} 0x{index:04X}" + (f":{subindex:02X}" if index == HEARTBEAT_CONSUMER else "")
                + " left armed (the drive was not seen disabled: it stops itself once the host's heartbeat ends)"
                for index, subindex, _, what in reversed(restore)]

    def _map_pdos(self) -> None:
        """Write the RPDO and TPDO mapping of ``setup`` (synchronous transmission) with SDO, then read each mapping
        back: a drive that acknowledges the writes but keeps a mapping of its own (a fixed one) would have another
        object measured. DriveFaultError naming the PDO and its objects otherwise."""
        from canopen.sdo import SdoAbortedError, SdoCommunicationError

        s = self.setup
        for name, pdo, cob_id, objects in (
                (f"RPDO{s.rpdo}", self.node.rpdo[s.rpdo], s.rpdo_cob_id, [(s.setpoint.index, s.setpoint.subindex,
                                                                            s.setpoint.bits)]),
                (f"TPDO{s.tpdo}", self.node.tpdo[s.tpdo], s.tpdo_cob_id,
                 [(STATUSWORD, 0, 16), *((ref.index, ref.subindex, ref.bits) for _, ref, _ in s.actual)])):
            mapping = pdo.map_array.od.index
            where = f"{name} (communication 0x{pdo.com_record.od.index:04X}, mapping 0x{mapping:04X})"
            try:
                pdo.clear()
                for index, subindex, bits in objects:
                    pdo.add_variable(index, subindex, bits)
                pdo.cob_id, pdo.trans_type, pdo.enabled = cob_id, 1, True
                pdo.save()
                read = self._mapping_of(mapping)
            except (SdoAbortedError, SdoCommunicationError) as exc:
                raise DriveFaultError(f"{self._where()}: mapping {where} to {_mapping_text(objects)} failed: {exc}"
                                      f"{self._pump_note()}") from None
            if read != objects:
                raise DriveFaultError(f"{self._where()}: the drive did not take the {where} mapping: it reads "
                                      f"{_mapping_text(read)}, {_mapping_text(objects)} was written (a fixed mapping "
                                      "of the drive's own: map the objects it has, or change it in the drive)")

    def _mapping_of(self, map_index: int) -> list[tuple[int, int, int]]:
        """The (index, subindex, bits) entries a PDO mapping object ``map_index`` (0x1600.., 0x1A00..) reads."""
        count = int.from_bytes(self.node.sdo.upload(map_index, 0)[:1], "little")
        entries = []
        for sub in range(1, count + 1):
            raw = int.from_bytes(self.node.sdo.upload(map_index, sub)[:4], "little")
            entries.append((raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF))
        return entries

    def send_setpoint(self, value: float, counter: int = 0, idle: bool = False) -> None:
        """The setpoint RPDO, then SYNC when the host produces it (the drive applies the setpoint on SYNC).
        ``counter``: the host's tick of this setpoint; a sample is dated by the SYNC it answers (below). ``idle``:
        the tick may be spent checking the answer time (``_checks_answer``)."""
        super().send_setpoint(value, counter)
        if self.setup.sync == "produce":
            if self._checks_answer(value, idle):
                if not self._check_window:
                    return  # the SYNC left out
                sleep_until(self._last_sync + self._check_window)  # the SYNC sent late
            sent = time.time()  # before the send: the clock python-can stamps received frames with
            self._last_sync = time.perf_counter()
            self.port.send(Frame(SYNC_COB_ID, b""))
            self._sync_ticks[self._syncs_sent % _SYNC_MEMORY] = counter
            self._syncs_sent += 1
            if self._by_sync:
                self._matcher.sent(counter, sent)
            self._update_health()

    def _checks_answer(self, value: float, idle: bool) -> bool:
        """Whether this tick's SYNC is left out, or sent late, to check the drive's answer time
        (``SyncMatcher.skip``, ``_size_checks``): wanted after a gap dated by rhythm on the realtime clock, made once
        the latest SYNC has its answer, on an ``idle`` tick where the setpoint hardly moves (``CHECK_STEP``)."""
        if not self.setup.times_answers:
            return False
        step = abs(value - self._last_setpoint)  # the drive holds the last setpoint one tick longer without a SYNC
        self._last_setpoint = value
        self._steps.append(step)
        if not (self._check_wanted and idle) or step > CHECK_STEP * max(self._steps):
            return False
        for frame in self.port.recv(0.0):  # the answer to the latest SYNC may be in: dated now, returned next
            self._taken.extend(self._dispatch(frame))
        if not self._matcher.settled:
            return False
        self._check_wanted = False
        self._matcher.skip()
        return True

    @property
    def dating_unchecked(self) -> bool:
        """A gap dated by rhythm (or an undecided check) waits for its check, or a check is under way."""
        return self._check_wanted or self._matcher.checking

    @property
    def _by_sync(self) -> bool:
        """Whether samples are dated by the order and times of the frames (``timebase`` "sync")."""
        return self.setup.sync == "produce" and self.setup.timebase == "sync"

    @property
    def counts_host_ticks(self) -> bool:  # type: ignore[override]
        """With host-produced SYNC, samples are dated by the host tick of the SYNC they answer (``_dated``)."""
        return self.setup.sync == "produce"

    def _dated(self, samples: list[FeedbackSample]) -> list[FeedbackSample]:
        """With host-produced SYNC, each sample's counter becomes the host tick that follows the SYNC it answers.
        By the order and receive times of the frames (``timebase`` "sync", ``SyncMatcher``): samples that cannot
        be told which SYNC they answer are dropped (``BusHealth.undated``), SYNCs left unanswered are lost samples.
        Else by the drive's counter: it advances once a SYNC, so its step from the first sample counts SYNCs. Ticks
        the host skipped (a stalled pacing loop) then do not shift the time base, as the drive's cycle is the SYNC."""
        if self.setup.sync != "produce":
            return samples
        if self._by_sync:
            m = self._matcher
            dated = [dataclasses.replace(s, counter=tick + 1) for sample in samples
                     for tick, s in m.received(sample.receive_time, sample)]
            self.health.undated = m.ambiguous + m.unmatched
            self.health.duplicates = m.repeats
            self.health.lost_samples = m.lost
            self.health.dated_by_rhythm = m.by_rhythm
            self.health.answer_checks = m.checks
            gaps = m.by_rhythm + m.checks_undecided
            if gaps != self._gaps_checked and self.setup.times_answers:
                self._gaps_checked = gaps
                self._check_wanted = True
            return dated
        out = []
        for sample in samples:
            if sample.counter is None:
                out.append(sample)
                continue
            if self._first_counter is None:
                self._first_counter = sample.counter
            n = sample.counter - self._first_counter
            if not 0 <= n < self._syncs_sent or self._syncs_sent - n > _SYNC_MEMORY:
                self._first_counter = sample.counter - (self._syncs_sent - 1)  # lost track: the latest SYNC
                n = self._syncs_sent - 1
            tick = self._sync_ticks[n % _SYNC_MEMORY]
            out.append(dataclasses.replace(sample, counter=tick + 1))
        return out

    def receive(self, timeout: float) -> list[FeedbackSample]:
        """TPDO samples within ``timeout`` s (as ``Driver.receive``); DriveFaultError when the drive reported a fault
        (EMCY, a statusword out of "operation enabled"), its heartbeat is missing or it left NMT operational."""
        if not isinstance(timeout, (int, float)) or not timeout >= 0:
            raise ValueError(f"receive timeout must be a number >= 0 s, got {timeout!r}")
        deadline = time.monotonic() + timeout
        samples, self._taken = self._taken, []
        try:
            while True:
                for frame in self.port.recv(max(0.0, deadline - time.monotonic())):
                    samples.extend(self._dispatch(frame))
                self._check()
                if samples or time.monotonic() >= deadline:
                    return samples
        finally:
            self._update_health()

    def _check(self) -> None:
        """Raise DriveFaultError for a fault the drive has shown."""
        active = list(self.node.emcy.active)
        if active:
            e = active[-1]
            raise DriveFaultError(f"{self._where()}: EMCY 0x{e.code:04X} ({e.get_desc() or 'no description'}), "
                                  f"error register 0x{e.register:02X}")
        if self._left is not None:
            raise DriveFaultError(f"{self._where()} left {self.profile.running}: {self._left}")
        if self._matcher.extra:
            raise DriveFaultError(self._extra_tpdo())
        limit = self.setup.heartbeat_timeout_s
        with self._lock:
            seen, state = self._last_heartbeat, self._nmt_state
        if seen is not None and time.monotonic() - seen > limit:
            while frames := self.port.recv(0.0):  # heartbeats waiting in the queue count
                for frame in frames:
                    self._dispatch(frame)
            with self._lock:
                seen, state = self._last_heartbeat, self._nmt_state
            if seen is not None and time.monotonic() - seen > limit:
                raise DriveFaultError(f"{self._where()}: no heartbeat for {time.monotonic() - seen:.3g} s "
                                      f"(canopen.heartbeat_timeout_s = {limit:g} s)")
        if state is not None and state != NMT_OPERATIONAL:
            raise DriveFaultError(f"{self._where()} reports NMT state {NMT_STATES.get(state, state)} in its heartbeat")

    def _extra_tpdo(self) -> str:
        """The line for a TPDO that came when every SYNC before it had its answer (``SyncMatcher.extra``)."""
        m = self._matcher
        since = (f"the samples dated by SYNC since tick {m.rhythm_tick} (a gap dated by rhythm) may be a SYNC off"
                 if m.rhythm_tick is not None else "its samples cannot be dated by SYNC")
        period = self.setup.sync_period_s
        late = f"later than a SYNC period ({period * 1e3:.3g} ms)" if period else "after the next SYNC"
        slower = ", or lower bench.rate_hz if its answers are often that slow" if period else ""
        return (f"{self._where()}: a TPDO came when every SYNC sent before it had its answer: the drive answers "
                f"{late} at times, or sends TPDOs unasked; {since}; date by a sample counter the drive sends "
                f'(timebase = "counter"){slower}')

    def disable(self) -> bool:
        """Quick stop, disable voltage, NMT pre-operational (each tried even when an earlier one failed); True when
        the drive was then seen "switch on disabled" (or in fault, its power stage off). ``shutdown_account`` says
        what was done and seen."""
        self._cyclic = False
        steps: list[str] = []
        seen: StrEnum | None = None
        if self.port.closed:
            self.shutdown_account = "the bus was closed: no quick stop, disable voltage or NMT command sent" + (
                "; the drive's 0x1016 and 0x6007 NOT restored" if self._restore else "")
            self._restore = []
            return False
        p = self.profile
        with self._pumped():
            for step in p.leave:
                try:
                    word, seen = self._command(step, self.setup.state_timeout_s)
                    steps.append(f"{step.name} (controlword 0x{step.controlword:04X}): statusword 0x{word:04X} "
                                 f"({seen or 'undefined'})")
                except DriverOperationError as exc:
                    seen = None
                    steps.append(f"{step.name} (controlword 0x{step.controlword:04X}) not confirmed: {exc}")
            # before the NMT command, the last word to the drive; a drive not seen safe keeps watching the host
            restored = self._restore_protection() if seen in p.safe else self._leave_protection_armed()
            try:
                self._nmt(0x80)
                steps.append("NMT pre-operational sent")
            except DriverOperationError as exc:
                steps.append(f"NMT pre-operational not sent: {exc}")
            if restored:
                steps.append("lost-host settings: " + ", ".join(restored))
        if self._unprotected:
            steps.append(self._unprotected)
        self.shutdown_account = "; ".join(steps)
        return seen in p.safe

    def close(self) -> None:
        """Write back the drive's 0x1016 and 0x6007 if no ``disable()`` did and the drive reads safe (else they stay
        armed, so that it stops itself once the host's heartbeat ends), stop the host's heartbeat, close the
        port."""
        try:
            if self._restore and not self.port.closed:
                with self._pumped():
                    try:
                        safe = self.profile.decode(self._read_status()) in self.profile.safe
                    except DriverOperationError:
                        safe = False
                    steps = self._restore_protection() if safe else self._leave_protection_armed()
                restored = "lost-host settings: " + ", ".join(steps)
                self.shutdown_account = "; ".join(part for part in (self.shutdown_account, restored) if part)
        finally:
            self._restore = []
            self._pumping.clear()
            self._beat_stop.set()
            if self._beat_thread is not None:
                self._beat_thread.join(timeout=2.0)
                self._beat_thread = None
            super().close()
