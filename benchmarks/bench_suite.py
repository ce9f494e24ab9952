"""Wall time of the test suite on a busy machine: the README's test command beside CPU-bound processes.

Run: python benchmarks/bench_suite.py [--busy 2] [--slow]

The README's second command (its test command: the part after its ``pip install ... &&``) runs from the repository
root in a shell while ``--busy`` processes (default 2) spin a CPU-bound loop each; they are killed when it ends,
whatever way it ends. Printed: tests passed and failed, and the command's wall time against the target, 300 s
beside two CPU-bound processes on a 2-core machine. ``--slow`` then times the tests marked ``slow``
(``python -m pytest -n 2 -m slow``, which CI runs after the README's command) the same way; that tier has no
target. Prints figures only; the exit status is the suite's.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGET_S = 300.0
SLOW_TIER = "python -m pytest -n 2 -m slow"
BUSY_LOOP = "while True: pass"
SUMMARY = re.compile(r"^=*\s*(\d+ (?:passed|failed|error).*?) in [0-9.]+s", re.M)


def readme_test_command() -> str:
    """The README's test command: the second line of its first ``sh`` block, without its ``pip install``."""
    block = re.search(r"```sh\n(.*?)```", (ROOT / "README.md").read_text(encoding="utf-8"), re.S)
    if block is None or len(block.group(1).splitlines()) < 2:
        raise SystemExit("README.md: no sh block with two commands at its start")
    return block.group(1).splitlines()[1].split("&&")[-1].strip()


def timed_beside_busy(command: str, busy: int) -> tuple[int, float, str]:
    """Run ``command`` in a shell at the repository root beside ``busy`` CPU-bound processes:
    (exit status, wall time in s, pytest's summary line)."""
    loops = [subprocess.Popen([sys.executable, "-c", BUSY_LOOP]) for _ in range(busy)]
    try:
        start = time.perf_counter()
        run = subprocess.run(command, shell=True, cwd=ROOT, capture_output=True, text=True)
        wall = time.perf_counter() - start
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()
    summaries = SUMMARY.findall(run.stdout)
    return run.returncode, wall, summaries[-1] if summaries else "no pytest summary"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--busy", type=int, default=2, help="CPU-bound processes beside the suite (default 2)")
    parser.add_argument("--slow", action="store_true", help=f"then time the slow tier ({SLOW_TIER})")
    args = parser.parse_args(argv)
    command = readme_test_command()
    status, wall, summary = timed_beside_busy(command, args.busy)
    verdict = "met" if status == 0 and wall <= TARGET_S else "NOT met"
    print(f"README's test command ({command}) beside {args.busy} CPU-bound processes: {summary}, "
          f"exit {status}, {wall:.0f} s wall (target <= {TARGET_S:.0f} s: {verdict})")
    if args.slow:
        slow_status, slow_wall, slow_summary = timed_beside_busy(SLOW_TIER, args.busy)
        print(f"slow tier ({SLOW_TIER}) beside {args.busy} CPU-bound processes: {slow_summary}, "
              f"exit {slow_status}, {slow_wall:.0f} s wall (no target; CI runs it after the README's command)")
        status = status or slow_status
    return status


if __name__ == "__main__":
    sys.exit(main())
