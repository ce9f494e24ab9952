"""The ``bodebench`` command."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

from instrument.config import ConfigError, ExperimentConfig, load_config
from instrument.response import ResultsError


def _simulate(args: argparse.Namespace) -> int:
    from instrument.experiment import default_executor, sweep, write_case
    from instrument.response import FrequencyResponse

    config: ExperimentConfig = load_config(args.config)
    out = Path(args.out)
    started = time.perf_counter()
    executor = None if args.jobs == 1 else default_executor(args.jobs)
    try:
        for case in config.cases:
            directory = out / case.name if config.has_cases else out
            partial = FrequencyResponse(config=case.raw, case=case.name)
            total = len(case.excitation.frequencies_hz)
            done = 0

            def saved(points: list, directory: Path = directory, partial: FrequencyResponse = partial) -> None:
                nonlocal done
                for p in points:
                    partial.write_point(directory, p)
                done += 1
                if not args.quiet:
                    f = points[0].frequency_hz
                    worst = max(p.periods for p in points)
                    print(f"{case.name}: {done}/{total}  f = {f:g} Hz  {worst} periods", file=sys.stderr)

            response = sweep(case, executor, on_point=saved)
            files = write_case(response, directory)
            unconverged = [p for p in response.points if not p.converged]
            print(f"{case.name or config.path.stem}: {len(response.points)} points, "
                  f"{len(unconverged)} not converged -> {directory}/response.csv "
                  f"(+ {', '.join(f.name for f in files)})")
    finally:
        if executor is not None:
            executor.shutdown(cancel_futures=True)
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="bodebench", description=__doc__.strip().splitlines()[0] if __doc__ else "")
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser("simulate", help="sweep a simulated plant offline (the papers' computational experiment)")
    sim.add_argument("config", help="TOML experiment file")
    sim.add_argument("--out", required=True, help="results directory (one sub-directory per case)")
    sim.add_argument("--jobs", type=int, default=None,
                     help="worker processes (default: all cores; 1 runs in this process)")
    sim.add_argument("--quiet", action="store_true", help="no progress lines")
    sim.set_defaults(handler=_simulate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``bodebench`` command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args))
    except (ConfigError, ResultsError) as exc:
        print(f"bodebench: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bodebench: interrupted; points already measured are on disk", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
