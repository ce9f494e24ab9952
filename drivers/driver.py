"""The instrument's view of a servo controller: send setpoints and commands, receive assembled feedback samples.

``Driver`` works on any ``FramePort`` with any ``Layout``. Feedback frames that share a counter value are joined
into one ``FeedbackSample``; counter gaps, repeats and partial samples are counted in ``BusHealth``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

from .codec import COUNTER, SETPOINT, TIMESTAMP, Codec
from .e2e import crc_byte, intact
from .errors import LayoutError
from .layout import Layout
from .ports import Frame, FramePort

__all__ = ["REJECT_CAUSES", "BusHealth", "Driver", "FeedbackSample", "Unwrapper"]

_MAX_PENDING = 64
"""Most partial samples held at once; beyond that the oldest is dropped as incomplete."""
_RESTART_BEHIND = 64
"""A feedback counter this many samples or more behind the expected one is taken as a restart of the counter."""
_FAR = 64
"""A feedback counter this many samples or more ahead of the latest accepted one, or a restart, is believed only when
``_CONFIRM`` frames in a row carry it (the same or each the next counter): one frame from elsewhere cannot move the
count."""
_CONFIRM = 3
REJECT_CAUSES = ("length", "crc", "counter")
"""Why feedback frames are rejected before they become data: a payload of the wrong length, a CRC-8 that does not
match, a counter that breaks continuity (far from the expected one and not confirmed)."""


class Unwrapper:
    """Turns a rolling counter (values ``0 .. modulus - 1``) into a monotonic integer.

    Each raw value is placed at the unwrapped value nearest to the previous one: a step of ``d = (raw - previous)
    mod modulus`` counts forward when ``d < modulus / 2`` and backward (``d - modulus``) otherwise. So a jump
    backwards in the raw value by more than half the modulus is a wrap (e.g. 65535 -> 2 with modulus 65536 is +3),
    and a small backward step (a repeated or reordered value) stays a backward step. The first value is returned
    as is. Gaps of half the modulus or more cannot be told from backward steps.
    """

    def __init__(self, modulus: int) -> None:
        """``modulus``: number of distinct raw values (``2**bits``), at least 2."""
        if not isinstance(modulus, int) or isinstance(modulus, bool) or modulus < 2:
            raise ValueError(f"Unwrapper modulus must be an integer >= 2, got {modulus!r}")
        self.modulus = modulus
        self._last: int | None = None

    @property
    def last(self) -> int | None:
        """The last unwrapped value (None before the first)."""
        return self._last

    def reset(self) -> None:
        """Forget the history; the next value is returned as is."""
        self._last = None

    def unwrap(self, raw: int) -> int:
        """Unwrapped value of ``raw`` (0 <= raw < modulus)."""
        self._last = self.peek(raw)
        return self._last

    def peek(self, raw: int) -> int:
        """The value ``unwrap(raw)`` would return, without taking it as the new previous value."""
        if not isinstance(raw, int) or isinstance(raw, bool) or not 0 <= raw < self.modulus:
            raise ValueError(f"raw counter value must be an integer 0..{self.modulus - 1}, got {raw!r}")
        if self._last is None:
            return raw
        m = self.modulus
        step = (raw - self._last) % m
        if step >= (m + 1) // 2:
            step -= m
        return self._last + step


@dataclass(frozen=True)
class FeedbackSample:
    """One feedback sample.

    ``counter``: unwrapped sample counter (monotonic), None when the layout has none. ``timestamp``: controller time
    in s unwrapped from timestamp_us, None without one. ``receive_time``: timestamp (s) of the last frame of the
    sample. ``values``: physical channel values in ``Layout.channels`` order.
    """

    counter: int | None
    timestamp: float | None
    receive_time: float
    values: tuple[float, ...]


@dataclass
class BusHealth:
    """Link statistics (plain data). ``errors`` = port errors (error frames, CRC failures, malformed input) plus
    feedback frames that failed to decode or were rejected; ``lost_samples``: counter values never seen;
    ``duplicates``: repeated or stale counter values (dropped; CANopen with ``timebase = "sync"``: TPDOs the same as
    the one before with no SYNC between them); ``incomplete_samples``: counters with some but not
    all feedback frames (dropped); ``bus_state``: "active", "passive", "bus-off" or "unknown"; ``last_error``:
    description of the latest error; ``counter_restarts``: times the feedback counter jumped back by more than 64
    samples (assembly restarted there); ``resyncs``: serial lines only, runs of bytes discarded between frames (line
    noise, garbage); ``rejected``: feedback frames refused before assembly, by cause (``REJECT_CAUSES``): never part
    of a sample; ``broken_frames``: serial lines only, frames cut short (the line went quiet inside one), dropped at
    once; ``undated``: CANopen with ``timebase = "sync"``, TPDOs dropped because the SYNC they answer cannot be
    told (``drivers.sync_dating``; the SYNCs left without an answer count in ``lost_samples``); ``dated_by_rhythm``:
    there too, the gaps after which TPDOs were dated by their rhythm alone (a lost TPDO, or a drive fallen a SYNC
    behind, which the host cannot tell apart: 0 on a bus that loses no frame); ``answer_checks``: there too, on the
    realtime clock, the SYNCs left out (or sent late) after such gaps to check that the drive still answers within
    a SYNC period."""

    frames_in: int = 0
    frames_out: int = 0
    errors: int = 0
    lost_samples: int = 0
    duplicates: int = 0
    incomplete_samples: int = 0
    bus_state: str = "unknown"
    last_error: str = ""
    counter_restarts: int = 0
    resyncs: int = 0
    broken_frames: int = 0
    undated: int = 0
    dated_by_rhythm: int = 0
    answer_checks: int = 0
    rejected: dict[str, int] = dataclasses.field(default_factory=lambda: dict.fromkeys(REJECT_CAUSES, 0))

    @property
    def rejected_total(self) -> int:
        """Feedback frames rejected, all causes."""
        return sum(self.rejected.values())

    def snapshot(self) -> BusHealth:
        """An independent copy."""
        return dataclasses.replace(self, rejected=dict(self.rejected))


class Driver:
    """Setpoints, commands and feedback samples over ``port`` using ``layout`` (validated for the port's transport).

    Sample assembly: feedback frames are grouped by unwrapped counter. A sample is complete when every feedback
    message of its counter has arrived; it is then returned, and older partial samples are dropped and counted as
    incomplete, counters skipped without any frame count as lost. Frames whose counter is not newer than the last
    complete sample count as duplicates and are dropped (one count per repeated counter value), as do repeats of a
    message within a partial sample; a counter more than 64 samples behind is a restart of the controller's counter
    (partial samples dropped, counted in ``counter_restarts``; assembly continues with counters shifted to follow on
    from the last one, so ``FeedbackSample.counter`` stays monotonic). At most 64 partial samples are held; beyond
    that the oldest is dropped as incomplete. Frames with ids not in the feedback set are ignored (counted only in
    ``frames_in``); feedback frames that fail to decode count as errors and never raise.

    Before assembly each feedback frame must prove itself (rejections counted by cause in ``BusHealth.rejected``):
    its payload has exactly the message's length (a drive that pads its CAN frames declares the padding), its
    ``crc`` byte matches where the message has one, and a counter far from the latest accepted one (64 samples
    ahead or more, or a restart behind) is believed only when three frames in a row carry it.
    """

    def __init__(self, port: FramePort, layout: Layout) -> None:
        """Use ``port`` (kept open until ``close()``) with ``layout``; LayoutError if it does not suit the port."""
        layout.validate(port.transport)
        self.port = port
        self.layout = layout
        self.health = BusHealth()
        self.start_account = ""
        """What ``enable`` did and measured, in words, where it did more than send the enable frame (empty here)."""
        self._channels = layout.channels
        self._by_key: dict[tuple[int, bool], int] = {
            (msg.id, msg.extended): index for index, msg in enumerate(layout.feedback)
        }
        self._n_feedback = len(layout.feedback)
        modulus = layout.counter_modulus
        self._counter: Unwrapper | None = (
            Unwrapper(modulus) if layout.has_counter and modulus is not None else None
        )
        self._setpoint_modulus = layout.counter_modulus if layout.has_setpoint_counter else None
        ts_modulus = layout.timestamp_modulus
        self._clock: Unwrapper | None = Unwrapper(ts_modulus) if ts_modulus is not None else None
        self._ts_index = next(
            (i for i, msg in enumerate(layout.feedback) if TIMESTAMP in msg.signal_names), None
        )
        self._crc_at = {index: at for index, msg in enumerate(layout.feedback) if (at := crc_byte(msg)) is not None}
        self._far_raw: int | None = None  # the raw counter of the latest far frame, and how many in a row
        self._far_run = 0
        self._pending: dict[int, dict[int, tuple[dict[str, float], float]]] = {}
        self._next: int | None = None  # lowest counter not yet emitted, lost or dropped
        self._offset = 0  # added to unwrapped counters after counter restarts
        self._last_duplicate: int | None = None
        self._decode_errors = 0
        self._port_last_error = port.last_error
        self._update_health()

    # ----------------------------------------------------------------------------------------------------------
    # commands
    def send_setpoint(self, value: float, counter: int = 0, idle: bool = False) -> None:
        """Send the setpoint ``value`` (physical units of the layout) with ``counter`` (reduced modulo the counter
        modulus; ignored when the setpoint message has no counter). LayoutError when the value does not fit.
        ``idle``: the sample answering this tick enters no point (a ramp, or between points), so the driver may
        spend the tick checking its link (``dating_unchecked``)."""
        values = {SETPOINT: value}
        if self._setpoint_modulus is not None:
            values[COUNTER] = int(counter) % self._setpoint_modulus
        self._send(self.layout.setpoint, values)

    def enable(self) -> None:
        """Send the enable message (no-op when the layout has none)."""
        if self.layout.enable is not None:
            self._send(self.layout.enable, {})

    @property
    def dating_unchecked(self) -> bool:
        """Whether samples already returned may be dated wrongly until the driver has checked its link, which it
        does on an ``idle`` tick (CANopen, ``timebase = "sync"``: a gap in the TPDOs whose dating assumed a drive
        that keeps up). False for links whose samples carry their own date."""
        return False

    counts_host_ticks = False
    """True when ``FeedbackSample.counter`` is the host's tick after the setpoint the sample answers (the
    counter passed to ``send_setpoint`` plus one), not the drive's own count."""
    shutdown_account = ""
    """What ``disable()`` did to the drive beyond the disable frame, in words (empty: nothing more)."""

    def disable(self) -> bool:
        """Send the disable message (no-op when the layout has none); True when it went out."""
        if self.layout.disable is not None:
            self._send(self.layout.disable, {})
            return True
        return False

    def heartbeat(self) -> None:
        """Send the heartbeat message (no-op when the layout has none); call every ``layout.heartbeat_period_s``."""
        if self.layout.heartbeat is not None:
            self._send(self.layout.heartbeat, {})

    def start_heartbeat(self) -> bool:
        """Have the port repeat the heartbeat every ``layout.heartbeat_period_s`` on its own (python-can's periodic
        send); False when the layout has none or the port cannot (then call ``heartbeat()`` on time)."""
        hb = self.layout.heartbeat
        if hb is None:
            return False
        try:
            return self.port.send_periodic(Frame(hb.id, hb.encode({}), hb.extended), self.layout.heartbeat_period_s)
        finally:
            self._update_health()

    def _send(self, msg: Codec, values: dict[str, float]) -> None:
        data = msg.encode(values)
        try:
            self.port.send(Frame(msg.id, data, msg.extended))
        finally:
            self._update_health()

    # ----------------------------------------------------------------------------------------------------------
    # feedback
    def receive(self, timeout: float) -> list[FeedbackSample]:
        """Samples completed within ``timeout`` s: waits until at least one sample is complete, a frame turns out
        cut short (serial: the reply it was will never complete) or the time is up, then returns every sample
        completed by the frames received so far (oldest first)."""
        if not isinstance(timeout, (int, float)) or not timeout >= 0:
            raise ValueError(f"receive timeout must be a number >= 0 s, got {timeout!r}")
        deadline = time.monotonic() + timeout
        samples: list[FeedbackSample] = []
        broken = getattr(self.port, "broken_frames", 0)
        try:
            while True:
                frames = self.port.recv(max(0.0, deadline - time.monotonic()))
                for frame in frames:
                    sample = self._accept(frame)
                    if sample is not None:
                        samples.append(sample)
                if samples or time.monotonic() >= deadline or getattr(self.port, "broken_frames", 0) != broken:
                    return samples
        finally:
            self._update_health()

    def feed(self, frames: list[Frame]) -> list[FeedbackSample]:
        """Assemble samples from frames obtained elsewhere (same rules as ``receive``)."""
        samples = [s for s in (self._accept(f) for f in frames) if s is not None]
        self._update_health()
        return samples

    def _accept(self, frame: Frame) -> FeedbackSample | None:
        if frame.is_error:
            return None  # counted by the port
        index = self._by_key.get((frame.id, frame.extended))
        if index is None:
            return None
        msg = self.layout.feedback[index]
        data = frame.data
        if len(data) != msg.length:
            self._reject("length", frame, f"payload of {len(data)} bytes, the message has {msg.length}")
            return None
        at = self._crc_at.get(index)
        if at is not None and not intact(data, at):
            self._reject("crc", frame, "CRC-8 does not match")
            return None
        try:
            values = msg.decode(data)
            raw = self._raw_counter(values) if self._counter is not None else None
            counter = self._counter.peek(raw) if self._counter is not None and raw is not None else None
        except (LayoutError, ValueError) as exc:
            self._decode_errors += 1
            self.health.last_error = f"feedback frame 0x{frame.id:X}: {exc}"
            return None
        if counter is None:
            return self._emit(None, {index: (values, frame.timestamp)})
        assert self._counter is not None and raw is not None
        last = self._counter.last
        if last is not None:
            ahead = counter - last  # continuity: from the latest frame accepted
            if (ahead >= _FAR or ahead < -_RESTART_BEHIND) and not self._confirmed(raw):
                self._reject("counter", frame, f"counter {raw} is {ahead:+d} from the expected one")
                return None
        self._far_raw, self._far_run = None, 0
        counter = self._counter.unwrap(raw)
        if self._next is None:
            self._next = counter
        counter += self._offset
        if counter < self._next - _RESTART_BEHIND:
            counter = self._restart(counter)
        if counter < self._next:
            if counter != self._last_duplicate:
                self.health.duplicates += 1
                self._last_duplicate = counter
            return None
        parts = self._pending.setdefault(counter, {})
        if index in parts:
            if counter != self._last_duplicate:
                self.health.duplicates += 1
                self._last_duplicate = counter
            return None
        parts[index] = (values, frame.timestamp)
        if len(parts) < self._n_feedback:
            if len(self._pending) > _MAX_PENDING:
                self._drop_oldest()
            return None
        del self._pending[counter]
        older = [c for c in self._pending if c < counter]
        for c in older:
            del self._pending[c]
        self.health.incomplete_samples += len(older)
        self.health.lost_samples += counter - self._next - len(older)
        self._next = counter + 1
        return self._emit(counter, parts)

    def _reject(self, cause: str, frame: Frame, why: str) -> None:
        self.health.rejected[cause] += 1
        self.health.last_error = f"feedback frame 0x{frame.id:X} rejected: {why}"

    def _confirmed(self, raw: int) -> bool:
        """A far counter is believed on its third frame in a row carrying it or each the next value."""
        assert self._counter is not None
        if self._far_raw is not None and (raw - self._far_raw) % self._counter.modulus in (0, 1):
            self._far_run += 1
        else:
            self._far_run = 1
        self._far_raw = raw
        return self._far_run >= _CONFIRM

    def _raw_counter(self, values: dict[str, float]) -> int:
        raw = values[COUNTER]
        if raw != int(raw):
            raise ValueError(f"counter value {raw!r} is not an integer")
        return int(raw)

    def _restart(self, counter: int) -> int:
        """The controller's counter jumped far back (e.g. it restarted): drop partial samples and continue, shifting
        later counters so that the reported counter stays monotonic. Returns the shifted ``counter``."""
        assert self._next is not None
        self.health.incomplete_samples += len(self._pending)
        self._pending.clear()
        self.health.counter_restarts += 1
        self.health.last_error = (
            f"feedback counter jumped back from {self._next - 1} to {counter}; assembly restarted"
        )
        self._offset += self._next - counter
        self._last_duplicate = None
        return self._next

    def _drop_oldest(self) -> None:
        assert self._next is not None
        oldest = min(self._pending)
        del self._pending[oldest]
        self.health.incomplete_samples += 1
        self.health.lost_samples += oldest - self._next
        self._next = oldest + 1

    def _emit(self, counter: int | None, parts: dict[int, tuple[dict[str, float], float]]) -> FeedbackSample:
        merged: dict[str, float] = {}
        receive_time = 0.0
        for values, stamp in parts.values():  # in arrival order: the last one completed the sample
            merged.update(values)
            receive_time = stamp
        timestamp: float | None = None
        if self._clock is not None and self._ts_index is not None and self._ts_index in parts:
            raw = parts[self._ts_index][0][TIMESTAMP]
            timestamp = self._clock.unwrap(int(raw)) * 1e-6
        return FeedbackSample(counter, timestamp, receive_time, tuple(merged[name] for name in self._channels))

    # ----------------------------------------------------------------------------------------------------------
    # health and shutdown
    def _update_health(self) -> None:
        h = self.health
        port = self.port
        h.frames_in = port.frames_in
        h.frames_out = port.frames_out
        h.errors = port.errors + self._decode_errors + h.rejected_total
        h.resyncs = getattr(port, "resyncs", 0)
        h.broken_frames = getattr(port, "broken_frames", 0)
        h.bus_state = port.bus_state()
        if port.last_error != self._port_last_error:
            self._port_last_error = port.last_error
            h.last_error = port.last_error

    def close(self) -> None:
        """Close the port."""
        try:
            self.port.close()
        finally:
            self._update_health()

    def __enter__(self) -> Driver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
