"""Configuration tables of a bench session: [bench], [can], [serial], [frames], [safety], [simulator].

A config with a ``[bench]`` table describes a drive on a bus: the session
drives it with paced setpoints. With a ``[simulator]`` table too, the drive is
the simulated servo controller around ``[plant]``. The tables are registered
in ``instrument.config.TABLES``; the cross-table checks run once per case.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

if TYPE_CHECKING:
    from bodebench.drivers.layout import Layout
    from bodebench.io.config import CaseConfig

TRANSPORTS = ("can", "serial")
CLOCKS = ("lockstep", "realtime")
TIMEBASES = ("counter", "timestamp", "receive")
MIN_SAMPLES_PER_PERIOD = 8  # of the highest harmonic measured
MIN_FREQUENCY_HZ = 1e-3
"""Lowest frequency a bench sweeps: a period of 1000 s, so that a point (a ramp of whole periods, then the periods
the stopping rule needs) takes more than an hour. No drive is swept slower on a bench; a smaller value is a typing
error (a frequency in kHz, a wrong exponent)."""


class CaseCheckError(ValueError):
    """A cross-table problem at a dotted key (the loader prefixes the source)."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"{key}: {problem}")
        self.key = key
        self.problem = problem


@dataclass(frozen=True)
class BenchConfig:
    """How the session drives the bench."""

    TABLE_OPTIONAL = True

    transport: str = field(metadata={"choices": TRANSPORTS, "doc": "bus to the drive: can or serial"})
    rate_hz: float = field(metadata={"min": 0, "min_exclusive": True,
                                     "doc": "setpoint and feedback sample rate of the drive controller, Hz"})
    clock: str = field(default="lockstep", metadata={
        "choices": CLOCKS, "doc": "lockstep: one controller period per setpoint (simulated drives); realtime"})
    timebase: str = field(default="counter", metadata={
        "choices": TIMEBASES,
        "doc": "sample times from the feedback counter, the controller's timestamp, or the host's receive time"})
    output_channels: tuple[str, ...] = field(default=("position",), metadata={
        "non_empty": True, "unique": True, "doc": "feedback channels measured"})
    reference_channel: str = field(default="", metadata={
        "doc": "two-channel mode: gain and phase relative to this channel (e.g. setpoint_echo); "
               "empty: relative to the commanded sine"})
    ramp_in_periods: int = field(default=2, metadata={"min": 0, "doc": "amplitude ramp before analysis, periods"})
    ramp_out_periods: int = field(default=1, metadata={"min": 0, "doc": "amplitude ramp after a point, periods"})
    worker: str = field(default="auto", metadata={
        "choices": ("auto", "thread", "process"),
        "doc": "where pacing and bus I/O run: auto = own process on the realtime clock, thread in lockstep"})
    batch_ms: float = field(default=10.0, metadata={"min": 0, "min_exclusive": True,
                                                    "doc": "samples are handed to the analysis this often, ms"})
    reply_timeout_s: float = field(default=0.05, metadata={
        "min": 0, "min_exclusive": True,
        "doc": "lockstep: longest wait for a setpoint's reply (8 typical round trips, at least 2 ms, are waited), s"})
    pacing_cpu: int | None = field(default=None, metadata={
        "min": 0, "doc": "realtime: the CPU the bus worker keeps to itself (e.g. one isolated with isolcpus); "
                         "default: the last CPU the process may use"})


@dataclass(frozen=True)
class CanConfig:
    """python-can bus: any interface; options are passed to can.Bus as they are."""

    TABLE_OPTIONAL = True

    interface: str = field(metadata={"doc": "python-can interface: socketcan, pcan, kvaser, vector, slcan, "
                                            "virtual, udp_multicast, ..."})
    channel: str = field(default="", metadata={"doc": "interface channel; empty with [simulator]: "
                                                      "the simulator's"})
    bitrate: int | None = field(default=None, metadata={"min": 1, "doc": "bit/s"})
    options: dict = field(default_factory=dict, metadata={"doc": "further can.Bus keyword arguments"})


@dataclass(frozen=True)
class SerialConfig:
    """Serial line (pyserial)."""

    TABLE_OPTIONAL = True

    port: str = field(default="", metadata={"doc": "tty path or pyserial URL; empty with [simulator]: the "
                                                   "simulator's pseudo-terminal"})
    baudrate: int = field(default=1_000_000, metadata={"min": 1, "doc": "bit/s"})
    framing: str = field(default="binary", metadata={"choices": ("binary", "ascii"),
                                                     "doc": "binary (sync, length, CRC-16) or ASCII lines"})


