"""``bodebench overview``: the overview measurement (a periodic multisine, every line averaged to the tolerance) of
a simulated plant offline."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from bodebench.apps.commands.common import _load, say_compiling

if TYPE_CHECKING:
    from bodebench.bench.overview import OverviewResult
    from bodebench.core.response import FrequencyResponse


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
        if case.bench is not None:
            raise ConfigError(f"{args.config}: bench: bodebench overview runs the simulated plant offline (a "
                              "configuration without [bench]); on a bench configuration [overview] is checked "
                              "against [safety] by bodebench check", "bench")
    out = Path(args.out)
    started = time.perf_counter()
    say_compiling(config, args.quiet)
    for case in config.cases:
        directory = case_directory(config, out, case)
        if (directory / CSV_NAME).exists():
            raise ResultsError(f"{directory / CSV_NAME}: results already here; choose another --out")
        design = case.multisine()
        check_output(directory, len(design.lines))
        if not args.quiet:
            print(f"{case.name}: {len(design.lines)} lines from {design.frequencies_hz[0]:g} to "
                  f"{design.frequencies_hz[-1]:g} Hz, a period of {design.samples} samples ({design.period_s:g} s "
                  f"at {design.rate_hz:g} Hz), crest factor {design.crest_factor:.3g}", file=sys.stderr)

        def progress(periods: int, name: str = case.name) -> None:
            if not args.quiet and periods % 10 == 0:
                print(f"{name}: {periods} periods", file=sys.stderr)

        result = measure_overview(case, progress)
        response = save_overview(directory, result.lines, result.design, result.periods, case.raw, case.name)
        files = _draw(args, result, response, directory, config.title if not config.has_cases
                      else f"{config.title}: {case.name}")
        converged = sum(line.point.converged for line in result.lines)
        also = "".join(f", {path.name}" for path in files)
        print(f"{case.name}: {len(result.lines)} lines, {converged} converged, {result.periods} periods -> "
              f"{directory / OVERVIEW_CSV}{also}")
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


def _draw(args: argparse.Namespace, result: OverviewResult, response: FrequencyResponse, directory: Path,
          title: str) -> list[Path]:
    """The overview's plots in the formats --plots asks for: the Bode plot of its lines and their levels."""
    if not args.plots:
        return []
    import numpy as np

    from bodebench.apps.plots import plot_levels, write_plots

    files = write_plots(response, directory, title, args.plots, figures=("bode",))
    lines = result.lines
    files += plot_levels(np.array([line.point.frequency_hz for line in lines]),
                         np.array([line.point.magnitude for line in lines]),
                         np.array([line.distortion for line in lines]), np.array([line.noise for line in lines]),
                         directory / "levels", title, args.plots)
    return files
