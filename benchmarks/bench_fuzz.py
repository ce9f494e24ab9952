"""The configuration loader against many seeded mutants of the shipped configs (tests/config_mutants.py; the test
suite runs a few hundred of the same kind).

Run: python benchmarks/bench_fuzz.py [count]   (default 20,000 mutants, about a minute)

Prints how many mutants were accepted and refused, the defects found (a traceback-worthy exception, a refusal not
one line naming the file) against the target of none, the known-nonsense edits accepted against the target of none,
and the slowest load.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from config_mutants import judge_mutant, mutants, nonsense_mutants  # noqa: E402

from bodebench.io.config import ConfigError, parse_config  # noqa: E402

SEED = 2026
DEFAULT_COUNT = 20_000


def main(argv: list[str]) -> int:
    count = int(argv[0]) if argv else DEFAULT_COUNT
    defects: list[str] = []
    accepted = 0
    slowest = 0.0
    start = time.perf_counter()
    for mutant in mutants(SEED, count):
        before = time.perf_counter()
        taken, defect = judge_mutant(mutant)
        slowest = max(slowest, time.perf_counter() - before)
        accepted += taken
        if defect:
            defects.append(defect)
    took = time.perf_counter() - start
    nonsense_accepted = []
    for _, mutant in nonsense_mutants():
        try:
            parse_config(mutant.data, mutant.source)
            nonsense_accepted.append(f"{mutant.source}: {mutant.edits[0]}")
        except ConfigError:
            pass
    print(f"{count} mutants in {took:.1f} s: {accepted} accepted, {count - accepted - len(defects)} refused in one "
          f"line; slowest load {1e3 * slowest:.0f} ms")
    print(f"defects: {len(defects)} (target 0)")
    for defect in defects[:20]:
        print(f"  {defect}")
    print(f"known nonsense accepted: {len(nonsense_accepted)} (target 0)")
    for line in nonsense_accepted:
        print(f"  {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
