"""``bodebench check``: what a configuration will do, read off it without opening any bus.

For each case: the frequency plan (amplitude, samples a period, the ramp and settle periods, the fewest and the most
periods a point integrates, and the time that takes), what the loader noted about the plan (folds, moved frequencies,
the setpoint's resolution) and the disturbance lines near a measured harmonic; then what goes to the drive, in order,
on start and on every way out (the frames of the layout, the serial bytes, or the CANopen sequence), built with the
codecs, framing and constants the drivers use; and the safety limits.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np

from bodebench.core.autointegration import MIN_BUDGET_PERIODS, Autointegrator, period_budget, point_seconds
from bodebench.core.benchgrid import nearest_line
from bodebench.drivers.codec import COUNTER, SETPOINT, Codec
from bodebench.drivers.dbc import signal_specs
from bodebench.io.config import CaseConfig, ExperimentConfig
from bodebench.io.tables import AnalysisConfig

__all__ = ["check_lines", "fewest_periods"]

INDENT = "  "
EXIT_HEADING = ("sent to the drive on every way out (end of the sweep, a safety trip, a bus or drive error, Ctrl-C, "
                "a signal):")


def fewest_periods(analysis: AnalysisConfig, frequency_hz: float, rate_hz: float) -> int:
    """Periods a point integrates at least under ``analysis`` (its rule, tolerance, skipped periods, harmonics): the
    periods the bench's own sampler takes to stop on a steady, noise-free response at ``rate_hz`` samples a second
    (skipped periods included), at most ``analysis.max_periods``."""
    sampler = Autointegrator(frequency_hz, 1.0, ("y",), analysis)
    per_period = max(1, math.ceil(rate_hz / frequency_hz))
    start = 0
    while not sampler.done and sampler.periods < analysis.max_periods:
        t = np.arange(start, start + per_period) / rate_hz
        sampler.feed(t, (0.5 * np.sin(2 * math.pi * frequency_hz * t) + 0.1 * np.cos(2 * math.pi * frequency_hz * t)
                         )[:, None])
        start += per_period
    return min(sampler.periods, analysis.max_periods)


def _number(x: float) -> str:
    """A number as written in a configuration: shortest form, every digit kept."""
    return f"{x:.12g}"


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.3g} s"
    if seconds < 7200:
        return f"{seconds / 60:.3g} min"
    return f"{seconds / 3600:.3g} h"


def check_lines(config: ExperimentConfig) -> Iterator[str]:
    """What ``bodebench check`` prints for ``config``, line by line."""
    yield f"{config.path}: {config.title}: {len(config.cases)} case{'s' if len(config.cases) > 1 else ''}, valid"
    for case in config.cases:
        yield ""
        yield from _case_lines(case)


def _case_lines(case: CaseConfig) -> Iterator[str]:
    excitation, analysis, bench = case.excitation, case.analysis, case.bench
    rate = bench.rate_hz if bench is not None else 0.0
    if bench is None:
        yield (f"case {case.name}: offline experiment, {case.plant.model if case.plant else '?'} plant simulated at "
               f"{analysis.steps_per_period} steps a period; nothing is sent to any drive")
    else:
        yield f"case {case.name}: {_where(case)}, {bench.clock} clock at {_number(rate)} Hz, timebase {bench.timebase}"
    harmonics = ", ".join(str(k) for k in analysis.harmonics)
    seconds = point_seconds(analysis, on_bench=bench is not None)
    timed = "" if seconds is None else f", and at most {seconds:g} s of them (never fewer than {MIN_BUDGET_PERIODS})"
    yield (f"plan: {len(excitation.frequencies_hz)} frequencies, harmonics {harmonics}, criterion {analysis.criterion}"
           f", tolerance {analysis.tolerance_percent:g} %, skip_periods {analysis.skip_periods}, at most "
           f"{analysis.max_periods} periods a point{timed}")
    if bench is not None and analysis.measurement != "output":
        ratios = "; ".join(case.formed().formulas())
        yield f"measures: {ratios}, each period's ratio of the fundamentals, averaged ({analysis.measurement})"
    ramp_in = bench.ramp_in_periods if bench is not None else 0
    ramp_out = bench.ramp_out_periods if bench is not None else 0
    top = max(excitation.frequencies_hz)
    fewest = fewest_periods(analysis, top, rate if rate else top * analysis.steps_per_period)
    yield (f"{INDENT}periods: at least {fewest} (a steady response without noise, where the rule stops first), at most "
           f"the point's budget; time: {'drive' if bench is not None else 'simulated'} time at that many periods")
    header = (f"{'f Hz':>12} {'amplitude':>12} {'samples/period':>14} {'ramp in':>7} {'settle':>6} "
              f"{'periods':>13} {'ramp out':>8} {'time':>21}")
    yield INDENT + header
    least = most = 0.0
    for f in excitation.frequencies_hz:
        settle = excitation.settle_at(f)
        per_period = rate / f if bench is not None else float(analysis.steps_per_period)
        extra = ramp_in + settle + ramp_out
        budget = period_budget(analysis, f, on_bench=bench is not None)
        low, high = (extra + fewest) / f, (extra + budget) / f
        least, most = least + low, most + high
        yield INDENT + (f"{_number(f):>12} {_number(excitation.amplitude_at(f)):>12} {per_period:>14.4g} "
                        f"{ramp_in:>7} {settle:>6} {f'{fewest}-{budget}':>13} {ramp_out:>8} "
                        f"{_duration(low) + ' - ' + _duration(high):>21}")
    yield f"{INDENT}sweep: at least {_duration(least)}, at most {_duration(most)}"
    adaptive = excitation.adaptive
    if adaptive is not None:
        spend = f", or {_duration(adaptive.budget_s)} of bench time" if adaptive.budget_s is not None else ""
        first = "the overview's lines, then " if adaptive.from_overview else ""
        curve = (f"the curve to {adaptive.curve_gain_db:g} dB, {adaptive.curve_phase_deg:g} deg; " if adaptive.curve
                 else "")
        yield (f"{INDENT}adaptive: these first, then frequencies added where {first}the points call for them: "
               f"{', '.join(adaptive.figures) or 'no figure'} to {adaptive.frequency_percent:g} % (frequencies), "
               f"{adaptive.gain_db:g} dB, {adaptive.phase_deg:g} deg; {curve}up to {adaptive.max_points} "
               f"frequencies{spend}")
    for note in case.plan_notes:
        yield f"{INDENT}note: {note}"
    yield from _overview_lines(case)
    yield from _disturbance_lines(case, fewest)
    yield from _folds(case)
    if bench is not None:
        yield from _drive_lines(case)
        yield from _safety_lines(case)


def _overview_lines(case: CaseConfig) -> Iterator[str]:
    """The overview's multisine ([overview]), where the case has one: its lines, period, levels and slew."""
    if case.overview is None:
        return
    design = case.multisine()
    frequencies = design.frequencies_hz
    budget = case.overview.max_periods
    yield (f"overview: {len(design.lines)} odd lines from {frequencies[0]:.4g} to {frequencies[-1]:.4g} Hz, a period "
           f"of {design.samples} samples ({_duration(design.period_s)} at {_number(design.rate_hz)} Hz), at most "
           f"{budget} periods ({_duration(budget * design.period_s)})")
    yield (f"{INDENT}peak {design.peak:.4g}, rms {design.rms:.4g}, crest factor {design.crest_factor:.3g}, each line "
           f"{design.line_amplitude:.4g}, steepest slew {design.peak_slew:.4g} units/s")


