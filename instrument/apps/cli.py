"""The ``bodebench`` command."""

from __future__ import annotations

import argparse
import contextlib
import functools
import logging
import os
import sys
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

# Only the standard library at the top: `bodebench --help` and argument errors import nothing else; each command
# imports what it uses.
if TYPE_CHECKING:
    from bodebench.bench.procedure import PlotWriter
    from bodebench.core.response import FrequencyResponse
    from bodebench.core.summary import ResponseSummary
    from bodebench.io.config import ExperimentConfig
    from bodebench.io.document import Override

log = logging.getLogger("bodebench")

def _plot_formats(text: str) -> tuple[str, ...]:
    """``--plots``: comma-separated formats, or "none"."""
    if text.strip().lower() == "none":
        return ()
    from bodebench.apps.plots import check_formats

    try:
        return check_formats(text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _plot_writer(args: argparse.Namespace) -> PlotWriter | None:
    """What draws each finished case: the formats ``--plots`` asked for (None: no plots)."""
    if not args.plots:
        return None
    from bodebench.apps.plots import write_plots

    return functools.partial(write_plots, formats=args.plots)


def _existing(args: argparse.Namespace) -> str:
    """What a sweep does with results already in --out (:data:`bodebench.bench.procedure.EXISTING`)."""
    if not args.resume:
        return "refuse"
    return "resume_changed" if getattr(args, "accept_changes", False) else "resume"


def _bench_sweeps(config: ExperimentConfig, out: Path, *, direct: bool, quiet: bool, existing: str = "refuse",
                  plots: PlotWriter | None = None, log_bus: Path | None = None, keep_samples: bool = True) -> int:
    """Run every case of a bench config (``direct``: the simulated drive without a bus); the exit status."""
    from bodebench.apps.progress import ProgressPrinter
    from bodebench.bench.events import CaseBegins, SessionError
    from bodebench.bench.procedure import SweepProcedure
    from bodebench.drivers.errors import DriverError
    from bodebench.drivers.stop_signals import StopSignal
    from bodebench.io.results import ResultsError
    from bodebench.sim.serve import SimulatorStartError

    printer: ProgressPrinter | None = None

    def listener(event: object) -> None:
        nonlocal printer
        if isinstance(event, CaseBegins):
            case = config.cases[event.index]
            printer = ProgressPrinter(event.name, len(case.excitation.frequencies_hz), quiet=quiet)
        elif printer is not None:
            printer(event)

    procedure = SweepProcedure(config, out, listener=listener, direct=direct, plots=plots,
                               existing=existing, log_bus=log_bus,
                               keep_samples=keep_samples)
    try:
        outcomes = procedure.run()
    except ResultsError as exc:  # a results directory cannot take the sweep: found before any setpoint
        where = procedure.current.case.name if procedure.current else config.path.stem
        print(f"bodebench: {where}: not started: {exc}; nothing was sent to the drive", file=sys.stderr)
        return 2
    except BaseException as exc:
        if procedure.current is None:
            raise
        current = procedure.current
        session = current.session
        if not isinstance(exc, (SessionError, KeyboardInterrupt, SimulatorStartError, DriverError)):
            traceback.print_exc()
        kept = len(current.response.points)  # each of them saved when it was measured
        where = f"{kept} points kept in {current.directory}" if kept else "no point measured"
        drive = (session.ended.drive_state() if session is not None and session.ended is not None
                 else "nothing was sent to the drive")
        print(f"bodebench: {current.case.name}: stopped: {_cause(exc)}; {where}; {drive}", file=sys.stderr)
        return 128 + exc.signum if isinstance(exc, StopSignal) else 130 if isinstance(exc, KeyboardInterrupt) \
            else 1
    status = 0
    for outcome in outcomes:
        session, result = outcome.session, outcome.result
        assert session is not None and result is not None
        unconverged = [p for p in outcome.response.points if not p.converged]
        rt = f", round trip {result.round_trip_s * 1e6:.0f} us" if result.round_trip_s == result.round_trip_s else ""
        drive = session.ended.drive_state() if session.ended is not None else ""
        refused = (f", {len(session.refused)} frequencies refused (not written; --resume measures them again)"
                   if session.refused else "")
        print(f"{outcome.case.name}: {len(outcome.response.points)} points, {len(unconverged)} not "
              f"converged{refused}{rt} -> {outcome.directory}/response.csv{_also(outcome.files)}; {drive}")
        if result.periods_discarded:
            stale = (f"; {result.stale_samples} samples answered a setpoint sent late (pacing)"
                     if result.stale_samples else "")
            print(f"  {result.periods_discarded} periods discarded for gaps in the feedback (column "
                  f"periods_discarded){stale}")
        if result.log_failure:
            print(f"  bus log failed, the sweep went on without it: {result.log_failure}")
        _print_summary(outcome.summary)
        if session.refused:
            status = 1
    return status


def _print_summary(summary: Sequence[ResponseSummary]) -> None:
    """The figures read off a finished case, indented under its line."""
    for item in summary:
        for line in item.lines():
            print("  " + line)


def _also(files: Sequence[Path]) -> str:
    return f" (+ {', '.join(f.name for f in files)})" if files else ""


def _cause(exc: BaseException) -> str:
    """One line naming why a sweep stopped."""
    from bodebench.bench.events import SessionError
    from bodebench.drivers.errors import DriverError
    from bodebench.drivers.stop_signals import StopSignal
    from bodebench.sim.serve import SimulatorStartError

    if isinstance(exc, StopSignal):
        return f"interrupted ({exc.signame})"
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    if isinstance(exc, (SessionError, SimulatorStartError, DriverError)):
        return str(exc)
    return f"error: {type(exc).__name__}: {exc}"


class _ArgumentError(Exception):
    """A bad option found once the configuration is read: one line and exit status 2, as argparse gives."""


def _override(text: str) -> Override:
    """--set: one ``table.key=value``."""
    from bodebench.io.document import parse_override

    try:
        return parse_override(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _load(args: argparse.Namespace) -> ExperimentConfig:
    """The configuration ``args.config`` with the --set overrides (and --port, where the command has it)."""
    from bodebench.io.config import load_config, read_document
    from bodebench.io.document import OverrideError, apply_overrides, serial_port_overrides

    overrides: list[Override] = list(args.set or ())
    port = getattr(args, "port", None)
    if port is not None:
        try:
            document, _ = apply_overrides(read_document(args.config), overrides)
        except OverrideError:
            document = None  # load_config names the --set at fault
        if document is not None:
            try:
                overrides.extend(serial_port_overrides(document, port))
            except ValueError as exc:
                raise _ArgumentError(f"--port {port}: {exc}") from None
    for override in overrides:
        log.info("%s: %s %s", args.config, override.option, override)
    return load_config(args.config, overrides)


def _run(args: argparse.Namespace) -> int:
    from bodebench.io.config import ConfigError

    config = _load(args)
    if not config.on_bench:
        raise ConfigError(f"{args.config}: bench: missing (bodebench run needs a bench config; "
                          "use bodebench simulate for an offline experiment)", "bench")
    return _bench_sweeps(config, Path(args.out), direct=False, quiet=args.quiet, existing=_existing(args),
                         plots=_plot_writer(args), log_bus=_log_bus(args.log_bus),
                         keep_samples=not args.no_samples)


def _log_bus(value: str | None) -> Path | None:
    """The --log-bus file, checked before anything is sent: its directory must exist."""
    from bodebench.io.results import ResultsError

    if value is None:
        return None
    path = Path(value)
    if not path.parent.is_dir():
        raise ResultsError(f"--log-bus {value}: no directory {path.parent}")
    if path.is_dir():
        raise ResultsError(f"--log-bus {value}: is a directory")
    return path


def _tui(args: argparse.Namespace) -> int:
    from bodebench.apps.tui import run_tui
    from bodebench.io.config import ConfigError

    config = _load(args)
    if not config.on_bench:
        raise ConfigError(f"{args.config}: bench: missing (bodebench tui needs a bench config)", "bench")
    out = Path(args.out) if args.out else Path("results") / Path(args.config).stem
    return run_tui(config, out, log_bus=_log_bus(args.log_bus))


def _sim_controller(args: argparse.Namespace) -> int:
    from bodebench.bench.connection import simulator_spec
    from bodebench.io.config import ConfigError
    from bodebench.sim.canopen_device import ServingCanopen
    from bodebench.sim.serve import Serving, serve_can, serve_serial_pty, serve_slcan_pty

    config = _load(args)
    if args.write_config is not None:
        _check_copy_path(Path(args.config), Path(args.write_config))
    case = config.cases[0]
    if case.bench is None or case.simulator is None or case.plant is None:
        raise ConfigError(f"{args.config}: simulator: missing (sim-controller needs [bench], [plant] and "
                          "[simulator])", "simulator")
    bench, layout = case.on_bench.bench, case.on_bench.layout
    spec = simulator_spec(case)
    serving: Serving | ServingCanopen
    # what a bench config needs to reach this drive: the key to set, and whether [simulator] must go (a bench
    # config that keeps it on a CAN bus serves a simulated drive of its own)
    reach: tuple[tuple[str, str], str]
    drop_simulator = False
    if bench.transport == "serial":
        serving, path = serve_serial_pty(spec)
        where = f"serial ({spec.framing} framing) on {path}: set [serial] port = \"{path}\""
        reach = (("serial", "port"), path)
    elif bench.transport == "canopen":
        if case.can is not None and case.can.interface == "slcan":
            raise ConfigError(f"{args.config}: can.interface: the simulated CANopen device is served on a python-can "
                              "bus (virtual, udp_multicast, socketcan, ...), not as an SLCAN adapter",
                              "can.interface")
        serving = serve_can(spec)
        profile = spec.canopen.device_profile if spec.canopen else None
        where = (f"{profile.name if profile else 'CANopen'} {profile.device if profile else 'device'}, CANopen node "
                 f"{spec.canopen.node_id if spec.canopen else '?'}, on python-can "
                 f"{spec.can['interface']} channel {spec.can['channel']}")
        reach, drop_simulator = (("can", "channel"), str(spec.can["channel"])), True
    elif case.can is not None and case.can.interface == "slcan":
        serving, path = serve_slcan_pty(spec)
        where = f"SLCAN adapter on {path}: set [can] channel = \"{path}\""
        reach = (("can", "channel"), path)
    else:
        serving = serve_can(spec)
        where = f"python-can {spec.can['interface']} channel {spec.can['channel']}"
        reach, drop_simulator = (("can", "channel"), str(spec.can["channel"])), True
    if args.write_config is not None:
        try:
            written = _write_bench_copy(args, reach, drop_simulator)
        except BaseException:
            serving.close()
            raise
        where += f"; a bench config for it: {written} (bodebench run {written} --out DIR)"
    serving_started = time.monotonic()

    def report(text: str) -> None:  # each change of the drive's state, as the drive saw it
        print(f"{time.monotonic() - serving_started:10.3f} s  drive {text}", flush=True)

    serving.controller.on_event = report
    if bench.transport == "canopen":  # a CANopen device watches the host's heartbeat once the host writes 0x1016
        watchdog = "; it watches the host's heartbeat where the host sets its 0x1016 (canopen.host_heartbeat_ms)"
    else:
        watchdog = f"; watchdog {layout.drive_watchdog_s:g} s" if layout.drive_watchdog_s else "; no watchdog"
    print(f"simulated {case.plant.model} drive, {bench.clock} clock at {bench.rate_hz:g} Hz{watchdog}, "
          f"listening: {where}", flush=True)
    try:
        while not serving.stop.wait(0.5):
            if args.seconds and time.monotonic() - serving_started > args.seconds:
                break
    except KeyboardInterrupt:
        pass
    finally:
        serving.close()
    c = serving.controller
    print(f"stopped after {c.tick_count} control periods; last setpoint {c.applied:g}, "
          f"{'enabled' if c.enabled else 'disabled'}")
    return 0


def _check_copy_path(config: Path, copy: Path) -> None:
    """--write-config: a file in an existing directory, not the configuration itself."""
    if copy.is_dir():
        raise _ArgumentError(f"--write-config {copy}: is a directory")
    if not copy.parent.is_dir():
        raise _ArgumentError(f"--write-config {copy}: no directory {copy.parent}")
    if copy.exists() and copy.resolve() == config.resolve():
        raise _ArgumentError(f"--write-config {copy}: is the configuration itself (write the copy elsewhere)")


def _write_bench_copy(args: argparse.Namespace, reach: tuple[tuple[str, str], str], drop_simulator: bool) -> Path:
    """Write --write-config: the configuration file with its --set overrides, the key that reaches the served
    drive (``reach``: key parts and value) and, on a CAN bus, without [simulator]; relative file names in it
    (frames.dbc, canopen.eds) made absolute when the copy goes to another directory. The copy is validated;
    raises ResultsError when it cannot be written."""
    from bodebench.io.config import SIMULATED_EDS, ConfigError, load_config, read_document
    from bodebench.io.document import Override, OverrideError, apply_overrides, edited_copy
    from bodebench.io.results import ResultsError, atomic_write_text

    source, target = Path(args.config), Path(args.write_config)
    overrides: list[Override] = list(args.set or ())
    document, _ = apply_overrides(read_document(source), overrides)
    if source.resolve().parent != target.resolve().parent:
        tables: list[tuple[tuple[str, ...], dict[str, Any]]] = [((), document)]
        cases = document.get("cases")
        if isinstance(cases, dict):
            tables += [(("cases", str(name)), body) for name, body in cases.items() if isinstance(body, dict)]
        for prefix, body in tables:
            for table, key in (("frames", "dbc"), ("canopen", "eds")):
                sub = body.get(table)
                name = sub.get(key) if isinstance(sub, dict) else None
                if isinstance(name, str) and name and not Path(name).is_absolute():
                    overrides.append(Override((*prefix, table, key), str((source.parent / name).resolve())))
    parts, value = reach
    current = document.get(parts[0], {})
    if not isinstance(current, dict) or current.get(parts[1]) != value:
        overrides.append(Override(parts, value))
    canopen = document.get("canopen")
    if drop_simulator and isinstance(canopen, dict) and not canopen.get("eds"):
        profile = str(canopen.get("profile", "402"))
        if profile in SIMULATED_EDS:  # the [simulator] brought it
            overrides.append(Override(("canopen", "eds"), str(SIMULATED_EDS[profile])))
    header = (f"written by bodebench sim-controller: {source}, {'.'.join(parts)} set to {value}, where it serves "
              "the simulated drive" + (" ([simulator] left out: the drive is the one served)" if drop_simulator
                                       else ""))
    try:
        text = edited_copy(source.read_text(encoding="utf-8"), overrides,
                           ("simulator",) if drop_simulator else (), header)
    except (OverrideError, ValueError) as exc:
        raise ResultsError(f"--write-config {target}: {exc}") from None
    try:
        atomic_write_text(target, text)
    except OSError as exc:
        raise ResultsError(f"--write-config {target}: cannot write: {exc.strerror or exc}") from None
    try:
        load_config(target)
    except ConfigError as exc:
        raise ResultsError(f"--write-config {target}: the copy does not validate: {exc}") from None
    return target


def _simulate(args: argparse.Namespace) -> int:
    from bodebench.bench.events import CaseBegins, PointFinished
    from bodebench.bench.offline import ExecutorError, offline_executor
    from bodebench.bench.procedure import SweepProcedure

    config: ExperimentConfig = _load(args)
    out = Path(args.out)
    started = time.perf_counter()
    if config.on_bench:
        return _bench_sweeps(config, out, direct=True, quiet=args.quiet, existing=_existing(args),
                             plots=_plot_writer(args), keep_samples=args.samples)
    done, total, name = 0, 0, ""

    def listener(event: object) -> None:
        nonlocal done, total, name
        if isinstance(event, CaseBegins):
            name, done = event.name, 0
            total = len(config.cases[event.index].excitation.frequencies_hz)
        elif isinstance(event, PointFinished) and not args.quiet:
            done += 1
            worst = max(p.periods for p in event.points)
            print(f"{name}: {done}/{total}  f = {event.points[0].frequency_hz:g} Hz  {worst} periods",
                  file=sys.stderr)

    models = {case.plant.model for case in config.cases if case.plant is not None}
    try:
        with contextlib.ExitStack() as stack:
            drawer = None
            if args.plots:  # a process of its own, started first: it imports matplotlib while the pool starts
                from bodebench.apps.plots import DRAWING_MODULES
                from bodebench.bench.offline import drawing_executor

                drawer = stack.enter_context(drawing_executor(DRAWING_MODULES))
            executor = stack.enter_context(offline_executor(args.jobs, args.executor, models))
            procedure = SweepProcedure(config, out, listener=listener, executor=executor, plots=_plot_writer(args),
                                       existing=_existing(args),
                                       keep_samples=args.samples, drawer=drawer)
            outcomes = procedure.run()
    except ExecutorError as exc:
        print(f"bodebench: {exc}", file=sys.stderr)
        return 2
    for outcome in outcomes:
        unconverged = [p for p in outcome.response.points if not p.converged]
        print(f"{outcome.case.name}: {len(outcome.response.points)} points, "
              f"{len(unconverged)} not converged -> {outcome.directory}/response.csv{_also(outcome.files)}")
        _print_summary(outcome.summary)
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from bodebench.analysis import calibration
    from bodebench.bench.offline import ExecutorError, offline_executor

    out = Path(args.out) if args.out else calibration.DATA_FILE
    started = time.perf_counter()
    try:
        with offline_executor(args.jobs, args.executor, ("coulomb",)) as executor:
            table = calibration.compute_calibration(calibration.DEFAULT_FBAR_GRID, calibration.DEFAULT_OFFSET_GRID,
                                                    executor)
    except ExecutorError as exc:
        print(f"bodebench: {exc}", file=sys.stderr)
        return 2
    try:
        table.save(out)
    except OSError as exc:
        print(f"bodebench: {out}: cannot write the calibration: {exc}", file=sys.stderr)
        return 1
    lo, hi = table.fbar_range
    print(f"friction calibration: {table.fbar.size} Fbar from {lo:g} to {hi:g} x {table.offset.size} offsets "
          f"f/f_-90; r_90 from {table.r90.min():.4g} to {table.r90.max():.4g} -> {out} "
          f"({time.perf_counter() - started:.1f} s)")
    return 0


def _identify(args: argparse.Namespace) -> int:
    import dataclasses
    import json

    from bodebench.analysis.calibration import CalibrationError, load_calibration
    from bodebench.analysis.identify import IdentificationError, format_report, identify, plot_identification
    from bodebench.io.results import load_response

    directory = Path(args.results)
    response = _chain_taken_off(load_response(directory), args, directory)
    try:
        report = identify(response, args.stiffness, args.amplitude, harmonic=args.harmonic, channel=args.channel,
                          fit_stiffness=args.fit_stiffness, fit_damping=args.fit_damping,
                          table=load_calibration(args.calibration))
    except (IdentificationError, CalibrationError) as exc:
        print(f"bodebench: {directory}: {exc}", file=sys.stderr)
        return 2
    status = 0
    if not args.no_plot:
        try:
            paths = plot_identification(response, report, directory / "identify")
            report = dataclasses.replace(report, plots=tuple(str(p) for p in paths))
        except OSError as exc:
            print(f"bodebench: {directory}: cannot write the identification plot: {exc}", file=sys.stderr)
            status = 1
    print(json.dumps(report.to_json(), indent=2, allow_nan=False) if args.json else format_report(report))
    return status


def _plot(args: argparse.Namespace) -> int:
    from bodebench.apps.plots import plot_comparison
    from bodebench.io.results import CSV_NAME, ResultsError, load_response

    responses = {}
    for given in args.results:
        directory = Path(given)
        if not directory.is_dir():
            raise ResultsError(f"{directory}: not a directory")
        found = [directory] if (directory / CSV_NAME).exists() else sorted(
            p for p in directory.iterdir() if p.is_dir() and (p / CSV_NAME).exists())
        if not found:
            raise ResultsError(f"{directory}: no {CSV_NAME} here or in its sub-directories")
        for sub in found:
            label = given if sub == directory else str(Path(given) / sub.name)
            responses[label] = load_response(sub)
    try:
        path = plot_comparison(responses, Path(args.out), args.title)
    except ValueError as exc:
        print(f"bodebench: {args.out}: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"bodebench: {args.out}: cannot write the plot: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print(f"{len(responses)} responses -> {path}")
    return 0


def _analyse(args: argparse.Namespace) -> int:
    from bodebench.analysis.reanalyse import reanalyse
    from bodebench.io.results import CSV_NAME, ResultsError, load_response, save_response, verify_results
    from bodebench.io.samples import SamplesError

    directory = Path(args.results)
    overrides: dict[str, object] = {}
    if args.criterion is not None:
        overrides["criterion"] = args.criterion
    if args.tolerance is not None:
        overrides["tolerance_percent"] = args.tolerance
    out = Path(args.out) if args.out else None
    if out is not None and (out / CSV_NAME).exists():
        raise ResultsError(f"{out / CSV_NAME}: results already here; choose another --out")
    try:
        result = reanalyse(directory, **overrides)
    except SamplesError as exc:
        print(f"bodebench: {exc} (a sweep keeps its samples since bodebench 0.1; measure it again)",
              file=sys.stderr)
        return 2
    stored = load_response(directory)
    checked, changed = verify_results(directory)
    for line in changed:  # what changed since it was written, by the checksums recorded then
        print(f"{directory}: {line}")
    if not checked:
        print(f"{directory}: made without checksums: what was edited since cannot be told")
    response, analysis = _chain_taken_off(result.response, args, directory), result.analysis
    if args.without_chain:
        stored = _chain_taken_off(stored, args, directory)
    again = {(p.frequency_hz, p.harmonic, p.channel): p for p in response.points}
    differ = [(a, again.get((a.frequency_hz, a.harmonic, a.channel))) for a in stored.points
              if not any(f == a.frequency_hz for f, _ in result.failed)]
    differ = [(a, b) for a, b in differ if b is None or not _same_point(a, b)]
    same = len(stored.points) - len(differ) - sum(1 for a in stored.points
                                                  if any(f == a.frequency_hz for f, _ in result.failed))
    print(f"{directory}: {len(response)} points from their samples, criterion {analysis.criterion}, tolerance "
          f"{analysis.tolerance_percent:g} %; {same} identical to the stored points"
          + (f", {len(differ)} not:" if differ else ""))
    for a, b in differ:  # each one named, with by how much
        where = f"  {a.frequency_hz:g} Hz harmonic {a.harmonic} {a.channel}"
        if b is None:
            print(f"{where}: stored, not found again")
        else:
            change = abs(complex(b.p, b.q) - complex(a.p, a.q)) / max(abs(complex(a.p, a.q)), 1e-300)
            print(f"{where}: stored {a.gain_db:.6g} dB {a.phase_deg:.6g} deg {a.status}, again {b.gain_db:.6g} dB "
                  f"{b.phase_deg:.6g} deg {b.status} (|dZ|/|Z| = {change:.3g})")
    if not args.quiet:
        print(f"{'f Hz':>10} {'k':>2} {'channel':<14} {'gain dB':>11} {'phase deg':>10} {'periods':>7}  status")
        for p in response.points:
            print(f"{p.frequency_hz:10g} {p.harmonic:2d} {p.channel:<14} {p.gain_db:11.5f} {p.phase_deg:10.4f} "
                  f"{p.periods:7d}  {p.status}")
    if not args.quiet:
        from bodebench.core.summary import summarize_response

        if args.without_chain:
            print(f"the bench's hold and a delay of {args.delay:g} s taken off every phase (--without-chain):")
        print(f"{response.case}:")
        _print_summary(summarize_response(response, analysis.response_kind))
    for f, why in result.failed:
        print(f"{f:g} Hz left out, too many periods with gaps: {why}")
    if result.record_ended:
        print(f"the record ended before the rule stopped at {len(result.record_ended)} frequencies (capped there): "
              + ", ".join(f"{f:g}" for f in result.record_ended) + " Hz")
    if out is not None:
        from bodebench.apps.plots import write_plots

        save_response(response, out)
        files = write_plots(response, out, f"{response.case} ({analysis.criterion}, {analysis.tolerance_percent:g} %)",
                            formats=args.plots)
        print(f"-> {out / CSV_NAME} (+ {', '.join(f.name for f in files)})")
    return 0


class _NotRaised(Exception):
    """Stands for an error class not yet imported when start-up is interrupted (nothing raises it)."""


def _same_point(a: object, b: object) -> bool:
    """Whether two points are the same, bit for bit (NaN equal to NaN)."""
    import dataclasses
    import math

    assert dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b)
    for x, y in zip(dataclasses.astuple(a), dataclasses.astuple(b), strict=True):  # type: ignore[arg-type]
        if isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y):
            continue
        if x != y:
            return False
    return True


def _ports(args: argparse.Namespace) -> int:
    import json

    import serial.tools.list_ports

    serial_ports = [{"port": p.device, "description": p.description or "", "hwid": p.hwid or ""}
                    for p in sorted(serial.tools.list_ports.comports(), key=lambda p: p.device)]
    can_configs: list[dict[str, object]] = []
    unusable: list[dict[str, str]] = []
    if not args.no_can:
        from bodebench.drivers.ports import detect_can

        try:
            found = detect_can(args.can)
        except ValueError as exc:
            raise _ArgumentError(f"--can: {exc}") from None
        can_configs = [{k: v if isinstance(v, (str, int, float, bool)) or v is None else str(v)
                        for k, v in c.items()} for c in found.configs]
        unusable = [{"interface": name, "why": why} for name, why in found.unusable]
    if args.json:
        print(json.dumps({"serial": serial_ports, "can": can_configs, "can_unusable": unusable}, indent=2))
        return 0
    print(f"serial ports (pyserial): {len(serial_ports)}")
    for p in serial_ports:
        print(f'  port = "{p["port"]}"    # {p["description"]}; {p["hwid"]}')
    if args.no_can:
        return 0
    where = ", ".join(args.can) if args.can else "every interface"
    print(f"CAN configurations (python-can, {where}): {len(can_configs)}")
    for c in can_configs:
        print("  " + ", ".join(f"{k} = {json.dumps(v)}" for k, v in c.items()))
    if unusable:
        print(f"CAN interfaces that cannot be used here: {len(unusable)}")
        for item in unusable:
            print(f"  {item['interface']}: {item['why']}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from bodebench.apps.check import check_lines

    for line in check_lines(_load(args)):
        print(line)
    return 0


def _dbc(args: argparse.Namespace) -> int:
    from bodebench.drivers.dbc import layout_database
    from bodebench.io.config import ConfigError

    config = _load(args)
    if not config.on_bench:
        raise ConfigError(f"{args.config}: bench: missing (an offline experiment has no frames to describe)", "bench")
    texts: dict[str, list[str]] = {}
    for case in config.cases:
        layout = case.on_bench.layout
        texts.setdefault(layout_database(layout, f"bodebench frame layout of {args.config}").as_dbc_string(),
                         []).append(case.name)
    if len(texts) > 1:
        groups = "; ".join(", ".join(names) for names in texts.values())
        raise ConfigError(f"{args.config}: frames: the cases have different frame layouts ({groups}): write each "
                          "from a configuration of its own", "frames")
    _write_new(next(iter(texts)), args.out, "frame layout")
    return 0


def _write_new(text: str, out: str | None, what: str) -> None:
    """``text`` to stdout, or to the new file ``out`` (--out): an existing file is never overwritten
    (ResultsError, one line)."""
    from bodebench.io.results import ResultsError

    if out is None:
        sys.stdout.write(text)
        return
    try:
        with open(out, "x", encoding="utf-8", newline="") as handle:
            handle.write(text)
    except FileExistsError:
        raise ResultsError(f"--out {out}: a file is there already; bodebench does not overwrite it") from None
    except OSError as exc:
        raise ResultsError(f"--out {out}: cannot write: {exc.strerror or exc}") from None
    print(f"{what} -> {out}", file=sys.stderr)


def _example(args: argparse.Namespace) -> int:
    from bodebench.io.examples import ExampleError, example, examples

    if args.name is None:
        every = examples()
        width = max(len(e.name) for e in every)
        for item in every:
            print(f"{item.name:<{width}}  {item.line}")
        return 0
    try:
        item = example(args.name)
    except ExampleError as exc:
        raise _ArgumentError(str(exc)) from None
    _write_new(item.text(), args.out, f"example {item.name}")
    return 0


LOG_BUS_HELP = ("write the session's traffic to FILE: on CAN through python-can's Logger, the suffix picks the "
                 "format (.asc, .blf, .log, .csv, ...); on a serial line a raw timestamped byte log")


def _jobs(text: str) -> int:
    """--jobs: a whole number of worker processes, at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a whole number of worker processes, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1 (worker processes), got {value}")
    return value


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("bodebench")
    except metadata.PackageNotFoundError:
        return "unknown"


class _OneLineParser(argparse.ArgumentParser):
    """A bad option gives one line (and exit status 2), not the usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message} (see --help)\n")


def _common_options() -> _OneLineParser:
    """-v and -q, the same on every subcommand."""
    common = _OneLineParser(add_help=False)
    group = common.add_mutually_exclusive_group()
    group.add_argument("-v", "--verbose", action="count", default=0,
                       help="log more: -v what bodebench does, -vv its details and those of python-can")
    group.add_argument("-q", "--quiet", action="store_true", help="no progress display; log errors only")
    return common


def _configure_logging(verbose: int, quiet: bool) -> None:
    """Log lines on stderr: warnings by default, info with -v, debug with -vv, errors only with -q. python-can's
    own warnings (missing vendor libraries, ...) show from -v on."""
    import logging

    level = logging.ERROR if quiet else logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 \
        else logging.DEBUG
    logging.basicConfig(level=level, format="%(name)s: %(levelname)s: %(message)s", stream=sys.stderr, force=True)
    logging.getLogger("can").setLevel(level if verbose >= 2 else max(level, logging.ERROR) if verbose == 0
                                      else logging.WARNING)
EXECUTOR_HELP = ("run the frequencies on a Dask cluster: a scheduler address (tcp://host:8786), or local to start "
                 "one here with --jobs workers (needs the dask extra)")
ACCEPT_HELP = ("with --resume: continue even where rows or samples files of --out changed, vanished or appeared "
               "since they were written (each is named; by default the resume is refused)")
PLOTS_HELP = "plot files per case: comma-separated png, svg, pdf, or none (default: png)"
SET_HELP = ("set a key of the configuration before it is validated, as if the file said so (repeatable): "
            "a TOML value, or a bare word taken as a string; for example analysis.tolerance_percent=0.1, "
            "serial.port=/dev/ttyUSB0, excitation.frequencies_hz=[1,2,5], 'cases.\"fbar_0.8\".plant.friction=0.009'. "
            "The results record the configuration with these values")
CHAIN_HELP = ("take the bench's own delays out of every point's phase first: the setpoint's hold (half a sample "
              "period at the sweep's bench.rate_hz) and --delay; the gain is left as measured (docs/METHOD.md, "
              "\"Taking the bench's delays off\")")


def _chain_options(parser: argparse.ArgumentParser) -> None:
    """--without-chain and the delay it takes off, for the commands that read a measured response."""
    parser.add_argument("--without-chain", action="store_true", help=CHAIN_HELP)
    parser.add_argument("--delay", type=float, default=0.0, metavar="SECONDS",
                        help="with --without-chain: a further delay of the bench (transport, filters) to take off")
    parser.add_argument("--delay-uncertainty", type=float, default=0.0, metavar="SECONDS",
                        help="with --without-chain: the delay's 95 %% half-width, carried into each point's intervals")


def _chain_taken_off(response: FrequencyResponse, args: argparse.Namespace, directory: Path) -> FrequencyResponse:
    """``response`` with the bench's delays taken off when ``--without-chain`` asks (ResultsError in one line when
    the sweep was no bench sweep or a delay is not a time)."""
    from bodebench.core.chain import without_chain
    from bodebench.io.results import ResultsError

    if not args.without_chain:
        if args.delay or args.delay_uncertainty:
            raise ResultsError("--delay and --delay-uncertainty take effect with --without-chain only")
        return response
    bench = response.config.get("bench") if isinstance(response.config, dict) else None
    rate = bench.get("rate_hz") if isinstance(bench, dict) else None
    if not isinstance(rate, (int, float)) or isinstance(rate, bool):
        raise ResultsError(f"{directory}: --without-chain: not a bench sweep (its configuration has no bench.rate_hz)")
    try:
        return without_chain(response, float(rate), args.delay, args.delay_uncertainty)
    except ValueError as exc:
        raise ResultsError(f"--without-chain: {exc}") from None


PORT_HELP = ("the serial port of the drive: --set serial.port=PORT for every case (on a CAN bus, "
             "--set can.channel=... instead)")


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog="bodebench", description=__doc__.strip().splitlines()[0] if __doc__ else "")
    parser.add_argument("--version", action="version", version=f"bodebench {_version()}")
    common = _common_options()
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineParser)

    def add(name: str, **kwargs: Any) -> argparse.ArgumentParser:
        return sub.add_parser(name, parents=[common], **kwargs)

    sim = add("simulate", help="sweep a simulated plant offline (the papers' computational experiment)")
    sim.add_argument("config", help="TOML experiment file")
    sim.add_argument("--set", action="append", type=_override, metavar="KEY=VALUE", help=SET_HELP)
    sim.add_argument("--out", required=True, help="results directory (one sub-directory per case)")
    sim.add_argument("--jobs", type=_jobs, default=None,
                     help="worker processes (default: all cores; 1 runs in this process)")
    sim.add_argument("--resume", action="store_true",
                     help="continue an interrupted sweep in --out: measured points are kept, the rest measured")
    sim.add_argument("--accept-changes", action="store_true", help=ACCEPT_HELP)
    sim.add_argument("--executor", default=None, metavar="SCHEDULER", help=EXECUTOR_HELP)
    sim.add_argument("--plots", type=_plot_formats, default=("png",), metavar="FORMATS", help=PLOTS_HELP)
    sim.add_argument("--samples", action="store_true",
                     help="keep the raw samples of each frequency in DIR/samples/ for bodebench analyse (a "
                          "simulation's samples are reproducible from its config, so by default they are not kept)")
    sim.set_defaults(handler=_simulate)
    run = add("run", help="sweep a drive on the bench (CAN or serial), headless")
    run.add_argument("config", help="TOML bench file")
    run.add_argument("--set", action="append", type=_override, metavar="KEY=VALUE", help=SET_HELP)
    run.add_argument("--port", default=None, metavar="PORT", help=PORT_HELP)
    run.add_argument("--out", required=True, help="results directory")
    run.add_argument("--resume", action="store_true",
                     help="continue an interrupted sweep in --out: measured points are kept, the rest measured")
    run.add_argument("--accept-changes", action="store_true", help=ACCEPT_HELP)
    run.add_argument("--plots", type=_plot_formats, default=("png",), metavar="FORMATS", help=PLOTS_HELP)
    run.add_argument("--log-bus", metavar="FILE", default=None, help=LOG_BUS_HELP)
    run.add_argument("--no-samples", action="store_true",
                     help="do not keep the raw samples of each frequency in DIR/samples/ (analyse needs them)")
    run.set_defaults(handler=_run)
    ctl = add("sim-controller", help="run the simulated servo controller of a bench config standalone")
    ctl.add_argument("config", help="TOML bench file with [simulator]")
    ctl.add_argument("--set", action="append", type=_override, metavar="KEY=VALUE", help=SET_HELP)
    ctl.add_argument("--write-config", default=None, metavar="FILE",
                     help="write FILE, a copy of the configuration (with the --set values) that reaches this drive: "
                          "serial.port (or can.channel) set to what the simulator opened, [simulator] left out on a "
                          "CAN bus; bodebench run FILE then sweeps it")
    ctl.add_argument("--seconds", type=float, default=0.0, help="stop after this long (default: until Ctrl-C)")
    ctl.set_defaults(handler=_sim_controller)
    tui = add("tui", help="sweep a drive on the bench in the terminal UI")
    tui.add_argument("config", help="TOML bench file")
    tui.add_argument("--set", action="append", type=_override, metavar="KEY=VALUE", help=SET_HELP)
    tui.add_argument("--port", default=None, metavar="PORT", help=PORT_HELP)
    tui.add_argument("--out", default=None, help="results directory (default: results/<config stem>)")
    tui.add_argument("--log-bus", metavar="FILE", default=None, help=LOG_BUS_HELP)
    tui.set_defaults(handler=_tui)
    ana = add("analyse", help="analyse a measured sweep again from its samples, without the bench")
    ana.add_argument("results", metavar="RESULTS_DIR", help="directory holding response.csv, response.json, samples/")
    ana.add_argument("--criterion", default=None, help="stopping rule (default: the sweep's own)")
    ana.add_argument("--tolerance", type=float, default=None, metavar="PERCENT",
                     help="tolerance eps in percent (default: the sweep's own)")
    ana.add_argument("--out", default=None, help="write the new response and its plots here (default: print only)")
    ana.add_argument("--plots", type=_plot_formats, default=("png",), metavar="FORMATS", help=PLOTS_HELP)
    _chain_options(ana)
    ana.set_defaults(handler=_analyse)
    ports = add("ports", help="list the serial ports and the CAN interfaces and channels found here")
    ports.add_argument("--can", action="append", metavar="INTERFACE", default=None,
                       help="search only this python-can interface (repeatable; default: every interface)")
    ports.add_argument("--no-can", action="store_true", help="list the serial ports only")
    ports.add_argument("--json", action="store_true", help="print JSON")
    ports.set_defaults(handler=_ports)
    chk = add("check", help="validate a configuration and print its plan, what is sent to the drive and the "
                            "safety limits, opening no bus")
    chk.add_argument("config", help="TOML experiment or bench file")
    chk.add_argument("--set", action="append", type=_override, metavar="KEY=VALUE", help=SET_HELP)
    chk.add_argument("--port", default=None, metavar="PORT", help=PORT_HELP)
    chk.set_defaults(handler=_check)
    dbc = add("dbc", help="write a bench configuration's frame layout (setpoint and feedback frames) as a DBC file")
    dbc.add_argument("config", help="TOML bench file")
    dbc.add_argument("--set", action="append", type=_override, metavar="KEY=VALUE", help=SET_HELP)
    dbc.add_argument("--out", default=None, metavar="FILE",
                     help="write it to FILE, which must not exist yet (default: standard output)")
    dbc.set_defaults(handler=_dbc)
    exa = add("example", help="list the example configurations shipped with bodebench, or write one out")
    exa.add_argument("name", nargs="?", default=None, metavar="NAME",
                     help="the example to write (default: list them, one line each)")
    exa.add_argument("--out", default=None, metavar="FILE",
                     help="write it to FILE, which must not exist yet (default: standard output)")
    exa.set_defaults(handler=_example)
    cal = add("calibrate", help="compute the friction link's calibration curves (identify's procedure)")
    cal.add_argument("--out", default=None, help="output file (default: the table shipped in the package)")
    cal.add_argument("--jobs", type=_jobs, default=None,
                     help="worker processes (default: all cores; 1 runs in this process)")
    cal.add_argument("--executor", default=None, metavar="SCHEDULER", help=EXECUTOR_HELP)
    cal.set_defaults(handler=_calibrate)
    ident = add("identify", help="identify the friction link (F_ct, m) from a measured response")
    ident.add_argument("results", metavar="RESULTS_DIR", help="directory holding response.csv and response.json")
    ident.add_argument("--json", action="store_true", help="print the report as JSON")
    ident.add_argument("--stiffness", type=float, default=None, help="K_p (default: the sidecar's plant.stiffness)")
    ident.add_argument("--amplitude", type=float, default=None,
                       help="A_F, force amplitude (default: the sidecar's excitation.amplitude)")
    ident.add_argument("--harmonic", type=int, default=1, help="measured harmonic to use (default 1)")
    ident.add_argument("--channel", default=None, help='output channel (default: "position")')
    ident.add_argument("--fit-stiffness", action="store_true", help="let the fit adjust K_p as well")
    ident.add_argument("--fit-damping", action="store_true", help="fit a viscous damping ratio as well")
    ident.add_argument("--calibration", default=None, help="calibration file (default: the shipped table)")
    ident.add_argument("--no-plot", action="store_true", help="do not write identify.png/svg")
    _chain_options(ident)
    ident.set_defaults(handler=_identify)
    plot = add("plot", help="one Bode diagram comparing several results directories")
    plot.add_argument("results", metavar="DIR", nargs="+",
                      help="results directories (or directories of case sub-directories)")
    plot.add_argument("--out", required=True, help="image file; its suffix names the format (.png, .svg, .pdf)")
    plot.add_argument("--title", default="", help="the figure's title")
    plot.set_defaults(handler=_plot)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``bodebench`` command; returns the exit status. A stop signal at any moment, start-up
    included, ends it with one line saying so."""
    from bodebench.drivers.stop_signals import StopSignal, stop_on_signals

    # bound before the imports below, so that an exception during start-up finds every except clause defined
    ConfigError: type[Exception] = _NotRaised
    ResultsError: type[Exception] = _NotRaised
    DriverError: type[Exception] = _NotRaised
    SimulatorStartError: type[Exception] = _NotRaised
    MissingDependency: type[Exception] = _NotRaised
    try:
        with stop_on_signals():  # from the first moment: a signal during start-up is one line, not a traceback
            args = build_parser().parse_args(argv)
            from bodebench.drivers.errors import DriverError
            from bodebench.drivers.extras import MissingDependency
            from bodebench.io.config import ConfigError
            from bodebench.io.results import ResultsError
            from bodebench.sim.serve import SimulatorStartError

            _configure_logging(args.verbose, args.quiet)
            log.debug("bodebench %s: %s", _version(), " ".join(sys.argv if argv is None else ["bodebench", *argv]))
            if args.handler is not _tui:
                return int(args.handler(args))
        return int(args.handler(args))  # the terminal UI handles its own keys and signals
    except KeyboardInterrupt as exc:
        print(f"bodebench: {_cause(exc)}; points already measured are on disk", file=sys.stderr)
        return 128 + exc.signum if isinstance(exc, StopSignal) else 130
    except _ArgumentError as exc:
        print(f"bodebench {args.command}: {exc} (see --help)", file=sys.stderr)
        return 2
    except (ConfigError, ResultsError, MissingDependency) as exc:
        print(f"bodebench: {exc}", file=sys.stderr)
        return 2
    except (DriverError, SimulatorStartError) as exc:
        print(f"bodebench: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # output piped into a pager or head that closed early
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":
    sys.exit(main())