@dataclass(frozen=True)
class FramesConfig:
    """Frame layouts (drivers/PROTOCOL.md), in TOML or by name from a DBC file; absent: the default layout."""

    TABLE_OPTIONAL = True

    dbc: str = field(default="", metadata={"doc": "DBC file (relative to the config file)"})
    setpoint: dict = field(default_factory=dict)
    feedback: tuple[dict, ...] = ()
    enable: dict | None = None
    disable: dict | None = None
    heartbeat: dict | None = None
    heartbeat_period_s: float = field(default=0.0, metadata={"min": 0})
    drive_watchdog_s: float = field(default=0.0, metadata={
        "min": 0, "doc": "the drive zeroes and disables itself after this long without a valid setpoint or "
                         "heartbeat, s (0: it has no watchdog)"})


@dataclass(frozen=True)
class SafetyConfig:
    """Limits that protect the drive; any trip drives the setpoint to zero and disables the drive."""

    TABLE_OPTIONAL = True

    max_amplitude: float = field(metadata={"min": 0, "min_exclusive": True,
                                           "doc": "largest |setpoint| ever sent, setpoint units"})
    max_rate: float | None = field(default=None, metadata={"min": 0, "min_exclusive": True,
                                                           "doc": "setpoint slew limit, setpoint units/s"})
    feedback_limits: dict = field(default_factory=dict, metadata={
        "doc": "channel = [low, high]: a feedback sample outside aborts the sweep"})
    watchdog_s: float = field(default=0.5, metadata={"min": 0, "min_exclusive": True,
                                                     "doc": "no feedback for this long aborts, s"})

    def validate(self, where: Callable[[str], str]) -> None:
        from bodebench.io.config import FieldError

        for channel, window in self.feedback_limits.items():
            ok = (isinstance(window, list) and len(window) == 2
                  and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                          for v in window) and window[0] < window[1])
            if not ok:
                raise FieldError("feedback_limits", f"{channel}: expected [low, high] with low < high, "
                                                    f"got {window!r}")


@dataclass(frozen=True)
class SimulatorConfig:
    """The simulated servo controller around [plant], standing in for the drive."""

    TABLE_OPTIONAL = True

    jitter: float = field(default=0.0, metadata={"min": 0, "max": 0.5, "max_exclusive": True,
                                                 "doc": "sampling-instant jitter, fraction of a period"})
    noise: float = field(default=0.0, metadata={"min": 0, "doc": "standard deviation of white noise added to "
                                                                 "every feedback channel, the channel's units"})
    quantization: float = field(default=0.0, metadata={"min": 0, "doc": "least significant bit of every feedback "
                                                                        "channel, the channel's units (0: none)"})
    seed: int = field(default=0, metadata={"min": 0, "doc": "random seed of the jitter and the noise"})
    faults: dict = field(default_factory=dict, metadata={"doc": "fault injection (sim/faults.py FaultConfig)"})

    def validate(self, where: Callable[[str], str]) -> None:
        from bodebench.io.config import FieldError
        from bodebench.sim.faults import FaultConfig

        try:
            FaultConfig.from_mapping(self.faults)
        except ValueError as exc:
            raise FieldError("faults", str(exc)) from None


BENCH_TABLES: dict[str, type] = {
    "bench": BenchConfig,
    "can": CanConfig,
    "serial": SerialConfig,
    "frames": FramesConfig,
    "safety": SafetyConfig,
    "simulator": SimulatorConfig,
}


def frames_mapping(frames: FramesConfig) -> dict[str, Any]:
    """The [frames] table as the mapping drivers.layout reads."""
    out: dict[str, Any] = {}
    if frames.dbc:
        out["dbc"] = frames.dbc
    if frames.setpoint:
        out["setpoint"] = frames.setpoint
    if frames.feedback:
        out["feedback"] = list(frames.feedback)
    for name in ("enable", "disable", "heartbeat"):
        value = getattr(frames, name)
        if value is not None:
            out[name] = value
    if frames.heartbeat_period_s:
        out["heartbeat_period_s"] = frames.heartbeat_period_s
    if frames.drive_watchdog_s:
        out["drive_watchdog_s"] = frames.drive_watchdog_s
    return out


def build_layout(frames: FramesConfig | None, source: str) -> "Layout":
    """The frame layout a case uses (default layout without [frames]); raises LayoutError."""
    from bodebench.drivers.layout import Layout, default_layout

    if frames is None:
        return default_layout()
    mapping = frames_mapping(frames)
    if frames.dbc:
        dbc = Path(frames.dbc)
        if not dbc.is_absolute():
            dbc = Path(source).parent / dbc
        mapping["dbc"] = str(dbc)
    return Layout.from_mapping(mapping)