def _where(case: CaseConfig) -> str:
    assert case.bench is not None
    transport = case.bench.transport
    if transport == "serial" and case.serial is not None:
        port = case.serial.port or "the simulator's pseudo-terminal"
        return f"serial {port} at {case.serial.baudrate} bit/s, {case.serial.framing} framing"
    assert case.can is not None
    channel = case.can.channel or "of the simulated drive"
    bus = (f"python-can {case.can.interface or '(python-can configuration)'} channel {channel}"
           + (f" at {case.can.bitrate} bit/s" if case.can.bitrate else "") + (", CAN FD" if case.can.fd else ""))
    if transport == "canopen" and case.canopen is not None:
        return f"CANopen node {case.canopen.node_id} on {bus}"
    return f"CAN, {bus}"


def _disturbance_lines(case: CaseConfig, fewest: int) -> Iterator[str]:
    lines = case.disturbance_lines
    if case.bench is None:
        return
    if not lines:
        yield f"{INDENT}disturbance lines: none (analysis.disturbance_hz)"
        return
    yield f"{INDENT}disturbance lines: {', '.join(_number(d) for d in lines)} Hz (analysis.disturbance_hz)"
    for f in case.excitation.frequencies_hz:
        for k in case.analysis.harmonics:
            d = nearest_line(f, k, lines)
            gap = abs(d - k * f)
            needed = math.inf if gap == 0 else f / gap
            if needed > fewest:  # a point stopped before this many periods is flagged disturbed
                yield (f"{INDENT}note: {_number(f)} Hz harmonic {k} ({_number(k * f)} Hz) is {gap:.3g} Hz from the "
                       f"{_number(d)} Hz line: marked disturbed unless the point takes more than "
                       + ("any number of periods" if gap == 0 else f"{needed:.4g} periods")
                       + " (analysis.disturbances = \"move\" moves it off)")


