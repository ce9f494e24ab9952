"""What the subcommands share: loading a configuration with its ``--set`` overrides, running the sweeps of a bench
or offline configuration with their progress, printing summaries, and one-line errors."""

from __future__ import annotations

import argparse
import functools
import logging
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bodebench.bench.adaptive import GrowingPlan
    from bodebench.bench.procedure import PlotWriter
    from bodebench.core.response import FrequencyResponse
    from bodebench.core.summary import ResponseSummary
    from bodebench.io.config import ExperimentConfig
    from bodebench.io.document import Override

log = logging.getLogger("bodebench")

CHAIN_HELP = ("take the bench's own delays out of every point's phase first: the setpoint's hold (half a sample "
              "period at the sweep's bench.rate_hz) and --delay; the gain is left as measured (docs/METHOD.md, "
              "\"Taking the bench's delays off\")")


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


def plant_models(config: ExperimentConfig) -> set[str]:
    """The simulated plants' models of ``config``'s cases (none for a real drive)."""
    return {case.plant.model for case in config.cases if case.plant is not None}


def say_compiling(config: ExperimentConfig, quiet: bool) -> None:
    """Say, before a sweep of a simulated plant starts, that its step loops are compiled first where numba's cache
    does not hold them yet (the first run after installing)."""
    from bodebench.sim.models import compile_note

    note = compile_note(plant_models(config))
    if note and not quiet:
        print(f"bodebench: {note}", file=sys.stderr)


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

    say_compiling(config, quiet)
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
        unwritten = len(session.refused) if session is not None else 0  # frequencies measured, not written
        where = (f"{kept} points kept in {current.directory}" if kept else
                 f"no point kept ({unwritten} frequencies refused, in the run's record)" if unwritten else
                 "no point measured")
        drive = current.ended.drive_state() if current.ended is not None else "nothing was sent to the drive"
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
        _print_summary(outcome.summary, outcome.plan)
        if session.refused:
            status = 1
    return status


def _print_summary(summary: Sequence[ResponseSummary], plan: GrowingPlan | None = None) -> None:
    """The figures read off a finished case, and an adaptive plan's account, indented under its line."""
    for item in summary:
        for line in item.lines():
            print("  " + line)
    for line in plan.lines() if plan is not None else ():
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


def _jobs(text: str) -> int:
    """--jobs: a whole number of worker processes, at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a whole number of worker processes, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1 (worker processes), got {value}")
    return value


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
    from bodebench.io.config import measured_of
    from bodebench.io.results import ResultsError

    if not args.without_chain:
        if args.delay or args.delay_uncertainty:
            raise ResultsError("--delay and --delay-uncertainty take effect with --without-chain only")
        return response
    bench = response.config.get("bench") if isinstance(response.config, dict) else None
    rate = bench.get("rate_hz") if isinstance(bench, dict) else None
    if not isinstance(rate, (int, float)) or isinstance(rate, bool):
        raise ResultsError(f"{directory}: --without-chain: not a bench sweep (its configuration has no bench.rate_hz)")
    measured = measured_of(response.config) if isinstance(response.config, dict) else "output"
    if measured != "output":
        raise ResultsError(f"{directory}: --without-chain: the sweep measured {measured}, a ratio of two of the "
                           "drive's channels, which the bench's delays never enter")
    try:
        return without_chain(response, float(rate), args.delay, args.delay_uncertainty)
    except ValueError as exc:
        raise ResultsError(f"--without-chain: {exc}") from None
