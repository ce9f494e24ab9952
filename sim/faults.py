"""Fault injection for the simulated servo controller: what broken cables, busy buses and sick drives do.

Faults act where they happen on a real bench: on the feedback values the
drive reports (a stuck or jumping counter, NaN, a sensor out of range, a drive
that stops answering) and on the frames on the wire (dropped, duplicated,
reordered, delayed, error frames, random bytes on a serial line). Configured
in a bench config's ``[simulator.faults]`` table; every probability is per
feedback frame.
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from bodebench.drivers.ports import Frame, FramePort

ERROR_FRAME_ID = 0x0  # error frames carry no meaningful id; python-can flags them


@dataclass(frozen=True)
class FaultConfig:
    """What goes wrong, and how often (probabilities per feedback frame, times in s of controller time).

    drop, duplicate, reorder: a feedback frame is not sent / sent twice / held back behind the next one.
    delay_s, delay_jitter_s: feedback frames leave this much later (plus uniform jitter), wall clock.
    error_frames: an error frame follows a feedback frame (CAN).
    garbage: a burst of 1-32 random bytes precedes a frame (serial line).
    forged: a frame with a feedback id, the right length and random payload follows a feedback frame (another node
    on the bus; on a serial line it carries a valid CRC-16).
    truncated: a feedback frame is cut short on the wire, its tail never sent (serial line).
    counter_stuck_after: from this tick on the feedback counter no longer advances.
    counter_jump_at, counter_jump_by: at this tick the counter leaps ahead by ``counter_jump_by``.
    nan: a float channel value reads NaN (half of them +-inf).
    out_of_range_after_s: from then on the position reads +1e6 (a broken sensor).
    stop_after_s: from then on the drive answers nothing (cable pulled, drive crashed).
    silent_until_s: before then the drive answers nothing (still booting), its clock going on.
    bus_off_after_s: from then on the drive sends only error frames (its CAN controller went bus-off).
    disable_after_s: from then on the drive is disabled, its output stage at zero, and goes on answering (a trip it
    does not report: the host sees valid frames of a plant at rest and an echo of 0).
    stall_every_s, stall_s: the last ``stall_s`` of every ``stall_every_s`` the drive answers nothing (a stalled bus,
    frames lost in a burst): its clock and counter go on, so the host's samples have a gap there.
    seed: random seed.

    The fields carry their bounds as validation metadata: the configuration loader checks a
    ``[simulator.faults]`` table against them.
    """

    drop: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per feedback frame"})
    duplicate: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per feedback frame"})
    reorder: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per feedback frame"})
    delay_s: float = field(default=0.0, metadata={"min": 0, "doc": "s"})
    delay_jitter_s: float = field(default=0.0, metadata={"min": 0, "doc": "s"})
    error_frames: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per feedback frame"})
    garbage: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per feedback frame"})
    forged: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per feedback frame"})
    truncated: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per feedback frame"})
    counter_stuck_after: int = field(default=-1, metadata={"doc": "controller tick (negative: never)"})
    counter_jump_at: int = field(default=-1, metadata={"doc": "controller tick (negative: never)"})
    counter_jump_by: int = field(default=0, metadata={"doc": "counts"})
    nan: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per feedback frame"})
    out_of_range_after_s: float = field(default=-1.0, metadata={"doc": "controller time, s (negative: never)"})
    stop_after_s: float = field(default=-1.0, metadata={"doc": "controller time, s (negative: never)"})
    silent_until_s: float = field(default=0.0, metadata={"min": 0, "doc": "controller time, s"})
    bus_off_after_s: float = field(default=-1.0, metadata={"doc": "controller time, s (negative: never)"})
    disable_after_s: float = field(default=-1.0, metadata={"doc": "controller time, s (negative: never)"})
    stall_every_s: float = field(default=0.0, metadata={"min": 0, "doc": "controller time, s (0: never)"})
    stall_s: float = field(default=0.0, metadata={"min": 0, "doc": "s of each stall_every_s without an answer"})
    seed: int = field(default=0, metadata={"min": 0, "doc": "numpy random seed"})

    @property
    def any(self) -> bool:
        """True when anything goes wrong (any setting but the seed differs from the default)."""
        return self != FaultConfig(seed=self.seed)


class ValueFaults:
    """Faults of the drive itself, applied to a sample's values before they are encoded."""

    def __init__(self, config: FaultConfig) -> None:
        self.config = config
        self.rng = np.random.default_rng(config.seed + 1)

    def silent(self, time_s: float) -> bool:
        """The drive answers nothing (stopped) at controller time ``time_s``."""
        c = self.config
        if time_s < c.silent_until_s:
            return True
        if c.stall_every_s > 0 and time_s % c.stall_every_s >= c.stall_every_s - c.stall_s:
            return True
        return 0 <= c.stop_after_s <= time_s

    def disabled(self, time_s: float) -> bool:
        """The drive has disabled itself, unreported, at controller time ``time_s``."""
        return 0 <= self.config.disable_after_s <= time_s

    def bus_off(self, time_s: float) -> bool:
        """The drive sends only error frames (bus-off) at controller time ``time_s``."""
        c = self.config
        return 0 <= c.bus_off_after_s <= time_s

    def counter(self, tick: int) -> int:
        """The feedback counter the drive sends at ``tick`` (stuck or jumped ahead as configured)."""
        c = self.config
        if 0 <= c.counter_stuck_after <= tick:
            tick = c.counter_stuck_after
        if 0 <= c.counter_jump_at <= tick:
            tick += c.counter_jump_by
        return tick

    def value(self, name: str, value: float, time_s: float) -> float:
        """Channel ``name``'s ``value`` as the drive reports it at controller time ``time_s``."""
        c = self.config
        if name == "position" and 0 <= c.out_of_range_after_s <= time_s:
            return 1e6
        if c.nan and self.rng.random() < c.nan:
            return (math.nan, math.inf, -math.inf)[int(self.rng.integers(0, 3))]
        return value