def _folds(case: CaseConfig) -> Iterator[str]:
    """What the bench does with what its sample rate folds onto the measured harmonics (analysis.folds)."""
    if case.bench is None:
        return
    policy = case.analysis.fold_policy
    what = {"bound": "each point's interval carries a bound on what the sample rate folds onto it (its harmonics "
                     "taken to fall at least as 1/j^2, and as "
                     f"1/j^{_number(case.analysis.fold_decay)} in the tail a whole number of samples a period shows, "
                     "analysis.fold_decay), alias_limited where that alone exceeds the tolerance",
            "keep": "no bound on what the sample rate folds onto a harmonic (the notes above name exact folds)",
            "move": "frequencies moved so that every fold turns (the notes above say by how much)"}[policy]
    yield f"{INDENT}folds: {policy}: {what} (analysis.folds)"


def _payload(message: Codec, value: float) -> str:
    values = {name: 0.0 for name in message.signal_names}
    values[SETPOINT] = value
    return message.encode(values).hex(" ")


def _frame(message: Codec, data: bytes | None = None) -> str:
    payload = message.data if data is None else data
    return f"id 0x{message.id:X}{' (29-bit)' if message.extended else ''} data {bytes(payload or b'').hex(' ') or '-'}"


def _signals(message: Codec) -> str:
    return ", ".join(f"{s.name} ({s.length}-bit {'float' if s.is_float else 'signed' if s.signed else 'unsigned'} "
                     f"{'little' if s.byte_order == 'little_endian' else 'big'}-endian at bit {s.start}"
                     + (f", x {s.scale:g}" if s.scale != 1 else "") + (f" + {s.offset:g}" if s.offset else "") + ")"
                     for s in signal_specs(message))


def _drive_lines(case: CaseConfig) -> Iterator[str]:
    from bodebench.bench.worker import ZERO_SETPOINTS

    bench, layout, safety = case.on_bench.bench, case.on_bench.layout, case.on_bench.safety
    if bench.transport == "canopen":
        yield from _canopen_lines(case)
        return
    wire = _wire(case)
    setpoint = layout.setpoint
    counter = " (the counter bytes count the setpoints)" if COUNTER in setpoint.signal_names else ""
    yield "sent to the drive, on start:"
    step = 0

    def item(text: str) -> str:
        nonlocal step
        step += 1
        return f"{INDENT}{step}. {text}"

    if layout.enable is not None:
        yield item(f"enable: {_frame(layout.enable)}{wire(layout.enable, layout.enable.data or b'')}")
    else:
        yield item("no enable frame (the layout has none): the drive must be enabled by other means")
    if layout.heartbeat is not None:
        yield item(f"heartbeat: {_frame(layout.heartbeat)}{wire(layout.heartbeat, layout.heartbeat.data or b'')} every "
                   f"{layout.heartbeat_period_s:g} s until the session ends")
    yield item(f"setpoint at {_number(bench.rate_hz)} Hz: id 0x{setpoint.id:X}, {_signals(setpoint)}; each frequency's "
               f"sine ramped in over {bench.ramp_in_periods} periods and out over {bench.ramp_out_periods}")
    yield EXIT_HEADING
    step = 0
    if safety.max_rate is not None:
        yield item(f"the setpoint slewed to 0 at safety.max_rate = {safety.max_rate:g} units/s")
    zero = setpoint.encode({name: 0.0 for name in setpoint.signal_names})
    yield item(f"{ZERO_SETPOINTS} x setpoint 0: {_frame(setpoint, zero)}{counter}{wire(setpoint, zero)}")
    if layout.disable is not None:
        yield item(f"disable: {_frame(layout.disable)}{wire(layout.disable, layout.disable.data or b'')}")
    else:
        yield item("no disable frame (the layout has none): the drive is left at setpoint 0")
    if layout.heartbeat is not None:
        yield item("the heartbeat stops" + (f": the drive's own watchdog (frames.drive_watchdog_s = "
                                            f"{layout.drive_watchdog_s:g} s) then disables it" if
                                            layout.drive_watchdog_s else ""))