def check_bench_case(case: "CaseConfig", key: Callable[[str, str], str], source: str) -> None:
    """Cross-table checks of a bench case; raises CaseCheckError at the dotted key at fault."""
    tables = case.tables
    bench: BenchConfig | None = tables.get("bench")
    if bench is None:
        for name in ("can", "serial", "frames", "safety", "simulator"):
            if tables.get(name) is not None:
                raise CaseCheckError(name, "needs a [bench] table")
        return
    link = tables.get(bench.transport)
    if link is None:
        raise CaseCheckError(key("bench", "transport"), f'"{bench.transport}" needs a [{bench.transport}] table')
    simulated = tables.get("simulator") is not None
    if isinstance(link, CanConfig) and not link.channel and not simulated:
        raise CaseCheckError(key("can", "channel"), "missing (only a [simulator] provides its own)")
    if isinstance(link, SerialConfig) and not link.port and not simulated:
        raise CaseCheckError(key("serial", "port"), "missing (only a [simulator] provides its own)")
    cpus = os.cpu_count() or 1
    if bench.clock == "realtime" and bench.pacing_cpu is not None and bench.pacing_cpu >= cpus:
        raise CaseCheckError(key("bench", "pacing_cpu"),
                             f"CPU {bench.pacing_cpu} does not exist on this machine ({cpus} CPUs, numbered from 0)")
    if bench.clock == "lockstep" and bench.timebase == "receive":
        raise CaseCheckError(key("bench", "timebase"), "receive times mean nothing on the lockstep clock")
    safety: SafetyConfig | None = tables.get("safety")
    if safety is None:
        raise CaseCheckError("safety", "a bench config needs a [safety] table (at least max_amplitude)")
    amplitude = case.excitation.amplitude
    if amplitude > safety.max_amplitude:
        raise CaseCheckError(key("excitation", "amplitude"),
                             f"{amplitude:g} exceeds safety.max_amplitude ({safety.max_amplitude:g})")
    top = max(case.analysis.harmonics)
    for i, f in enumerate(case.excitation.frequencies_hz):
        if f < MIN_FREQUENCY_HZ:
            raise CaseCheckError(f"{key('excitation', 'frequencies_hz')}[{i}]",
                                 f"{f:g} Hz is below {MIN_FREQUENCY_HZ:g} Hz (a period of 1000 s): a point would "
                                 "take hours")
        if top * f * MIN_SAMPLES_PER_PERIOD > bench.rate_hz:
            raise CaseCheckError(f"{key('excitation', 'frequencies_hz')}[{i}]",
                                 f"{f:g} Hz: harmonic {top} needs at least {MIN_SAMPLES_PER_PERIOD} samples a "
                                 f"period at bench.rate_hz = {bench.rate_hz:g} (at most "
                                 f"{bench.rate_hz / (MIN_SAMPLES_PER_PERIOD * top):g} Hz)")
        if safety.max_rate is not None and 2 * math.pi * f * amplitude > safety.max_rate:
            raise CaseCheckError(f"{key('excitation', 'frequencies_hz')}[{i}]",
                                 f"{f:g} Hz: the sine's slew 2*pi*f*A = {2 * math.pi * f * amplitude:g} exceeds "
                                 f"safety.max_rate ({safety.max_rate:g})")
    from bodebench.drivers.errors import LayoutError

    try:
        layout = build_layout(tables.get("frames"), source)
        framing = tables["serial"].framing if bench.transport == "serial" else ""
        layout.validate(f"serial-{framing}" if framing else "can")
    except LayoutError as exc:
        text = str(exc)
        head, _, problem = text.partition(": ")
        if head.startswith("frames") and problem:
            raise CaseCheckError(head, problem) from None
        absent = "" if tables.get("frames") is not None else " (the default layout: give a [frames] table)"
        raise CaseCheckError("frames", text + absent) from None
    except OSError as exc:
        raise CaseCheckError(key("frames", "dbc"), f"cannot read: {exc.strerror or exc}") from None
    channels = set(layout.channels)
    for name in (*bench.output_channels, *( [bench.reference_channel] if bench.reference_channel else [])):
        if name not in channels:
            raise CaseCheckError(key("bench", "output_channels" if name in bench.output_channels
                                     else "reference_channel"),
                                 f"{name!r} is not a feedback channel of the frame layout "
                                 f"({', '.join(layout.channels)})")
    for name in safety.feedback_limits:
        if name not in channels:
            raise CaseCheckError(key("safety", "feedback_limits"), f"{name!r} is not a feedback channel")
    if bench.reference_channel and 1 not in case.analysis.harmonics:
        raise CaseCheckError(key("analysis", "harmonics"), "two-channel mode (bench.reference_channel) needs "
                                                           "harmonic 1")
    if bench.timebase == "counter" and not layout.has_counter:
        raise CaseCheckError(key("bench", "timebase"), "counter: the feedback frames carry no counter")
    if bench.timebase == "timestamp" and not layout.has_timestamp:
        raise CaseCheckError(key("bench", "timebase"), "timestamp: the feedback frames carry no timestamp_us")
