"""The simulated servo controller: a plant behind the same wire protocol a real drive speaks.

The controller receives setpoint, enable and disable frames, steps its plant
with the setpoint held over each control period, and answers with feedback
frames (counter, controller timestamp, channels). Two clocks:

- ``lockstep``: every setpoint advances simulated time by one control period
  and is answered at once, so a sweep runs as fast as the bus carries frames;
- ``realtime``: the plant is stepped at the control rate on the wall clock with
  the latest setpoint, whatever the host does.

It is transport-agnostic: ``handle``/``tick`` turn frames into frames, and
``serve`` runs either clock over any ``bodebench.drivers.ports.FramePort``.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bodebench.drivers.codec import CRC, SETPOINT_ECHO, Codec, Message
from bodebench.drivers.e2e import crc_byte, seal
from bodebench.drivers.errors import DriverTimeoutError, LayoutError
from bodebench.drivers.layout import Layout
from bodebench.drivers.ports import Frame, FramePort
from bodebench.drivers.scheduling import keep_to, lower_timer_slack, pacing_cpu, request_fifo
from bodebench.sim.faults import ValueFaults
from bodebench.sim.plants import Plant

CLOCKS = ("lockstep", "realtime")
CATCH_UP_S = 10.0
"""Realtime clock: a stall up to this long (s) is caught up tick by tick; a longer one (a suspended machine) is
not."""
CATCH_UP_BURST_S = 0.05
CATCH_UP_PAUSE_S = 0.001
"""Realtime clock: ticks missed in a stall are stepped back to back, at most this many seconds of them (s) before
the loop sleeps this long (s): under SCHED_FIFO a loop that never sleeps holds its CPU from every normal process,
and still catches up many times faster than the clock runs."""
DRIVE_PRIORITY = 10
"""SCHED_FIFO priority of a simulated drive's loop where the OS permits it (below the bus worker's)."""


@dataclass(frozen=True)
class ControllerTiming:
    """How the controller keeps time.

    rate_hz: control and sampling rate (Hz); clock: lockstep or realtime;
    jitter: sampling-instant jitter as a fraction of the control period
    (uniform in +-jitter; the feedback timestamp reports the true instant);
    seed: random seed of the jitter;
    pacing_cpu: realtime: the CPU the instrument's pacing loop keeps to itself, which the controller keeps off
    (None: ``bodebench.drivers.scheduling.pacing_cpu()``).
    """

    rate_hz: float
    clock: str = "lockstep"
    jitter: float = 0.0
    seed: int = 0
    pacing_cpu: int | None = None

    def __post_init__(self) -> None:
        if self.clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, got {self.clock!r}")
        if not self.rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {self.rate_hz}")
        if not 0 <= self.jitter < 0.5:
            raise ValueError(f"jitter must be in [0, 0.5), got {self.jitter}")


@dataclass(frozen=True)
class FeedbackSensing:
    """How the simulated drive's sensors corrupt what it reports, on every feedback channel.

    noise: standard deviation of additive white Gaussian noise (the channel's units); quantization: the
    least significant bit a value is rounded to after the noise (the channel's units, 0 = none); seed: of the
    noise, its own stream apart from the jitter's; hum, hum_hz: a sine of this amplitude (the channel's units) and
    frequency (Hz, on the drive's clock) added before the noise, as mains pick-up on a sensor line.
    """

    noise: float = 0.0
    quantization: float = 0.0
    seed: int = 0
    hum: float = 0.0
    hum_hz: float = 50.0

    def __post_init__(self) -> None:
        for name in ("noise", "quantization", "hum", "hum_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")

    @property
    def any(self) -> bool:
        """True when the sensors corrupt anything."""
        return self.noise > 0.0 or self.quantization > 0.0 or self.hum > 0.0

    def rng(self) -> np.random.Generator:
        """A new generator of the noise, from ``seed`` (a stream apart from the jitter's)."""
        return np.random.default_rng([self.seed, 1])

    def apply(self, value: float, rng: np.random.Generator, time_s: float = 0.0) -> float:
        """The value as the sensor reports it at drive time ``time_s`` (s)."""
        if self.hum > 0.0:
            value += self.hum * math.sin(2.0 * math.pi * self.hum_hz * time_s)
        if self.noise > 0.0:
            value += self.noise * float(rng.standard_normal())
        if self.quantization > 0.0:
            value = self.quantization * round(value / self.quantization)
        return value


class SimulatedController:
    """A servo controller around ``plant`` answering in ``layout``'s frames.

    Feedback channels are the plant's outputs of the same name, and
    ``setpoint_echo``, the setpoint applied over the period just ended.
    Disabled (after a disable frame, and from the start when the layout has an
    enable frame), the plant gets a zero setpoint. With ``layout.drive_watchdog_s``
    the drive's watchdog (drivers/PROTOCOL.md) zeroes the setpoint and disables
    the drive when no valid setpoint or heartbeat has come for that long (wall
    clock, checked by ``serve``). Each change of state (enabled, disabled,
    watchdog trip, setpoint zeroed) is passed to ``on_event`` as one line of text.
    """

    def __init__(self, plant: Plant, layout: Layout, timing: ControllerTiming,
                 faults: ValueFaults | None = None, on_event: Callable[[str], None] | None = None,
                 sensing: FeedbackSensing | None = None) -> None:
        self.plant = plant
        self.faults = faults
        self.sensing = sensing if sensing is not None and sensing.any else None
        self._sensing_rng = sensing.rng() if sensing is not None else None
        self.layout = layout
        self.timing = timing
        self.period = 1.0 / timing.rate_hz
        for name in layout.channels:
            if name != SETPOINT_ECHO and name not in plant.output_names:
                raise ValueError(f"feedback channel {name!r} is not an output of the plant "
                                 f"({', '.join(plant.output_names)}) nor {SETPOINT_ECHO!r}")
        self._sources = [(m, [(name, self._source(name)) for name in m.signal_names], crc_byte(m))
                         for m in layout.feedback]
        self._counter_modulus = layout.counter_modulus or 1  # looked up once: every sample needs them
        self._timestamp_modulus = layout.timestamp_modulus or 1 << 32
        self.state = plant.initial_state()
        # step a scratch copy once now, so the compiled integrator is ready before the first setpoint arrives
        plant.run_held(plant.initial_state(), np.zeros(1), self.period)
        self.tick_count = 0      # control periods stepped
        self.time = 0.0          # controller time at the last sample (s)
        self.setpoint = 0.0      # latest setpoint received
        self.applied = 0.0       # setpoint applied over the last period
        self.enabled = layout.enable is None
        self.setpoints_received = 0
        self.enable_frames = 0
        self.disable_frames = 0
        self.watchdog_trips = 0
        self.unsent = 0  # feedback frames the line did not take in time (lost)
        self.on_event = on_event or (lambda text: None)
        self._last_valid = time.monotonic()  # wall time of the last valid setpoint or heartbeat
        self._rng = np.random.default_rng(timing.seed)
        self._u = np.zeros(1)
        self._lock = threading.Lock()

    def _source(self, name: str) -> int:
        """Index into the plant's outputs, or -1 for the echoed setpoint / counter / timestamp."""
        return self.plant.output_names.index(name) if name in self.plant.output_names else -1

    @staticmethod
    def _matches(message: Codec | None, frame: Frame) -> bool:
        return (message is not None and frame.id == message.id and frame.extended == message.extended
                and (message.data is None or bytes(frame.data) == bytes(message.data)))

    def handle(self, frame: Frame) -> list[Frame]:
        """Take one received frame; in lockstep a setpoint is answered with the next sample's frames."""
        with self._lock:
            if frame.id == self.layout.setpoint.id and frame.extended == self.layout.setpoint.extended:
                try:
                    value = self.layout.setpoint.decode(bytes(frame.data))["setpoint"]
                except LayoutError:  # not a valid setpoint: ignored, and it does not feed the watchdog
                    return []
                if not math.isfinite(value):
                    value = 0.0
                if value == 0.0 and self.setpoint != 0.0:
                    self.on_event(f"setpoint zeroed (was {self.setpoint:g})")
                self.setpoint = value
                self.setpoints_received += 1
                self._last_valid = time.monotonic()
                if self.timing.clock == "lockstep":
                    return self._step()
            elif self._matches(self.layout.heartbeat, frame):
                self._last_valid = time.monotonic()
            elif self._matches(self.layout.disable, frame):
                if self.enabled:
                    self.on_event("disabled (disable frame)")
                self.enabled = False
                self.disable_frames += 1
            elif self._matches(self.layout.enable, frame):
                if not self.enabled:
                    self.on_event("enabled (enable frame)")
                self.enabled = True
                self.enable_frames += 1
                self._last_valid = time.monotonic()  # a drive just enabled waits its watchdog time for setpoints
            return []

    def check_watchdog(self) -> bool:
        """The drive's watchdog: after ``layout.drive_watchdog_s`` without a valid setpoint or heartbeat, zero the
        setpoint and disable (a layout without an enable frame cannot be re-enabled: it is zeroed only). True when
        it tripped now."""
        limit = self.layout.drive_watchdog_s
        if not limit:
            return False
        with self._lock:
            armed = self.setpoint != 0.0 or (self.enabled and self.layout.enable is not None)
            silent = time.monotonic() - self._last_valid
            if not armed or silent <= limit:
                return False
            self.watchdog_trips += 1
            self.on_event(f"watchdog trip: no valid setpoint or heartbeat for {silent:.3f} s "
                          f"(drive_watchdog_s = {limit:g} s)")
            if self.setpoint != 0.0:
                self.on_event(f"setpoint zeroed (was {self.setpoint:g})")
            self.setpoint = self.applied = 0.0  # the output stage holds zero from the trip on
            if self.layout.enable is not None and self.enabled:
                self.enabled = False
                self.on_event("disabled (watchdog)")
            return True

    def tick(self) -> list[Frame]:
        """One control period with the latest setpoint (the realtime clock calls this at the control rate)."""
        with self._lock:
            return self._step()

    def advance(self) -> np.ndarray:
        """One control period: the latest setpoint (zero while disabled) held on the plant until the next sampling
        instant (jittered where the timing says so); the plant's outputs there. Not locked: ``tick`` and
        ``handle`` lock around it."""
        dt = self.period
        if self.timing.jitter:
            # the sampling instant of this period moves; the next one is referenced to the nominal grid
            nominal_next = (self.tick_count + 1) * self.period
            target = nominal_next + self.timing.jitter * self.period * self._rng.uniform(-1.0, 1.0)
            dt = target - self.time
        if self.enabled and self.faults is not None and self.faults.disabled(self.time):
            self.enabled = False
            self.on_event("disabled (a fault the drive does not report)")
        self.applied = self.setpoint if self.enabled else 0.0
        self._u[0] = self.applied
        y = self.plant.run_held(self.state, self._u, dt)[0]
        self.time += dt
        self.tick_count += 1
        return y

    def sensed(self, y: np.ndarray, name: str) -> float:
        """What the drive's sensor reports of channel ``name`` (a plant output, or ``setpoint_echo``) at outputs
        ``y``: noise and quantization applied."""
        index = self._source(name)
        value = float(y[index]) if index >= 0 else self.applied
        if self.sensing is not None and self._sensing_rng is not None:
            value = self.sensing.apply(value, self._sensing_rng, self.time)
        return value

    def _step(self) -> list[Frame]:
        y = self.advance()
        if self.faults is not None:
            if self.faults.silent(self.time):
                return []
            if self.faults.bus_off(self.time):
                return [Frame(0, b"", False, time.time(), is_error=True)]
        return self._feedback(y)

    def _feedback(self, y: np.ndarray) -> list[Frame]:
        frames = []
        timestamp_us = int(round(self.time * 1e6)) % self._timestamp_modulus
        faults = self.faults
        sensing, sensing_rng = self.sensing, self._sensing_rng  # both set when the sensors corrupt values
        counter = self.tick_count if faults is None else faults.counter(self.tick_count)
        for message, sources, crc_at in self._sources:
            values: dict[str, float] = {}
            for name, index in sources:
                if name == "counter":
                    values[name] = counter % self._counter_modulus
                elif name == "timestamp_us":
                    values[name] = timestamp_us
                elif name == CRC:
                    values[name] = 0
                else:
                    value = float(y[index]) if index >= 0 else self.applied
                    if sensing is not None and sensing_rng is not None:
                        value = sensing.apply(value, sensing_rng, self.time)
                    values[name] = value if faults is None else faults.value(name, value, self.time)
            try:
                payload = message.encode(values)
            except LayoutError:  # a value its integer signal cannot carry: the drive sends its saturated raw value
                payload = message.encode({k: _saturate(message, k, v) for k, v in values.items()})
            if crc_at is not None:
                payload = seal(payload, crc_at)
            frames.append(Frame(message.id, payload, message.extended, time.time()))
        return frames

    def _transmit(self, port: FramePort, frame: Frame) -> None:
        """Send a feedback frame; one the line will not take in time is lost (counted in ``unsent``), as a drive's
        full transmit buffer loses it: the drive goes on."""
        try:
            port.send(frame)
        except DriverTimeoutError:
            self.unsent += 1

    def serve(self, port: FramePort, stop: threading.Event, poll_s: float = 0.05) -> None:
        """Answer on ``port`` until ``stop`` is set: lockstep answers each setpoint; realtime ticks on the wall
        clock."""
        if self.layout.drive_watchdog_s:
            poll_s = min(poll_s, self.layout.drive_watchdog_s / 20)
        if self.timing.clock == "lockstep":
            # a drive answers on its own hardware whatever else the bench PC runs: where permitted, this loop
            # preempts normal processes when a frame wakes it (it blocks on the port otherwise, so it takes only
            # the time its answers take)
            request_fifo(DRIVE_PRIORITY)
            while not stop.is_set():
                for frame in port.recv(poll_s):
                    for out in self.handle(frame):
                        self._transmit(port, out)
                self.check_watchdog()
            return
        # a drive ticks on its own hardware clock: where permitted, this thread gets realtime priority too (below
        # the instrument's pacing loop) so that a busy bench PC does not slow the simulated drive
        lower_timer_slack()
        request_fifo(DRIVE_PRIORITY)
        cpu = pacing_cpu(self.timing.pacing_cpu)
        if cpu is not None:
            keep_to(os.sched_getaffinity(0) - {cpu})
        next_tick = time.perf_counter() + self.period
        burst = 0  # ticks stepped back to back since the loop last slept
        most = max(1, math.ceil(CATCH_UP_BURST_S / self.period))
        while not stop.is_set():
            for frame in port.recv(0.0):
                self.handle(frame)
            self.check_watchdog()
            wait = next_tick - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
                burst = 0
            else:
                burst += 1
                if burst >= most:  # catching up: a realtime-priority loop must sleep now and then to let others run
                    time.sleep(CATCH_UP_PAUSE_S)
                    burst = 0
            for out in self.tick():
                self._transmit(port, out)
            next_tick += self.period
            # a drive's clock does not stop when its host is busy: ticks missed in a stall are stepped at once
            # (the setpoint held), so the counter keeps to the wall clock; only after a suspension longer than
            # CATCH_UP_S does the drive resume from now, its timeline shifted
            if time.perf_counter() - next_tick > CATCH_UP_S:
                next_tick = time.perf_counter() + self.period


def _saturate(message: Codec, name: str, value: float) -> float:
    """The nearest value an integer signal of a ``Message`` can carry (NaN reads 0), as a drive's firmware would
    clamp it; other values and codecs are left as they are."""
    signal = message.signal(name) if isinstance(message, Message) else None
    limits = signal.raw_range if signal is not None else None
    if signal is None or limits is None:
        return value
    if math.isnan(value):
        return 0.0
    lo = limits[0] * signal.scale + signal.offset
    hi = limits[1] * signal.scale + signal.offset
    lo, hi = min(lo, hi), max(lo, hi)
    return min(max(value, lo), hi)