def _wire(case: CaseConfig) -> Callable[[Codec, bytes], str]:
    """How a frame is written on the line: the serial bytes, or nothing more on a CAN bus."""
    from bodebench.drivers.serial_framing import encode_ascii, encode_binary

    if case.serial is None or case.bench is None or case.bench.transport != "serial":
        return lambda message, data: ""
    framing = case.serial.framing

    def wire(message: Codec, data: bytes) -> str:
        if framing == "binary":
            return f"; on the line: {encode_binary(message.id, data).hex(' ')}"
        line = encode_ascii(message, None if message.data is not None else message.decode(data))
        return f"; on the line: {line.decode('ascii').strip()!r}"

    return wire


def _canopen_lines(case: CaseConfig) -> Iterator[str]:
    from canopen.nmt import NMT_COMMANDS

    from bodebench.bench.worker import ZERO_SETPOINTS
    from bodebench.drivers.canopen_link import (
        ABORT_CONNECTION,
        ANSWER_LIMIT,
        ANSWER_PROBES,
        ANSWER_QUANTILE,
        CONTROLWORD_OBJECT,
        HEARTBEAT_CONSUMER,
        HEARTBEAT_PRODUCER,
        HOST_HEARTBEAT_STATE,
        STATUSWORD,
        SYNC_COB_ID,
    )
    from bodebench.drivers.device_profile import Step

    setup, safety = case.canopen_setup, case.on_bench.safety
    assert setup is not None and case.bench is not None
    node = setup.node_id

    def nmt(state: str) -> str:
        return f"NMT {state.lower()}: id 0x000 data {NMT_COMMANDS[state]:02x} {node:02x}"

    def sdo(index: int, sub: int | None, value: str, what: str) -> str:
        where = f"0x{index:04X}" + (f":{sub:02X}" if sub is not None else "")
        return f"SDO write {where} = {value} ({what})"

    profile = setup.device_profile

    def control(step: Step) -> str:
        return sdo(CONTROLWORD_OBJECT, 0, f"0x{step.controlword:04X}", f"controlword: {step.name}") + \
            f", waited for in the statusword 0x{STATUSWORD:04X}"

    start = [nmt("PRE-OPERATIONAL")]
    if setup.heartbeat_ms:
        start.append(sdo(HEARTBEAT_PRODUCER, 0, str(setup.heartbeat_ms), "the drive's heartbeat period, ms"))
    device = profile.device
    start.append(f"wait for the {device}'s heartbeat (id 0x{0x700 + node:X}); read the statusword 0x{STATUSWORD:04X}"
                 + (f"; a {device} in fault: controlword 0, then {control(profile.reset)}" if setup.fault_reset
                    else f"; a {device} in fault is refused (canopen.fault_reset = false)")
                 + ("; a device under local control (statusword bit 4) is refused" if profile.local_bit else ""))
    for index, sub, value, what in setup.assumed:
        start.append(f"SDO read 0x{index:04X}:{sub:02X} ({what}): the scales assume {value}, a device that reads "
                     "otherwise is refused")
    if setup.host_heartbeat_ms:
        start.append(f"host heartbeat: id 0x{setup.host_heartbeat_cob_id:X} data {HOST_HEARTBEAT_STATE:02x} every "
                     f"{setup.host_heartbeat_ms} ms until the session ends")
        if profile.abort_connection:
            start.append(sdo(ABORT_CONNECTION, 0, str(setup.abort_connection), "abort connection option code, where "
                                                                               "the EDS has it; the old value read "
                                                                               "first"))
        start.append(sdo(HEARTBEAT_CONSUMER, None, f"0x{setup.consumer_value:08X}", f"a sub-entry watches node "
                     f"{setup.host_node_id} for {setup.drive_heartbeat_timeout_ms} ms; the old value read first"))
    else:
        start.append("no host heartbeat (canopen.host_heartbeat_ms = 0): the drive cannot tell that the host died")
    actual = ", ".join(f"{ref} as {name}" for name, ref, _ in setup.actual)
    start.append(f"PDO mapping over SDO: RPDO{setup.rpdo} (id 0x{setup.rpdo_cob_id:X}) = {setup.setpoint}; "
                 f"TPDO{setup.tpdo} (id 0x{setup.tpdo_cob_id:X}) = statusword 0x{STATUSWORD:04X}, {actual}; both "
                 "synchronous")
    if profile.device_mode is not None:
        index, value, what = profile.device_mode
        start.append(sdo(index, 0, str(value), what) + ", until it reads back")
    start.append(sdo(profile.mode_object, 0, str(profile.modes[setup.mode]), f"mode: {setup.mode}")
                 + f", until 0x{profile.mode_display:04X} shows it")
    start.append(sdo(setup.setpoint.index, setup.setpoint.subindex, "0", setup.setpoint.name))
    if setup.operating_point is not None:
        target, held = setup.operating_point
        start.append(sdo(target.index, target.subindex, f"{held} as read" if held is not None else "0",
                         f"{target.name}: the operating point, held while the offset is excited"))
    start.append(nmt("OPERATIONAL"))
    if setup.times_answers:
        start.append(f"{ANSWER_PROBES} x SYNC (id 0x{SYNC_COB_ID:X}) one at a time, each TPDO's answer timed: "
                     f"refused unless {ANSWER_QUANTILE:.0%} come within {ANSWER_LIMIT:.0%} of the "
                     f"{_number(setup.sync_period_s * 1e3)} ms between SYNCs (timebase sync on the realtime clock)")
    start += [control(step) for step in profile.enable]
    sync = (f", then SYNC (id 0x{SYNC_COB_ID:X})" if setup.sync == "produce" else " (SYNC from another node)")
    start.append(f"at {_number(case.bench.rate_hz)} Hz: RPDO{setup.rpdo} id 0x{setup.rpdo_cob_id:X} setpoint in counts "
                 f"of {setup.setpoint_scale:g} ({setup.setpoint.type}){sync}"
                 + (": after a gap in the TPDOs, one SYNC left out to check the answer time (sent late instead "
                    "where the drive watches its SYNC by 0x1006)" if setup.times_answers else ""))
    yield "sent to the drive, on start:"
    for i, text in enumerate(start, 1):
        yield f"{INDENT}{i}. {text}"
    out = []
    if safety.max_rate is not None:
        out.append(f"the setpoint slewed to 0 at safety.max_rate = {safety.max_rate:g} units/s")
    out.append(f"{ZERO_SETPOINTS} x setpoint 0: RPDO{setup.rpdo} id 0x{setup.rpdo_cob_id:X} data "
               f"{case.on_bench.layout.setpoint.encode({SETPOINT: 0.0}).hex(' ')}{sync}")
    out += [control(step) for step in profile.leave]
    if setup.host_heartbeat_ms:
        out.append(f"SDO write back 0x{HEARTBEAT_CONSUMER:04X}"
                   + (f" and 0x{ABORT_CONNECTION:04X}" if profile.abort_connection else "") + " as they were")
    out.append(nmt("PRE-OPERATIONAL"))
    if setup.host_heartbeat_ms:
        out.append("the host heartbeat stops")
    yield EXIT_HEADING
    for i, text in enumerate(out, 1):
        yield f"{INDENT}{i}. {text}"


