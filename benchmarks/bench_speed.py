"""Speed of the offline experiment and of the compiled Coulomb-friction kernel.

Run: python benchmarks/bench_speed.py

1. The 2013 experiment (configs/paper2013.toml, 3 cases x 42 frequencies x harmonics 1 and 2) run the way
   ``bodebench simulate`` runs it: ``bodebench.bench.offline.sweep`` on every case with one
   ``default_executor()`` process pool over all cores (no files written). A warm-up first runs one short
   frequency of every plant model in this process so that the numba kernels are compiled (or loaded from
   numba's on-disk cache) before the clock starts; the pool's workers then load the cached kernels.
   Periods: "needed" is what the points report (per frequency, the most any of its series needed);
   "simulated" is what measure_frequency actually integrated, which rounds the needed periods up to its
   batch schedule (FIRST_BATCH_PERIODS doubling to MAX_BATCH_PERIODS, capped at max_periods).
2. Integration steps per second of CoulombOscillator.run_sine (Fbar 0.8, f = 3 Hz, K_f = 200): compiled,
   2e6 steps, and the same code in plain Python (a subprocess with NUMBA_DISABLE_JIT=1, 2e4 steps).

Targets: whole experiment < 30 s; compiled / plain Python >= 30x. Prints figures only.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

from bodebench.bench import offline as experiment
from bodebench.core.response import FrequencyResponse
from bodebench.io.config import load_config
from bodebench.sim.plants import CoulombOscillator, LinearOscillator

ROOT = Path(__file__).resolve().parent.parent

CONFIG = ROOT / "configs" / "paper2013.toml"
KERNEL_FRICTION = 0.008  # F_ct for Fbar 0.8 at A_F = 0.01
KERNEL_FREQUENCY_HZ = 3.0
KERNEL_STEPS_PER_PERIOD = 200
COMPILED_STEPS = 2_000_000
PLAIN_STEPS = 20_000
REPEATS = 3
TARGET_EXPERIMENT_S = 30.0
TARGET_RATIO = 30.0


def simulated_periods(needed: int, max_periods: int) -> int:
    """Periods measure_frequency integrates before a point that needs ``needed`` periods is done."""
    total = 0
    batch = experiment.FIRST_BATCH_PERIODS
    while total < needed:
        total += min(batch, max_periods - total)
        batch = min(2 * batch, experiment.MAX_BATCH_PERIODS)
    return total


def warm_up() -> float:
    """Compile (or load) the numba kernels in this process: one short frequency per plant model; seconds."""
    start = time.perf_counter()
    config = load_config(CONFIG)
    case = config.cases[0]
    short = replace(case, analysis=replace(case.analysis, max_periods=16))
    experiment.measure_frequency(short, 10.0)
    lin = LinearOscillator(2.533e-4, 1.0, 0.05)
    lin.run_sine(lin.initial_state(), 0.0, 1e-3, 10, 0.01, 3.0)
    return time.perf_counter() - start


def run_experiment() -> tuple[float, list[FrequencyResponse], int]:
    """The whole experiment as ``bodebench simulate`` runs it; (wall seconds, responses, workers)."""
    config = load_config(CONFIG)
    start = time.perf_counter()
    executor = experiment.default_executor()
    workers = os.cpu_count() or 1  # default_executor() sizes its pool so
    try:
        responses = [experiment.sweep(case, executor) for case in config.cases]
    finally:
        executor.shutdown(cancel_futures=True)
    return time.perf_counter() - start, responses, workers


def kernel_rate(n_steps: int, repeats: int) -> tuple[float, int]:
    """Best steps/s of CoulombOscillator.run_sine over ``repeats`` runs from rest; (rate, events per run)."""
    plant = CoulombOscillator(2.533e-4, 1.0, KERNEL_FRICTION)
    h = 1.0 / (KERNEL_STEPS_PER_PERIOD * KERNEL_FREQUENCY_HZ)
    plant.run_sine(plant.initial_state(), 0.0, h, 10, 0.01, KERNEL_FREQUENCY_HZ)  # compile / load
    best = 0.0
    events = 0
    for _ in range(repeats):
        state = plant.initial_state()
        before = plant.events
        start = time.perf_counter()
        plant.run_sine(state, 0.0, h, n_steps, 0.01, KERNEL_FREQUENCY_HZ)
        best = max(best, n_steps / (time.perf_counter() - start))
        events = plant.events - before
    return best, events


def plain_python_rate() -> tuple[float, int]:
    """The same kernel with numba's JIT disabled, in a subprocess; (steps/s, events per run)."""
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    code = (f"import sys; sys.path.insert(0, {str(ROOT)!r}); "
            "from benchmarks.bench_speed import kernel_rate; "
            f"r, e = kernel_rate({PLAIN_STEPS}, {REPEATS}); print(r, e)")
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True,
                         check=True)
    rate, events = out.stdout.split()
    return float(rate), int(events)


def main() -> None:
    print(f"warm-up (compiles or loads the numba kernels in this process): {warm_up():.1f} s")
    wall, responses, workers = run_experiment()
    points = sum(len(r.points) for r in responses)
    needed = simulated = unconverged = 0
    for r in responses:
        max_periods = int(r.config["analysis"]["max_periods"])
        per_frequency: dict[float, int] = {}
        for p in r.points:
            per_frequency[p.frequency_hz] = max(per_frequency.get(p.frequency_hz, 0), p.periods)
            unconverged += not p.converged
        needed += sum(per_frequency.values())
        simulated += sum(simulated_periods(n, max_periods) for n in per_frequency.values())
    steps_per_period = int(responses[0].config["analysis"]["steps_per_period"])

    print()
    print(f"experiment: {CONFIG.relative_to(ROOT)}, {len(responses)} cases, "
          f"sweep() with default_executor() ({workers} workers), no files written")
    print(f"  wall time              {wall:10.2f} s      (target < {TARGET_EXPERIMENT_S:g} s: "
          f"{'met' if wall < TARGET_EXPERIMENT_S else 'NOT met'})")
    print(f"  points                 {points:10d}        ({unconverged} not converged)")
    print(f"  periods needed         {needed:10d}        (per frequency, the most any of its series needed)")
    print(f"  periods simulated      {simulated:10d}        (rounded up to measure_frequency's batches)")
    print(f"  steps simulated        {simulated * steps_per_period:10.3e}        "
          f"({simulated * steps_per_period / wall:.3e} steps/s over the pool)")

    compiled, events_c = kernel_rate(COMPILED_STEPS, REPEATS)
    plain, events_p = plain_python_rate()
    ratio = compiled / plain
    print()
    print(f"CoulombOscillator.run_sine, Fbar 0.8, f = {KERNEL_FREQUENCY_HZ:g} Hz, "
          f"K_f = {KERNEL_STEPS_PER_PERIOD}, from rest, best of {REPEATS}")
    print(f"  compiled (numba)       {compiled:12,.0f} steps/s  ({COMPILED_STEPS:.0e} steps, "
          f"{events_c} friction events)")
    print(f"  plain Python           {plain:12,.0f} steps/s  ({PLAIN_STEPS:.0e} steps, "
          f"{events_p} friction events, NUMBA_DISABLE_JIT=1)")
    print(f"  ratio                  {ratio:12.0f} x        (target >= {TARGET_RATIO:g}x: "
          f"{'met' if ratio >= TARGET_RATIO else 'NOT met'})")


if __name__ == "__main__":
    main()
