"""``bodebench overview``: the overview measurement (a periodic multisine, every line averaged to the tolerance) of
a simulated plant offline, or of the drive a bench configuration reaches."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from bodebench.apps.commands.common import _load, say_compiling

if TYPE_CHECKING:
    from collections.abc import Callable

    from bodebench.bench.overview import OverviewResult
    from bodebench.core.response import FrequencyResponse
    from bodebench.io.config import CaseConfig


def _overview(args: argparse.Namespace) -> int:
    from bodebench.bench.overview import measure_overview
    from bodebench.bench.procedure import case_directory
    from bodebench.io.config import ConfigError
    from bodebench.io.overview import OVERVIEW_CSV, save_overview
    from bodebench.io.results import CSV_NAME, ResultsError, check_output

    config = _load(args)
    for case in config.cases:
        if case.overview is None:
            raise ConfigError(f"{args.config}: overview: missing (bodebench overview needs an [overview] table: "
                              "start_hz, stop_hz, amplitude)", "overview")
        if case.bench is not None and case.analysis.measurement != "output":
            raise ConfigError(f"{args.config}: analysis.measured: \"{case.analysis.measurement}\": bodebench "
                              "overview measures the output channel against the setpoint (measured = \"output\")",
                              "analysis.measured")
    out = Path(args.out)
    started = time.perf_counter()
    say_compiling(config, args.quiet)
    for case in config.cases:
        directory = case_directory(config, out, case)
        if (directory / CSV_NAME).exists():
            raise ResultsError(f"{directory / CSV_NAME}: results already here; choose another --out")
        design = case.multisine()
        made = check_output(directory, len(design.lines))
        if not args.quiet:
            print(f"{case.name}: {len(design.lines)} lines from {design.frequencies_hz[0]:g} to "
                  f"{design.frequencies_hz[-1]:g} Hz, a period of {design.samples} samples ({design.period_s:g} s "
                  f"at {design.rate_hz:g} Hz), crest factor {design.crest_factor:.3g}", file=sys.stderr)

        def progress(periods: int, name: str = case.name) -> None:
            if not args.quiet and periods % 10 == 0:
                print(f"{name}: {periods} periods", file=sys.stderr)

        if case.bench is None:
            result = measure_overview(case, progress)
        else:
            try:
                result = _on_bench(case, progress)
            except OverviewStopped as exc:
                if made and not any(directory.iterdir()):
                    directory.rmdir()  # nothing measured: no empty directory left behind
                print(f"bodebench: {exc}", file=sys.stderr)
                return 1
        response = save_overview(directory, result.lines, result.design, result.periods, case.raw, case.name)
        files = _draw(args, result, response, directory, config.title if not config.has_cases
                      else f"{config.title}: {case.name}")
        converged = sum(line.point.converged for line in result.lines)
        also = "".join(f", {path.name}" for path in files)
        drive = f"; {result.ended.drive_state()}" if result.ended is not None else ""
        print(f"{case.name}: {len(result.lines)} lines, {converged} converged, {result.periods} periods -> "
              f"{directory / OVERVIEW_CSV}{also}{drive}")
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


def _on_bench(case: CaseConfig, progress: Callable[[int], None]) -> OverviewResult:
    """The overview of a bench case on its drive (a [simulator]'s drive on its bus); a trip or an error is one
    line saying what the drive was last sent."""
    from bodebench.bench.connection import plan_link
    from bodebench.bench.events import SessionEnded, SessionError
    from bodebench.bench.overview import measure_overview_on_bench
    from bodebench.drivers.errors import DriverError

    ended: list[SessionEnded] = []
    try:
        return measure_overview_on_bench(case, plan_link(case), progress, on_end=ended.append)
    except (SessionError, DriverError) as exc:
        drive = ended[0].drive_state() if ended else "nothing was sent to the drive"
        raise OverviewStopped(f"{case.name}: stopped: {exc}; {drive}") from None


class OverviewStopped(Exception):
    """A bench overview that stopped before its end; the message says why and what the drive was last sent."""


def _draw(args: argparse.Namespace, result: OverviewResult, response: FrequencyResponse, directory: Path,
          title: str) -> list[Path]:
    """The overview's plots in the formats --plots asks for: the Bode plot of its lines and their levels."""
    if not args.plots:
        return []
    import numpy as np

    from bodebench.apps.plots import plot_levels, write_plots
    from bodebench.core.response import FrequencyResponse

    # the legend states the tolerance the lines were measured to: [overview]'s, where it differs from [analysis]'s
    tolerance = response.points[0].tolerance_percent
    config = {**response.config, "analysis": {**response.config.get("analysis", {}), "tolerance_percent": tolerance}}
    shown = FrequencyResponse(response.points, config=config, case=response.case)
    files = write_plots(shown, directory, title, args.plots, figures=("bode",))
    lines = result.lines
    files += plot_levels(np.array([line.point.frequency_hz for line in lines]),
                         np.array([line.point.magnitude for line in lines]),
                         np.array([line.distortion for line in lines]), np.array([line.noise for line in lines]),
                         directory / "levels", title, args.plots)
    return files
