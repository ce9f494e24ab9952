"""Run every benchmark in turn, each as its own process, and print its output.

Run: python benchmarks/run_all.py [name ...]   (names without .py; default: all, in the order below)

Benchmarks print figures and never assert; the exit status is non-zero only when a benchmark fails to run.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
BENCHMARKS: tuple[str, ...] = ("bench_sampler", "bench_speed", "bench_rules", "bench_rule_cost", "bench_pacing",
                                "bench_lockstep", "bench_tui", "bench_soak", "bench_fuzz",
                                "bench_zero_harmonics", "bench_fit", "bench_adaptive", "bench_suite")
"""All of them, about 35 minutes on 2 cores; the soak alone takes 10, the suite beside two busy processes 3."""


def run(name: str) -> tuple[int, float]:
    """Run benchmarks/<name>.py from the repository root, streaming its output; (exit status, seconds)."""
    script = HERE / f"{name}.py"
    if not script.is_file():
        raise ValueError(f"no benchmark named {name!r} ({script} does not exist)")
    start = time.perf_counter()
    status = subprocess.run([sys.executable, str(script)], cwd=ROOT).returncode
    return status, time.perf_counter() - start


def main(argv: list[str]) -> int:
    names = argv or list(BENCHMARKS)
    failed: list[str] = []
    for name in names:
        print(f"===== {name} =====", flush=True)
        status, seconds = run(name)
        print(f"===== {name}: {'ok' if status == 0 else f'FAILED (exit {status})'} in {seconds:.1f} s =====\n",
              flush=True)
        if status != 0:
            failed.append(name)
    if failed:
        print(f"failed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