class FaultyPort(FramePort):
    """The drive's side of the wire with frame faults: wraps the port the controller serves on.

    Only feedback frames (ids in ``feedback_ids``) are disturbed; what the host
    sends reaches the controller unchanged.
    """

    def __init__(self, inner: FramePort, config: FaultConfig, feedback_ids: set[int],
                 raw_write: Callable[[bytes], object] | None = None,
                 encode: Callable[[Frame], bytes] | None = None) -> None:
        """raw_write: writes bytes straight onto a serial line; encode: a frame's bytes on that line (both None on a
        bus)."""
        super().__init__(f"{inner.name} (faults)", inner.transport)
        self.inner = inner
        self.config = config
        self.feedback_ids = feedback_ids
        self.raw_write = raw_write  # serial: writes bytes straight onto the line
        self.encode = encode
        self.rng = np.random.default_rng(config.seed)
        self._held: Frame | None = None
        self._due: list[tuple[float, int, Frame]] = []
        self._seq = 0
        self.injected = {"dropped": 0, "duplicated": 0, "reordered": 0, "delayed": 0, "error_frames": 0,
                         "garbage_bursts": 0, "forged": 0, "truncated": 0}

    def _emit(self, frame: Frame) -> None:
        c = self.config
        if c.delay_s or c.delay_jitter_s:
            due = time.monotonic() + c.delay_s + c.delay_jitter_s * self.rng.random()
            self._seq += 1
            heapq.heappush(self._due, (due, self._seq, frame))
            self.injected["delayed"] += 1
            return
        self._write(frame)

    def _write(self, frame: Frame) -> None:
        c = self.config
        if self.raw_write is not None and c.garbage and self.rng.random() < c.garbage:
            self.raw_write(bytes(self.rng.integers(0, 256, int(self.rng.integers(1, 33)), dtype=np.uint8)))
            self.injected["garbage_bursts"] += 1
        if self.raw_write is not None and self.encode is not None and c.truncated and self.rng.random() < c.truncated:
            wire = self.encode(frame)
            self.raw_write(wire[: int(self.rng.integers(1, len(wire)))])
            self.injected["truncated"] += 1
        else:
            self.inner.send(frame)
        if c.forged and self.rng.random() < c.forged:
            forged = bytes(self.rng.integers(0, 256, len(frame.data), dtype=np.uint8))
            self.inner.send(Frame(frame.id, forged, frame.extended, 0.0))
            self.injected["forged"] += 1
        if c.error_frames and self.rng.random() < c.error_frames:
            self.inner.send(Frame(ERROR_FRAME_ID, b"", False, 0.0, is_error=True))
            self.injected["error_frames"] += 1

    def _flush_due(self) -> None:
        now = time.monotonic()
        while self._due and self._due[0][0] <= now:
            self._write(heapq.heappop(self._due)[2])

    def _send(self, frame: Frame) -> None:
        self._flush_due()
        if frame.id not in self.feedback_ids or frame.is_error:
            self.inner.send(frame)
            return
        c = self.config
        if c.drop and self.rng.random() < c.drop:
            self.injected["dropped"] += 1
            return
        if c.reorder and self._held is None and self.rng.random() < c.reorder:
            self._held = frame
            self.injected["reordered"] += 1
            return
        self._emit(frame)
        if c.duplicate and self.rng.random() < c.duplicate:
            self._emit(frame)
            self.injected["duplicated"] += 1
        if self._held is not None:
            held, self._held = self._held, None
            self._emit(held)

    def _recv(self, timeout: float, limit: int) -> list[Frame]:
        if self._due:
            timeout = min(timeout, max(0.0, self._due[0][0] - time.monotonic()))
        frames = self.inner.recv(timeout)
        self._flush_due()
        return frames

    def _close(self) -> None:
        self.inner.close()


