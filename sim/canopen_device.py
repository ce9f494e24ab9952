"""Simulated CANopen devices: a CiA 402 servo drive and a CiA 408 fluid-power device (a proportional valve or a
hydraulic drive), each a canopen ``LocalNode`` (the shipped EDS of its profile, or any with the same objects) around
a ``SimulatedController``'s plant. The CiA 408 device differs from the drive only where the profiles do: its state
machine (``drivers.cia408``: DISABLED, HOLD, ACTIVE and the fault states, a hardware enable input), its device mode
0x6042 and control mode 0x6043, and its reaction to a lost host (a fault: EMCY, FAULT_REACTION, FAULT_DISABLED).

What it honours, as a drive does:

- NMT: it boots pre-operational (boot-up message), exchanges PDOs only while operational, and produces its
  heartbeat at the producer time the host writes to 0x1017;
- the PDO mapping the host writes over SDO: on NMT start it reads its RPDO and TPDO mapping objects, applies the
  setpoint object of an RPDO received before each SYNC, and sends every enabled synchronous TPDO after it;
- SYNC: each SYNC holds the latest setpoint over one control period on the plant (``SimulatedController.advance``)
  and samples the actual values at its end, so a lockstep host gets the same zero-order-hold record as from the
  other simulated links;
- the power state machine (``drivers.cia402``): the plant gets a zero setpoint unless "operation enabled" (CiA 408:
  unless ACTIVE with device mode 1; in HOLD the hold set point, zero);
- a lost host: the heartbeat consumer times of 0x1016 (node id << 16 | time in ms) and the abort connection option
  code 0x6007 (where its EDS has them). A watched node's heartbeat, once seen, missing for longer than its consumer
  time is a heartbeat event: the drive says so, sends an EMCY (0x8130) and takes the 0x6007 reaction (1 fault,
  2 disable voltage, 3 quick stop, 0 none). ``check_heartbeat`` checks on the wall clock; ``ServingCanopen`` calls it
  from a thread of its own, as a drive's timer does, so a host that died (and sends no SYNC) is still noticed;
- faults (``CanopenFaults``): it refuses to enable, sends an EMCY and goes to fault, stops its heartbeat, or falls
  silent altogether, at a given controller time; at random, it misses a SYNC (the plant holds the setpoint it had
  over that period, no TPDO), drops a TPDO, or sends one late: after the next SYNC, just before that SYNC's own.
"""

from __future__ import annotations

import math
import queue
import random
import threading
import time
from collections.abc import Callable
from enum import StrEnum
from typing import TYPE_CHECKING, Any, cast

from bodebench.drivers import cia408
from bodebench.drivers.canopen_link import (
    ABORT_CONNECTION,
    CONTROLWORD_OBJECT,
    HEARTBEAT_CONSUMER,
    MODES_DISPLAY,
    MODES_OF_OPERATION,
    STATUSWORD,
    SYNC_COB_ID,
    SYNC_PERIOD,
    CanopenSetup,
    load_od,
)
from bodebench.drivers.cia402 import (
    ABORT_CONNECTION_OPTIONS,
    MODES,
    Command,
    State,
    command_of,
    next_state,
    statusword,
)
from bodebench.drivers.codec import COUNTER
from bodebench.drivers.device_profile import CIA402, CIA408, DeviceProfile
from bodebench.sim.controller import SimulatedController
from bodebench.sim.faults import CanopenFaults

if TYPE_CHECKING:
    import canopen

__all__ = ["ServingCanopen", "SimulatedCia402Drive", "SimulatedCia408Device", "serve_canopen"]

SAMPLE_COUNTER = 0x2000
"""The shipped EDS's sample counter (UNSIGNED16): control periods stepped."""
ERROR_CODE = 0x603F
DEVICE_ERROR_CODE = 0x604E
"""CiA 408 device error code."""
DEVICE_MODE = 0x6042
CONTROL_MODE = 0x6043
HEARTBEAT_ERROR = 0x8130
"""EMCY error code of a heartbeat event (CiA 301: life guard error or heartbeat error)."""
_ABORT_NAMES = {0: "no action", **{code: name for name, code in ABORT_CONNECTION_OPTIONS.items()}}


