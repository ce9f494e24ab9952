"""Speed of the offline experiment against its kernel, cold and warm; the cost of starting the command.

Run: python benchmarks/bench_speed.py [--repeat 3]

1. The 2013 experiment (configs/paper2013.toml, 3 cases x 42 frequencies x harmonics 1 and 2) end to end, as a user
   runs it: ``bodebench simulate configs/paper2013.toml --out DIR --quiet`` in a subprocess (interpreter start,
   imports, the pool, the sweep, results and PNG plots written; Python caching compiled modules, as it does by
   default), wall time and CPU time of the process and its workers. Warm: numba's on-disk cache already holds the
   compiled kernels (least of ``--repeat`` runs). Cold: ``NUMBA_CACHE_DIR`` pointed at an empty directory, so the
   kernels are compiled (once: the pool's first worker compiles them while the others wait for the cache; the number
   of cache index files written is printed as the evidence).
2. The kernel alone on the same periods, in this process: for every frequency, the plant's ``run_sine`` over
   exactly the batches ``measure_frequency`` integrated for it (from the periods the run's CSV reports), CPU
   time summed over all frequencies (one core), least of three passes. The compiled kernels are loaded first and
   that load timed on its own: it is paid once per process (numba's initialisation and the cached machine code,
   about 0.2 s), by the command as it starts, not per period. The ratio end-to-end wall / kernel CPU is the
   figure of merit (target <= 2 on 2 cores: the whole experiment, plots included, costs at most twice its
   integration).
3. ``bodebench --help``: CPU time (user + system) of the process, mean of 5 runs (target < 0.3 s).

The per-period cost of the stopping rules is benchmarks/bench_rule_cost.py's. Prints figures only.
"""

from __future__ import annotations

import argparse
import csv
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from bodebench.bench import offline
from bodebench.io.config import load_config

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "paper2013.toml"
TARGET_RATIO = 2.0
TARGET_HELP_CPU_S = 0.3
HELP_RUNS = 5
KERNEL_PASSES = 3


def simulated_batches(needed: int, max_periods: int) -> list[int]:
    """The batches of periods measure_frequency integrates for a frequency whose points needed ``needed``."""
    batches: list[int] = []
    total, batch = 0, offline.FIRST_BATCH_PERIODS
    while total < needed:
        batches.append(min(batch, max_periods - total))
        total += batches[-1]
        batch = min(2 * batch, offline.MAX_BATCH_PERIODS)
    return batches


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def user_environment(**extra: str) -> dict[str, str]:
    """This process's environment as a user's shell has it: Python caches the modules it compiles (a
    PYTHONDONTWRITEBYTECODE set here, as some sandboxes and CI images do, would have every run compile the package
    from source), plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(extra)
    return env


def run_command(args: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """Run ``python -m bodebench ARGS`` (in ``env``, else :func:`user_environment`); (wall s, CPU s of it and its
    workers)."""
    before = children_cpu()
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "bodebench", *args], cwd=ROOT, env=env or user_environment(), check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - start, children_cpu() - before


def end_to_end(out: Path, cache: Path | None = None) -> tuple[float, float]:
    env = user_environment(NUMBA_CACHE_DIR=str(cache)) if cache is not None else None
    return run_command(["simulate", str(CONFIG), "--out", str(out), "--quiet"], env)


def kernel_load_cpu() -> float:
    """CPU s of loading the experiment's compiled kernels into this process (from numba's on-disk cache)."""
    from bodebench.apps.commands.common import plant_models
    from bodebench.sim.models import load_kernels

    start = time.process_time()
    load_kernels(plant_models(load_config(CONFIG)))
    return time.process_time() - start


def kernel_cpu(out: Path) -> tuple[float, int, int]:
    """CPU s of the plants' run_sine over the batches the run in ``out`` integrated (the kernels loaded already);
    (s, periods, steps)."""
    config = load_config(CONFIG)
    total_s, periods, steps = 0.0, 0, 0
    for case in config.cases:
        needed: dict[float, int] = defaultdict(int)
        with open(out / case.name / "response.csv", newline="") as fh:
            for row in csv.DictReader(row for row in fh if not row.startswith("#")):
                f = float(row["frequency_hz"])
                needed[f] = max(needed[f], int(row["periods"]))
        plant = offline.build_plant(case.plant)
        k_f = case.analysis.steps_per_period
        for f, n in needed.items():
            h = 1.0 / (k_f * f)
            state, step = plant.initial_state(), 0
            start = time.process_time()
            for batch in simulated_batches(n, case.analysis.max_periods):
                plant.run_sine(state, step * h, h, batch * k_f, case.excitation.amplitude, f)
                step += batch * k_f
            total_s += time.process_time() - start
            periods += step // k_f
            steps += step
    return total_s, periods, steps


def help_cpu() -> float:
    return sum(run_command(["--help"])[1] for _ in range(HELP_RUNS)) / HELP_RUNS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="warm end-to-end runs (least taken)")
    args = parser.parse_args()
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        cache = base / "numba-cache"
        cache.mkdir()
        cold_wall, cold_cpu = end_to_end(base / "cold", cache)
        compiled = sorted(p.name for p in cache.rglob("*.nbi"))
        end_to_end(base / "prime")  # the repository's own cache, primed
        warm = [end_to_end(base / f"warm{i}") for i in range(args.repeat)]
        warm_wall, warm_cpu = min(warm)
        load_s = kernel_load_cpu()
        passes = [kernel_cpu(base / "warm0") for _ in range(KERNEL_PASSES)]
        kernel_s, periods, steps = min(passes)
        help_s = help_cpu()

    ratio = warm_wall / kernel_s
    print(f"experiment: {CONFIG.relative_to(ROOT)} (3 cases x 42 frequencies, harmonics 1 and 2), "
          f"bodebench simulate --quiet, {cores} cores, PNG plots written")
    print(f"  kernel alone            {kernel_s:8.2f} s CPU   ({periods} periods, {steps:.3e} steps, "
          f"{steps / kernel_s:.3e} steps/s, one core; least of {KERNEL_PASSES}: "
          f"{', '.join(f'{p[0]:.2f}' for p in passes)} s)")
    print(f"  kernels' load           {load_s:8.2f} s CPU   (once per process, before the first step; not in the "
          f"figure above)")
    print(f"  end to end, warm cache  {warm_wall:8.2f} s wall  ({warm_cpu:.2f} s CPU; least of {args.repeat}; "
          f"all runs {', '.join(f'{w:.2f}' for w, _ in warm)} s)")
    print(f"  end to end, cold cache  {cold_wall:8.2f} s wall  ({cold_cpu:.2f} s CPU; {len(compiled)} kernels "
          f"compiled into an empty numba cache)")
    print(f"  warm wall / kernel CPU  {ratio:8.2f} x      (target <= {TARGET_RATIO:g}: "
          f"{'met' if ratio <= TARGET_RATIO else 'NOT met'})")
    print()
    print(f"bodebench --help          {help_s:8.3f} s CPU   (mean of {HELP_RUNS}; target < {TARGET_HELP_CPU_S:g} s: "
          f"{'met' if help_s < TARGET_HELP_CPU_S else 'NOT met'})")


if __name__ == "__main__":
    main()
