"""``bodebench calibrate``: the calibration curves of the friction-link identification."""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

log = logging.getLogger("bodebench")


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