def _safety_lines(case: CaseConfig) -> Iterator[str]:
    safety, bench, layout = case.on_bench.safety, case.on_bench.bench, case.on_bench.layout
    excitation = case.excitation
    amplitude, f_amp = max((excitation.amplitude_at(f), f) for f in excitation.frequencies_hz)
    slew, f_slew = max((2 * math.pi * f * excitation.amplitude_at(f), f) for f in excitation.frequencies_hz)
    yield "safety (any trip zeroes the setpoint and disables the drive, as above):"
    yield (f"{INDENT}max_amplitude {safety.max_amplitude:g}: largest |setpoint| ever sent (the plan's largest "
           f"amplitude: {amplitude:g} at {_number(f_amp)} Hz)")
    yield (f"{INDENT}max_rate " + (f"{safety.max_rate:g} units/s" if safety.max_rate is not None else "none")
           + f": setpoint slew limit (the plan's largest 2 pi f A: {slew:.4g} units/s at {_number(f_slew)} Hz)")
    for channel, (low, high) in safety.feedback_limits.items():
        yield f"{INDENT}feedback_limits.{channel} [{low:g}, {high:g}]: a sample outside stops the sweep"
    if not safety.feedback_limits:
        yield f"{INDENT}feedback_limits: none (no feedback channel is watched for its range)"
    yield f"{INDENT}watchdog_s {safety.watchdog_s:g}: no feedback for this long stops the sweep"
    if bench.transport == "canopen" and case.canopen is not None:
        yield (f"{INDENT}canopen.heartbeat_timeout_s {case.canopen.heartbeat_timeout_s:g}: the drive's heartbeat "
               "missing this long stops the sweep")
    elif layout.drive_watchdog_s:
        yield (f"{INDENT}frames.drive_watchdog_s {layout.drive_watchdog_s:g}: the drive zeroes and disables itself "
               "this long after the host's last frame")
    else:
        yield f"{INDENT}frames.drive_watchdog_s 0: the drive declares no watchdog of its own"