@dataclass(frozen=True)
class CanopenFaults:
    """Faults of the simulated CANopen device (times in s of controller time; 0: never).

    refuse_enable: the drive stays "switched on" when told to enable operation (CiA 408: in HOLD when told ACTIVE).
    enable_input: (CiA 408) the hardware enable input is set; False: the device stays DISABLED. emcy_at_s, emcy_code:
    from then on the drive is in fault, having sent an EMCY with this error code. heartbeat_stops_at_s: its heartbeat
    stops (the PDOs go on). silent_at_s: it answers nothing more (no heartbeat, PDO or SDO). sync_miss, tpdo_drop,
    tpdo_late: probabilities per SYNC that the drive misses it (no new setpoint taken, no TPDO; the plant goes on), that
    its TPDOs are not sent, that they are sent late (after the next SYNC arrived, before that SYNC's own); tpdo_stall:
    probability per SYNC that the drive stalls, holding back its TPDOs of this SYNC and the next tpdo_stall_syncs - 1
    and sending them in one burst when SYNC tpdo_stall_syncs later arrives, before that SYNC's own; seed: of all
    these draws. tpdo_delay_s, tpdo_delay_share: a TPDO reaches the bus this long after it is due (as a gateway or a USB
    adapter delays it), every one or this share of them at random (later ones wait for it: none overtakes), from
    controller time tpdo_delay_at_s on (0: from the start, before the drive is enabled).
    tpdo_repeat: probability per TPDO that it goes out twice (as a frame received twice). fixed_tpdo_mapping: the
    drive's TPDO mapping is its EDS's whatever the host writes. sync_period_us: the communication cycle period
    0x1006 the drive holds (us), as one that watches its SYNC by it does (this one does not watch).
    """

    refuse_enable: bool = field(default=False, metadata={"doc": "never reach operation enabled (CiA 408: ACTIVE)"})
    enable_input: bool = field(default=True, metadata={"doc": "CiA 408: the hardware enable input is set (false: "
                                                              "the device stays DISABLED)"})
    emcy_at_s: float = field(default=0.0, metadata={"min": 0, "doc": "EMCY and fault at this controller time, s"})
    emcy_code: int = field(default=0x2310, metadata={"min": 0x1000, "max": 0xFFFF,
                                                     "doc": "error code of that EMCY (0x2310: continuous "
                                                            "overcurrent)"})
    heartbeat_stops_at_s: float = field(default=0.0, metadata={"min": 0, "doc": "heartbeat stops, s"})
    silent_at_s: float = field(default=0.0, metadata={"min": 0, "doc": "the drive falls silent, s"})
    sync_miss: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per SYNC that the "
                                                                               "drive misses it"})
    tpdo_drop: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per SYNC that its "
                                                                               "TPDOs are not sent"})
    tpdo_late: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per SYNC that its "
                                                                               "TPDOs go out after the next SYNC"})
    tpdo_stall: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per SYNC that the "
                                                                                "drive stalls: its TPDOs go out in "
                                                                                "a burst tpdo_stall_syncs later"})
    tpdo_stall_syncs: int = field(default=4, metadata={"min": 1, "max": 1000, "doc": "SYNCs a stall holds the "
                                                                                    "TPDOs back for"})
    tpdo_delay_s: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "a TPDO is sent this long "
                                                                                  "after it is due, s"})
    tpdo_delay_share: float = field(default=1.0, metadata={"min": 0, "max": 1, "doc": "the share of TPDOs "
                                                                                      "tpdo_delay_s delays"})
    tpdo_delay_at_s: float = field(default=0.0, metadata={"min": 0, "doc": "tpdo_delay_s applies from this "
                                                                           "controller time on, s (0: always)"})
    tpdo_repeat: float = field(default=0.0, metadata={"min": 0, "max": 1, "doc": "probability per TPDO that the "
                                                                                "host receives it twice"})
    seed: int = field(default=0, metadata={"min": 0, "doc": "random seed of the draws above (sync_miss to "
                                                            "tpdo_repeat)"})
    sync_period_us: int = field(default=0, metadata={"min": 0, "max": 10_000_000, "doc": "the communication "
                                                     "cycle period 0x1006 the drive holds, us (not watched)"})
    fixed_tpdo_mapping: bool = field(default=False, metadata={
        "doc": "the drive acknowledges writes to its TPDO mapping (0x1A00..0x1A03) but reads back, and keeps, the "
               "mapping its EDS gives"})

    @property
    def any(self) -> bool:
        """True when any fault is configured."""
        return self.refuse_enable or not self.enable_input or self.fixed_tpdo_mapping or bool(self.sync_period_us or
            self.emcy_at_s or self.heartbeat_stops_at_s or self.silent_at_s or self.sync_miss or self.tpdo_drop
            or self.tpdo_late or self.tpdo_stall or self.tpdo_delay_s or self.tpdo_repeat)
