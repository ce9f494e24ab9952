"""``bodebench simulate``: the offline experiment, or a bench configuration's simulated drive without a bus."""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bodebench.io.config import ExperimentConfig

from bodebench.apps.commands.common import (
    _also,
    _bench_sweeps,
    _existing,
    _load,
    _plot_writer,
    _print_summary,
    plant_models,
    say_compiling,
)

log = logging.getLogger("bodebench")


def _simulate(args: argparse.Namespace) -> int:
    from bodebench.bench.events import CaseBegins, OverviewProgress, PlanGrew, PointFinished, SessionError
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
        elif isinstance(event, OverviewProgress) and not args.quiet and event.periods % 10 == 0:
            print(f"{event.case}: the overview first, {event.periods} periods", file=sys.stderr)
        elif isinstance(event, PlanGrew) and not args.quiet:
            total += len(event.frequencies_hz)
            print(f"{name}: the plan adds {len(event.frequencies_hz)} frequencies", file=sys.stderr)
            for f, reason in zip(event.frequencies_hz, event.reasons, strict=True):
                print(f"  + {f:.6g} Hz: {reason}", file=sys.stderr)
        elif isinstance(event, PointFinished) and not args.quiet:
            done += 1
            worst = max(p.periods for p in event.points)
            print(f"{name}: {done}/{total}  f = {event.points[0].frequency_hz:g} Hz  {worst} periods",
                  file=sys.stderr)

    models = plant_models(config)
    say_compiling(config, args.quiet)
    try:
        with contextlib.ExitStack() as stack:
            drawer = None
            if args.plots:  # a process of its own, started first: it imports matplotlib while the pool starts
                from bodebench.apps.plots import DRAWING_MODULES
                from bodebench.bench.drawing import drawing_executor

                drawer = stack.enter_context(drawing_executor(DRAWING_MODULES))
            executor = stack.enter_context(offline_executor(args.jobs, args.executor, models))
            procedure = SweepProcedure(config, out, listener=listener, executor=executor, plots=_plot_writer(args),
                                       existing=_existing(args),
                                       keep_samples=args.samples, drawer=drawer)
            outcomes = procedure.run()
    except ExecutorError as exc:
        print(f"bodebench: {exc}", file=sys.stderr)
        return 2
    except SessionError as exc:  # the disk would not take a record or the plots: every point is on disk
        kept = sum(len(outcome.response.points) for outcome in procedure.measuring)
        print(f"bodebench: stopped: {exc}; {kept} points kept in {out}", file=sys.stderr)
        return 1
    for outcome in outcomes:
        unconverged = [p for p in outcome.response.points if not p.converged]
        print(f"{outcome.case.name}: {len(outcome.response.points)} points, "
              f"{len(unconverged)} not converged -> {outcome.directory}/response.csv{_also(outcome.files)}")
        _print_summary(outcome.summary, outcome.plan)
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0
