"""The ``bodebench`` command."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

# Only the standard library and the subcommands' modules (which import only the standard library at the top):
# `bodebench --help` and argument errors import nothing else; each command imports what it uses when it runs.
from bodebench.apps.commands.analyse import _analyse, _NotRaised
from bodebench.apps.commands.calibrate import _calibrate
from bodebench.apps.commands.check import _check
from bodebench.apps.commands.common import _ArgumentError, _cause, _chain_options, _jobs, _override, _plot_formats
from bodebench.apps.commands.dbc import _dbc
from bodebench.apps.commands.example import _example
from bodebench.apps.commands.fit import _fit
from bodebench.apps.commands.identify import _identify
from bodebench.apps.commands.overview import _overview
from bodebench.apps.commands.plot import _plot
from bodebench.apps.commands.ports import _ports
from bodebench.apps.commands.run import _run, _tui
from bodebench.apps.commands.sim_controller import _sim_controller
from bodebench.apps.commands.simulate import _simulate

log = logging.getLogger("bodebench")

























































LOG_BUS_HELP = ("write the session's traffic to FILE: on CAN through python-can's Logger, the suffix picks the "
                 "format (.asc, .blf, .log, .csv, ...); on a serial line a raw timestamped byte log")




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
    own warnings (missing vendor libraries, ...) show from -v on, and canopen's own lines (an SDO transfer it
    aborted, which the fault line names) too."""
    import logging

    level = logging.ERROR if quiet else logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 \
        else logging.DEBUG
    logging.basicConfig(level=level, format="%(name)s: %(levelname)s: %(message)s", stream=sys.stderr, force=True)
    logging.getLogger("can").setLevel(level if verbose >= 2 else max(level, logging.ERROR) if verbose == 0
                                      else logging.WARNING)
    logging.getLogger("canopen").setLevel(level if verbose >= 2 else logging.CRITICAL if verbose == 0
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
    ovw = add("overview", help="measure with a periodic multisine, a simulated plant offline or a drive on the bench: "
                               "every line's response to the tolerance and its nonlinear distortion ([overview])")
    ovw.add_argument("config", help="TOML experiment or bench file with an [overview] table")
    ovw.add_argument("--set", action="append", type=_override, metavar="KEY=VALUE", help=SET_HELP)
    ovw.add_argument("--out", required=True, help="results directory (one sub-directory per case)")
    ovw.add_argument("--plots", type=_plot_formats, default=("png",), metavar="FORMATS", help=PLOTS_HELP)
    ovw.set_defaults(handler=_overview)
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
    fit = add("fit", help="fit a rational transfer function to a measured response, weighted by each point's "
                          "interval")
    fit.add_argument("results", metavar="RESULTS_DIR", help="directory holding response.csv and response.json")
    fit.add_argument("--order", default=None, metavar="NUM/DEN",
                     help="numerator and denominator degrees (the integrator counted), e.g. 0/2 (default: each "
                          "order up to --max-order, the stable one of least BIC)")
    fit.add_argument("--max-order", type=int, default=4, help="highest denominator degree compared (default 4)")
    fit.add_argument("--integrator", action="store_true", help="a pole at s = 0 (a position loop's plant)")
    fit.add_argument("--fit-delay", action="store_true", help="fit a transport delay as well")
    fit.add_argument("--harmonic", type=int, default=1, help="measured harmonic to fit (default 1)")
    fit.add_argument("--channel", default=None, help="output channel (default: the first)")
    fit.add_argument("--json", action="store_true",
                     help="print the fit as JSON (written to fit.json; fit.mat for MATLAB)")
    fit.add_argument("--no-plot", action="store_true", help="do not write fit.png (the fit over the data and the "
                                                            "residuals)")
    _chain_options(fit)
    fit.set_defaults(handler=_fit)

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