class SimulatedCia402Drive:
    """The drive's object dictionary, state machine and SYNC handling around ``controller`` (whose layout is
    ``setup.layout()``), on a canopen network given to ``attach``. Each change of state goes to ``on_event``.

    The heartbeat consumer: ``consumers`` (0x1016 sub-entry -> (node id, consumer time s)), ``abort_option`` (0x6007),
    ``heartbeats_consumed`` (heartbeats of watched nodes taken in), ``heartbeat_events`` (lost heartbeats acted
    on)."""

    def __init__(self, controller: SimulatedController, setup: CanopenSetup, faults: CanopenFaults | None = None,
                 on_event: Callable[[str], None] | None = None) -> None:
        self.controller = controller
        self.setup = setup
        self.faults = faults if faults is not None and faults.any else None
        self.on_event = on_event or (lambda text: None)
        self.state: StrEnum = self._initial_state()
        controller.enabled = False
        self.mode = 0
        self.error_code = 0
        self.syncs = 0
        self.silent = False
        self.transitions: list[tuple[StrEnum, StrEnum]] = []
        self._last_word = 0  # the latest controlword written
        self._heartbeat_stopped = False
        self._rpdos: list[Any] = []
        self._tpdos: list[Any] = []
        self._channel_of: dict[tuple[int, int], tuple[str, float]] = {
            (ref.index, ref.subindex): (name, scale) for name, ref, scale in setup.actual}
        self._setpoint_key = (setup.setpoint.index, setup.setpoint.subindex)
        self._setpoint_raw: float = 0
        self._lock = threading.Lock()
        self.node: canopen.LocalNode | None = None
        self.network: canopen.Network | None = None
        self.consumers: dict[int, tuple[int, float]] = {}
        self.abort_option = 0
        self.heartbeats_consumed = 0
        self.heartbeat_events = 0
        self._heard: dict[int, float] = {}  # watched node id -> time.monotonic() of its latest heartbeat, once seen
        self._subscribed: set[int] = set()  # node ids whose heartbeat COB-ID is subscribed to
        self._draws = random.Random(self.faults.seed if self.faults is not None else 0)
        self._late: list[tuple[int, bytes]] = []  # (COB-ID, data) of TPDOs held back to a later SYNC
        self._stalled_for = 0  # SYNCs the drive still holds its TPDOs back for (tpdo_stall)
        self._delayed: queue.Queue[tuple[float, int, bytes] | None] | None = None  # (due, COB-ID, data): tpdo_delay_s
        self._delayed_until = 0.0  # time.monotonic() the latest delayed TPDO is due at
        self.missed_syncs = 0
        self.dropped_tpdos = 0
        self.late_tpdos = 0
        self.stalls = 0
        self.repeated_tpdos = 0
        self.sync_period_us = self.faults.sync_period_us if self.faults is not None else 0
        """The communication cycle period the drive holds (0x1006, us; 0: none)."""

    # ----------------------------------------------------------------------------------------------------------
    def attach(self, network: canopen.Network) -> None:
        """Create the local node on ``network`` and boot it (boot-up message, then pre-operational)."""
        import canopen

        node = canopen.LocalNode(self.setup.node_id, load_od(self.setup.eds, self.setup.node_id))
        node.add_read_callback(self._on_read)
        node.add_write_callback(self._on_write)
        network.add_node(node)
        network.subscribe(0, self._on_nmt)  # after the node's own NMT handler
        network.subscribe(SYNC_COB_ID, self._on_sync)
        self.node, self.network = node, network
        od: Any = node.object_dictionary  # what the EDS holds before the host writes anything
        if ABORT_CONNECTION in od:
            self.abort_option = int(od[ABORT_CONNECTION].default or 0)
        if HEARTBEAT_CONSUMER in od:
            for sub, var in od[HEARTBEAT_CONSUMER].subindices.items():
                if sub >= 1 and var.default:
                    self._watch(sub, int(var.default))
        node.nmt.send_command(0x81)  # reset node: boot-up message
        node.nmt.send_command(0x80)  # pre-operational (the heartbeat starts here if 0x1017 is set)

    @property
    def nmt_state(self) -> str:
        """The node's NMT state."""
        assert self.node is not None
        return self.node.nmt.state

    # ----------------------------------------------------------------------------------------------------------
    # the profile: what a CiA 408 device does otherwise
    profile: DeviceProfile = CIA402
    error_code_object = ERROR_CODE

    def _initial_state(self) -> StrEnum:
        """The state after boot."""
        return State.SWITCH_ON_DISABLED

    def _statusword(self) -> int:
        return statusword(cast(State, self.state), warning=self.error_code != 0)

    def _controlword(self, word: int) -> None:
        """A controlword written (``self._last_word`` is the one before it)."""
        command = command_of(word, self._last_word)
        new = next_state(cast(State, self.state), command)
        if command is Command.FAULT_RESET and self.state is State.FAULT:
            self._clear_error()
        if new is State.OPERATION_ENABLED and self.faults is not None and self.faults.refuse_enable:
            self.on_event(f"refuses to enable operation (controlword 0x{word:04X})")
            return
        self._go(new, f"controlword 0x{word:04X}")

    def _write_mode(self, index: int, data: bytes) -> bool:
        """A write to a mode object: taken (True), refused (SdoAbortedError), or not a mode object (False)."""
        from canopen.sdo import SdoAbortedError

        if index != MODES_OF_OPERATION:
            return False
        mode = int.from_bytes(data, "little", signed=True)
        if mode not in MODES.values():
            raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
        self.mode = mode
        return True

    def _read_mode(self, index: int) -> int | None:
        return self.mode if index == MODES_DISPLAY else None

    def _fault(self, why: str) -> None:
        """Go to the fault state (an EMCY was sent)."""
        self._go(State.FAULT, why)

    def _left_operational(self, why: str) -> None:
        """NMT left operational: a running drive stops."""
        if self.state is State.OPERATION_ENABLED:
            self._go(State.SWITCH_ON_DISABLED, why)

    def _lost_host(self, why: str) -> None:
        """The reaction to a lost heartbeat: the abort connection option code 0x6007."""
        option = self.abort_option
        if option == ABORT_CONNECTION_OPTIONS["fault"]:
            if self.state not in (State.FAULT, State.SWITCH_ON_DISABLED, State.NOT_READY):
                self.error_code = HEARTBEAT_ERROR
                self._go(State.FAULT, why)
        elif option == ABORT_CONNECTION_OPTIONS["disable voltage"]:
            self._go(next_state(cast(State, self.state), Command.DISABLE_VOLTAGE), why)
        elif option == ABORT_CONNECTION_OPTIONS["quick stop"]:
            self._go(next_state(cast(State, self.state), Command.QUICK_STOP), why)

    def _lost_host_note(self) -> str:
        option = self.abort_option
        return f"abort connection option {option} ({_ABORT_NAMES.get(option, 'manufacturer-specific: no action')})"

    @property
    def running(self) -> bool:
        """Whether the bus set point acts on the plant."""
        return self.state is self.profile.running

    def _clear_error(self) -> None:
        self.error_code = 0
        assert self.node is not None
        self.node.emcy.reset()

    # ----------------------------------------------------------------------------------------------------------
    def _go(self, state: StrEnum, why: str) -> None:
        if state is self.state:
            return
        self.transitions.append((self.state, state))
        self.on_event(f"{state} ({why})")
        self.state = state
        enabled = self.running
        if not enabled and self.controller.setpoint != 0.0:
            self.on_event(f"setpoint zeroed (was {self.controller.setpoint:g})")
        self.controller.enabled = enabled
        if not enabled:
            self.controller.setpoint = 0.0

    # ----------------------------------------------------------------------------------------------------------
    # object dictionary
    def _on_read(self, index: int, subindex: int, od: Any) -> int | None:
        if index == STATUSWORD:
            return self._statusword()
        if self.faults is not None and self.faults.fixed_tpdo_mapping and 0x1A00 <= index <= 0x1A03:
            return int(od.default or 0)  # the writes were acknowledged, not taken
        mode = self._read_mode(index)
        if mode is not None:
            return mode
        if index == self.error_code_object:
            return self.error_code
        if index == SAMPLE_COUNTER:
            return self.controller.tick_count % (1 << 16)
        if index == SYNC_PERIOD:
            return self.sync_period_us
        return None

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        with self._lock:  # the heartbeat consumer's thread changes the state too
            self._write(index, subindex, od, data)

    def _write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        from canopen.sdo import SdoAbortedError

        if index == HEARTBEAT_CONSUMER and subindex >= 1:
            self._watch(subindex, int.from_bytes(data, "little"))
        elif index == ABORT_CONNECTION:
            option = int.from_bytes(data, "little", signed=True)
            if option not in _ABORT_NAMES:
                raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
            self.abort_option = option
        elif index == CONTROLWORD_OBJECT:
            word = int.from_bytes(data, "little")
            self._controlword(word)
            self._last_word = word
        elif self._write_mode(index, data):
            pass
        elif (index, subindex) == self._setpoint_key:
            self._setpoint_raw = od.decode_raw(data)
        elif index == SYNC_PERIOD:
            self.sync_period_us = int.from_bytes(data, "little")

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.silent or len(data) < 2 or data[1] not in (0, self.setup.node_id):
            return
        with self._lock:
            self._nmt_changed()

    def _nmt_changed(self) -> None:
        if self.nmt_state == "OPERATIONAL":
            self._read_pdos()
            self.on_event("NMT operational")
        else:
            self._rpdos, self._tpdos = [], []
            self._left_operational(f"left NMT operational: {self.nmt_state.lower()}")
            self.on_event(f"NMT {self.nmt_state.lower()}")

    # ----------------------------------------------------------------------------------------------------------
    # heartbeat consumer
    def _watch(self, subindex: int, value: int) -> None:
        """0x1016 sub ``subindex`` = ``value``: watch node ``value >> 16`` for ``value & 0xFFFF`` ms (either 0: that
        sub-entry watches nothing). SdoAbortedError for reserved bits, a node id out of range, or a node another
        sub-entry already watches (CiA 301)."""
        from canopen.sdo import SdoAbortedError

        node_id, ms = (value >> 16) & 0xFF, value & 0xFFFF
        if value >> 24 or node_id > 127:
            raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
        others = {n for sub, (n, _) in self.consumers.items() if sub != subindex}
        if node_id and ms and node_id in others:
            raise SdoAbortedError(0x06040043)  # general parameter incompatibility
        self.consumers.pop(subindex, None)
        if node_id and ms:
            self.consumers[subindex] = (node_id, ms / 1000)
            self._heard.pop(node_id, None)  # watched from its next heartbeat on
        watched = {n for n, _ in self.consumers.values()}
        for n in set(self._heard) - watched:
            del self._heard[n]
        if self.network is not None:
            for n in self._subscribed - watched:
                self.network.unsubscribe(0x700 + n, self._on_consumed)
            for n in watched - self._subscribed:
                self.network.subscribe(0x700 + n, self._on_consumed)
            self._subscribed = watched

    def _on_consumed(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.silent:
            return
        node_id = can_id - 0x700
        with self._lock:
            if not any(n == node_id for n, _ in self.consumers.values()):
                return
            if node_id not in self._heard:
                limit = min(t for n, t in self.consumers.values() if n == node_id)
                self.on_event(f"watching the heartbeat of node {node_id} (consumer time {limit:g} s; "
                              f"{self._lost_host_note()})")
            self._heard[node_id] = time.monotonic()
            self.heartbeats_consumed += 1

    @property
    def poll_s(self) -> float:
        """How often ``check_heartbeat`` should run: a twentieth of the shortest consumer time, at most 20 ms."""
        return min([0.02] + [t / 20 for _, t in self.consumers.values()])

    def check_heartbeat(self) -> bool:
        """The heartbeat consumer on the wall clock: a watched node heard once and silent for longer than its
        consumer time is a heartbeat event (said, EMCY 0x8130, the 0x6007 reaction); watched again from its next
        heartbeat. True when an event happened now."""
        if self.silent or not self._heard:
            return False
        now = time.monotonic()
        happened = False
        with self._lock:
            for node_id, limit in list(self.consumers.values()):
                seen = self._heard.get(node_id)
                if seen is None or now - seen <= limit:
                    continue
                del self._heard[node_id]
                self._heartbeat_lost(node_id, now - seen, limit)
                happened = True
        return happened

    def _heartbeat_lost(self, node_id: int, silent: float, limit: float) -> None:
        assert self.node is not None
        self.heartbeat_events += 1
        self.on_event(f"heartbeat of node {node_id} lost for {silent:.3f} s (consumer time {limit:g} s): "
                      f"{self._lost_host_note()}")
        self.node.emcy.send(HEARTBEAT_ERROR, 0x11)  # error register: generic error, communication error
        was = self.running
        self._lost_host(f"heartbeat of node {node_id} lost")
        if was and not self.running:
            self.controller.applied = 0.0  # the output stage holds zero from here on

    def _read_pdos(self) -> None:
        """The RPDOs and TPDOs the mapping objects now describe (enabled ones only)."""
        assert self.node is not None
        self.node.rpdo.read()
        self.node.tpdo.read()
        rpdos: Any = self.node.rpdo.map
        tpdos: Any = self.node.tpdo.map
        self._rpdos = [m for m in rpdos.values() if m.enabled and m.map]
        self._tpdos = [m for m in tpdos.values() if m.enabled and m.map and 1 <= m.trans_type <= 240]

    # ----------------------------------------------------------------------------------------------------------
    # SYNC
    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.silent or self.nmt_state != "OPERATIONAL":
            return
        with self._lock:
            self._sync()

    def _sync(self) -> None:
        assert self.node is not None
        c = self.controller
        f = self.faults
        if f is not None and self._due(f.silent_at_s):
            self._fall_silent()
            return
        if f is not None and not self._heartbeat_stopped and self._due(f.heartbeat_stops_at_s):
            self._heartbeat_stopped = True
            self.node.nmt.stop_heartbeat()
            self.on_event("heartbeat stopped")
        if self._stalled_for:
            self._stalled_for -= 1
        if not self._stalled_for:
            late, self._late = self._late, []
            for cob_id, data in late:  # the answers to earlier SYNCs, held back
                self._transmit(cob_id, data)
        missed = f is not None and f.sync_miss > 0 and self._draws.random() < f.sync_miss
        if missed:  # the setpoint of this SYNC is never taken in; the plant goes on with the one it had
            self.missed_syncs += 1
            c.advance()
            self.syncs += 1
            return
        for rpdo in self._rpdos:
            for var in rpdo.map:
                if (var.index, var.subindex) == self._setpoint_key and rpdo.is_received:
                    self._setpoint_raw = var.raw
        value = float(self._setpoint_raw) * self.setup.setpoint_scale
        c.setpoint = value if self.running and math.isfinite(value) else 0.0
        c.enabled = self.running
        y = c.advance()
        self.syncs += 1
        if f is not None and f.emcy_at_s and self.error_code == 0 and self.state not in self.profile.faults \
                and self._due(f.emcy_at_s):
            self.error_code = f.emcy_code
            self.node.emcy.send(f.emcy_code, 0x03)  # error register: generic error, current
            self.on_event(f"EMCY 0x{f.emcy_code:04X}")
            self._fault(f"error 0x{f.emcy_code:04X}")
        drop = f is not None and f.tpdo_drop > 0 and self._draws.random() < f.tpdo_drop
        hold = f is not None and f.tpdo_late > 0 and self._draws.random() < f.tpdo_late
        if f is not None and f.tpdo_stall > 0 and not self._stalled_for and self._draws.random() < f.tpdo_stall:
            self._stalled_for = f.tpdo_stall_syncs
            self.stalls += 1
        for tpdo in self._tpdos:
            if self.syncs % tpdo.trans_type:
                continue
            for var in tpdo.map:
                var.raw = self._value(var, y)
            if drop:
                self.dropped_tpdos += 1
            elif hold or self._stalled_for:
                self.late_tpdos += hold
                self._late.append((tpdo.cob_id, bytes(tpdo.data)))
            else:
                self._transmit(tpdo.cob_id, bytes(tpdo.data))

    def _transmit(self, cob_id: int, data: bytes) -> None:
        """Send a TPDO, twice where ``tpdo_repeat`` draws it."""
        f = self.faults
        if f is not None and f.tpdo_repeat > 0 and self._draws.random() < f.tpdo_repeat:
            self.repeated_tpdos += 1
            self._transmit_once(cob_id, data)  # a frame the host receives twice
        self._transmit_once(cob_id, data)

    def _transmit_once(self, cob_id: int, data: bytes) -> None:
        """Send a TPDO now, or ``tpdo_delay_s`` later (from ``tpdo_delay_at_s`` on) from a thread of its own (in
        order)."""
        assert self.network is not None
        f = self.faults
        if f is None or not f.tpdo_delay_s or f.tpdo_delay_at_s and not self._due(f.tpdo_delay_at_s):
            self.network.send_message(cob_id, data)
            return
        if self._delayed is None:
            self._delayed = queue.Queue()
            threading.Thread(target=self._send_delayed, args=(self.network, self._delayed), name="tpdo-delay",
                             daemon=True).start()
        delay = f.tpdo_delay_s if f.tpdo_delay_share >= 1 or self._draws.random() < f.tpdo_delay_share else 0.0
        self._delayed_until = max(self._delayed_until, time.monotonic() + delay)  # in order: none overtakes
        self._delayed.put((self._delayed_until, cob_id, data))

    @staticmethod
    def _send_delayed(network: canopen.Network, items: queue.Queue[tuple[float, int, bytes] | None]) -> None:
        while (item := items.get()) is not None:
            due, cob_id, data = item
            time.sleep(max(0.0, due - time.monotonic()))
            network.send_message(cob_id, data)

    def stop_sending(self) -> None:
        """Stop the thread that sends delayed TPDOs (``tpdo_delay_s``), if there is one."""
        if self._delayed is not None:
            self._delayed.put(None)
            self._delayed = None

    def _due(self, at_s: float) -> bool:
        return bool(at_s) and self.controller.time >= at_s

    def _value(self, var: Any, y: Any) -> int | float:
        """The value of a mapped object after this period: statusword, sample counter, an actual value in counts."""
        key = (var.index, var.subindex)
        if var.index == STATUSWORD:
            return self._statusword()
        channel = self._channel_of.get(key)
        if channel is None:
            if var.index == SAMPLE_COUNTER:
                return self.controller.tick_count % (1 << var.length)
            return 0
        name, scale = channel
        if name == COUNTER:
            return self.controller.tick_count % (1 << var.length)
        value = self.controller.sensed(y, name) / scale
        if var.od.data_type in (0x8, 0x11):
            return value
        lo, hi = var.od.min, var.od.max
        if lo is None or hi is None:
            signed = var.od.data_type in (0x2, 0x3, 0x4)
            bits = var.length
            lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
        return int(min(max(round(value), lo), hi)) if math.isfinite(value) else 0

    def _fall_silent(self) -> None:
        assert self.node is not None and self.network is not None
        self.silent = True
        self.node.nmt.stop_heartbeat()
        self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        self.on_event("fell silent (no heartbeat, PDO or SDO answer)")


class SimulatedCia408Device(SimulatedCia402Drive):
    """A simulated CiA 408 device (a proportional valve, or a hydraulic drive in axis position or velocity control:
    whichever the plant is) with the drive's NMT, PDO, SYNC, heartbeat consumer and faults, and the CiA 408 state
    machine: it boots to DISABLED; HOLD and ACTIVE need the hardware enable input (``CanopenFaults.enable_input``);
    bus set points act only in ACTIVE with device mode 0x6042 = 1; a fault (an EMCY, a lost host) goes through
    FAULT_REACTION to FAULT_DISABLED, left by a rising edge of controlword bit 3."""

    profile = CIA408
    error_code_object = DEVICE_ERROR_CODE

    def __init__(self, controller: SimulatedController, setup: CanopenSetup, faults: CanopenFaults | None = None,
                 on_event: Callable[[str], None] | None = None) -> None:
        super().__init__(controller, setup, faults, on_event)
        self.device_mode = 0
        self.control_mode = 0

    def attach(self, network: canopen.Network) -> None:
        """As the drive's; device and control mode start as the EDS has them."""
        super().attach(network)
        assert self.node is not None
        od: Any = self.node.object_dictionary
        self.device_mode = int(od[DEVICE_MODE].default or 0)
        self.control_mode = int(od[CONTROL_MODE].default or 0)

    def _initial_state(self) -> StrEnum:
        return cia408.State.DISABLED  # NOT READY and INIT pass during the boot

    def _statusword(self) -> int:
        return cia408.statusword(cast(cia408.State, self.state))

    @property
    def running(self) -> bool:
        return self.state is cia408.State.ACTIVE and self.device_mode == 1

    @property
    def _enable_input(self) -> bool:
        return self.faults is None or self.faults.enable_input

    def _controlword(self, word: int) -> None:
        state = cast(cia408.State, self.state)
        new = cia408.next_state(state, word, self._last_word, enable_input=self._enable_input)
        if state in cia408.FAULT_STATES and new not in cia408.FAULT_STATES:
            self._clear_error()
        if new is cia408.State.ACTIVE and self.faults is not None and self.faults.refuse_enable:
            self.on_event(f"refuses to go ACTIVE (controlword 0x{word:04X})")
            new = cia408.State.HOLD
        if new is cia408.State.DISABLED and cia408.requested_state(word) in (cia408.State.HOLD, cia408.State.ACTIVE) \
                and not self._enable_input:
            self.on_event(f"stays DISABLED: no hardware enable input (controlword 0x{word:04X})")
        self._go(new, f"controlword 0x{word:04X}")

    def _write_mode(self, index: int, data: bytes) -> bool:
        from canopen.sdo import SdoAbortedError

        if index not in (DEVICE_MODE, CONTROL_MODE):
            return False
        value = int.from_bytes(data, "little", signed=True)
        if index == DEVICE_MODE:
            if value not in (1, 3, 4):  # set points via the bus, install, reference mode
                raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
            self.device_mode = value
        else:
            if value not in cia408.CONTROL_MODES.values():
                raise SdoAbortedError(0x06090030)
            self.control_mode = value
        return True

    def _read_mode(self, index: int) -> int | None:
        return {DEVICE_MODE: self.device_mode, CONTROL_MODE: self.control_mode}.get(index)

    def _fault(self, why: str) -> None:
        self._go(cia408.State.FAULT_REACTION, why)
        self._go(cia408.State.FAULT_DISABLED, "fault reaction done")

    def _left_operational(self, why: str) -> None:
        if self.state in (cia408.State.ACTIVE, cia408.State.HOLD):
            self._go(cia408.State.DISABLED, why)

    def _lost_host(self, why: str) -> None:
        if self.state in (cia408.State.HOLD, cia408.State.ACTIVE):
            self.error_code = HEARTBEAT_ERROR
            self._fault(why)

    def _lost_host_note(self) -> str:
        return "a lost host is a fault: FAULT_REACTION, then FAULT_DISABLED"


class ServingCanopen:
    """A simulated CiA 402 drive on its own python-can bus (canopen's notifier thread answers); ``close`` stops it.
    ``controller`` is the drive's ``SimulatedController`` (its ``on_event`` reports the drive's changes too)."""

    def __init__(self, drive: SimulatedCia402Drive, network: canopen.Network) -> None:
        self.drive = drive
        self.network = network
        self.controller = drive.controller
        self.stop = threading.Event()
        self.error: BaseException | None = None
        self._consumer_timer = threading.Thread(target=self._watch_heartbeats, name="cia402-heartbeat-consumer",
                                                daemon=True)
        self._consumer_timer.start()

    def _watch_heartbeats(self) -> None:
        """The drive's heartbeat consumer timer: on the wall clock, whether or not SYNCs come."""
        try:
            while not self.stop.wait(self.drive.poll_s):
                self.drive.check_heartbeat()
        except BaseException as exc:  # noqa: BLE001 - reported to whoever closes us
            self.error = exc

    def close(self) -> None:
        """Stop the heartbeat consumer, the heartbeat, the notifier and the bus."""
        self.stop.set()
        self._consumer_timer.join(timeout=2.0)
        self.drive.stop_sending()
        if self.drive.node is not None:
            self.drive.node.nmt.stop_heartbeat()
        self.network.disconnect()


def serve_canopen(controller: SimulatedController, setup: CanopenSetup, can: dict[str, Any],
                  faults: CanopenFaults | None = None) -> ServingCanopen:
    """Serve a simulated CANopen device of ``setup.profile`` (a CiA 402 drive or a CiA 408 device) around
    ``controller`` on a python-can bus opened from ``can`` (interface, channel, bitrate, options); the device's events
    go to ``controller.on_event``."""
    import can as python_can
    import canopen

    kwargs = dict(can.get("options") or {})
    if can.get("bitrate") is not None:
        kwargs["bitrate"] = can["bitrate"]
    bus = python_can.Bus(interface=can["interface"], channel=can.get("channel"), **kwargs)
    network = canopen.Network(bus)
    kind = SimulatedCia408Device if setup.profile == "408" else SimulatedCia402Drive
    drive = kind(controller, setup, faults, lambda text: controller.on_event(text))
    try:
        network.connect()
        drive.attach(network)
    except BaseException:
        network.disconnect()
        raise
    return ServingCanopen(drive, network)
