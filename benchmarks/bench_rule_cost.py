"""What the stopping rules cost per period: CPU microseconds per period per series, every criterion.

Run: python benchmarks/bench_rule_cost.py [--repeat 3] [--every 1] [--against REV]

Series: the first harmonic of the position output of the paper's two plants (configs/paper2013.toml, input
amplitude A_F, eps 0.01 %, n_k = 1, l = 5, max_periods 20000) on its 42-frequency grid (``--every k``: every k-th
frequency), simulated from rest the way measure_frequency does it (step 1/(K_f f), harmonics 1 and 2, so that
the scale handed to the rules is the channel's largest coefficient):
  linear    LinearOscillator(m, K_p, damping ratio 0.05)
  friction  CoulombOscillator(m, K_p, F_ct = 0.008), Fbar 0.8
each clean and with white noise on every sample (seeded) of 1 % of the linear oscillator's steady output
amplitude at that frequency. Every criterion is replayed period by period on its own SeriesHistory with a fresh
rule, as the Autointegrator calls it (check, then the capped verdict at max_periods), the history growing 256
periods at a time as in an offline sweep; the CPU time (time.process_time) of those calls, stop included, over
the periods checked is the figure. Each series is replayed ``--repeat`` times on the same coefficients and its
least CPU time taken (a busy machine only ever adds to it). A warm-up replay of every criterion comes first, so
that imports done on first use are not counted.

Then the whole call path: Autointegrator.feed on the linear oscillator at 2 f_n with 1 % noise (harmonics 1
and 2, the default rule), fed one period at a time (a bench) and 256 at a time (a sweep), its integrator's
answers recorded on a first pass and handed back in turn: what the Autointegrator adds to its integrator per
period per series (least of ``--repeat`` runs).

Then one long series that no rule can close, the friction link at Fbar 0.6 at its natural frequency (a beat that
never dies: capped at max_periods): the default rule's cost per period over periods 1..1000, 1000..5000 and
5000..20000, to show that it does not grow with the record.

``--against REV``: instead, the default rule of this tree against the one of git revision REV (its
bodebench/core/rules package, or the single module rules.py before it, loaded beside this one), replayed in one
process series by series in turn (least of ``--repeat`` each), on the same four grids: both figures, their ratio,
whether every series stopped at the same period with the same status and method, and how far apart the values are
(relative). Turn by turn, a machine whose speed wanders slows both alike.

Target: at most 5 us per period per series. Prints figures only.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import subprocess
import sys
import tempfile
import time
import types
from dataclasses import replace
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bodebench.bench.offline import OUTPUT_CHANNEL  # noqa: E402
from bodebench.core.autointegration import Autointegrator  # noqa: E402
from bodebench.core.fourier import PeriodIntegrator  # noqa: E402
from bodebench.core.rules import (  # noqa: E402
    CRITERIA,
    AdaptiveRule,
    SeriesHistory,
    StoppingRule,
    Verdict,
    make_rule,
)
from bodebench.io.config import AnalysisConfig, load_config  # noqa: E402
from bodebench.sim.plants import CoulombOscillator, LinearOscillator, Plant  # noqa: E402

CONFIG = ROOT / "configs" / "paper2013.toml"
FRICTION_CASE = "fbar_0.8"
DAMPING_RATIO = 0.05
NOISE_RELATIVE = 0.01
HARMONICS = (1, 2)
CHUNK_PERIODS = 256
LONG_FBAR = 0.6
BANDS = ((0, 1000), (1000, 5000), (5000, 20000))
TARGET_US = 5.0


def git(*args: str) -> str:
    """The output of a git command run in the repository."""
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True, text=True).stdout


def rules_at(revision: str) -> types.ModuleType:
    """bodebench.core.rules as git revision ``revision`` had it, loaded as a module of its own: the single module
    instrument/core/rules.py where the revision has it, else the package instrument/core/rules/, written out to
    a temporary folder under a name of its own (its imports of its own modules renamed alike)."""
    name = f"rules_at_{git('rev-parse', '--short=12', revision).strip()}"
    files = git("ls-tree", "--name-only", revision, "instrument/core/").split()
    if "instrument/core/rules.py" in files:
        source = git("show", f"{revision}:instrument/core/rules.py")
        module = types.ModuleType(name)
        sys.modules[module.__name__] = module  # dataclasses look their module up
        exec(compile(source, f"{revision}:instrument/core/rules.py", "exec"), module.__dict__)
        return module
    folder = Path(tempfile.mkdtemp(prefix="bench_rule_cost_")) / name
    folder.mkdir()
    for path in git("ls-tree", "--name-only", revision, "instrument/core/rules/").split():
        if path.endswith(".py"):
            source = git("show", f"{revision}:{path}").replace("bodebench.core.rules", name)
            (folder / Path(path).name).write_text(source)
    sys.path.insert(0, str(folder.parent))
    return importlib.import_module(name)


def against(revision: str, plants: dict[str, Plant], freqs: tuple[float, ...], amplitude: float,
            analysis: AnalysisConfig, steady: np.ndarray, repeat: int) -> None:
    """The default rule of this tree against revision's, series by series in turn (see the module docstring)."""
    modules = {revision: rules_at(revision), "this tree": sys.modules[AdaptiveRule.__module__]}

    print(f"adaptive, {revision} against this tree, series by series in turn; CPU us per period per series")
    for name, plant in plants.items():
        for label, noise in (("clean", None), ("1% noise", NOISE_RELATIVE * steady)):
            seconds = dict.fromkeys(modules, 0.0)
            periods, same, moved = 0, True, 0.0
            for i, f in enumerate(freqs):
                sim = Simulation(plant, f, amplitude, analysis.steps_per_period,
                                 0.0 if noise is None else float(noise[i]), 1000 + i)
                best = dict.fromkeys(modules, math.inf)
                verdicts = {}
                for _ in range(repeat):
                    for key, module in modules.items():
                        rule = module.AdaptiveRule(analysis.tolerance_percent, analysis.skip_periods,
                                                   max_periods=analysis.max_periods)
                        spent, _, verdicts[key] = cost(sim, rule, module.SeriesHistory(), analysis)
                        best[key] = min(best[key], spent)
                for key in modules:
                    seconds[key] += best[key]
                periods += verdicts["this tree"].period
                same &= len({(v.period, v.status, v.method) for v in verdicts.values()}) == 1
                old, new = (complex(verdicts[key].p, verdicts[key].q) for key in modules)
                moved = max(moved, abs(new - old) / max(abs(old), 1e-300))
            old_us, new_us = (seconds[key] / periods * 1e6 for key in modules)
            print(f"  {name} {label}: {revision} {old_us:.2f}, this tree {new_us:.2f} ({periods} periods); ratio "
                  f"{new_us / old_us:.2f}; {'the same' if same else 'NOT the same'} stops (period, status, method), "
                  f"values apart by at most {moved:.1e} of themselves")


def fresh_rule(criterion: str, analysis: AnalysisConfig) -> StoppingRule:
    return make_rule(criterion, tolerance_percent=analysis.tolerance_percent, skip_periods=analysis.skip_periods,
                     window=analysis.window, settle_periods=analysis.settle_periods,
                     average_periods=analysis.average_periods, max_periods=analysis.max_periods)


def replay(rule: StoppingRule, hist: SeriesHistory, reference: np.ndarray, start: int, stop: int,
           max_periods: int) -> tuple[Verdict | None, int]:
    """Check periods start+1..stop as the Autointegrator does; (the verdict, None: none yet; last period checked)."""
    for n in range(start + 1, stop + 1):
        verdict = rule.check(hist, n, float(reference[n - 1]))
        if verdict is None and n >= max_periods:
            verdict = rule.capped(hist, n, float(reference[n - 1]))
        if verdict is not None:
            return verdict, n
    return None, stop


class Simulation:
    """Per-period coefficients of one plant at one frequency from rest, simulated on demand (harmonics 1, 2)."""

    def __init__(self, plant: Plant, frequency_hz: float, amplitude: float, steps: int, noise_std: float,
                 seed: int) -> None:
        self.plant, self.frequency_hz, self.amplitude, self.steps = plant, frequency_hz, amplitude, steps
        self.noise_std = noise_std
        self.rng = np.random.default_rng(seed)
        self.channel = plant.output_names.index(OUTPUT_CHANNEL)
        self.h = 1.0 / (steps * frequency_hz)
        self.integ = PeriodIntegrator(frequency_hz, HARMONICS, 1)
        self.integ.feed(np.array([0.0]), np.zeros((1, 1)))
        self.state = plant.initial_state()
        self.step = 0
        self.z = np.empty(0, dtype=complex)      # first harmonic, periods 1..
        self.scale = np.empty(0)                 # largest coefficient of each period

    def extend_to(self, periods: int) -> None:
        while self.z.size < periods:
            n = min(CHUNK_PERIODS, periods - self.z.size) * self.steps
            y = self.plant.run_sine(self.state, self.step * self.h, self.h, n, self.amplitude,
                                    self.frequency_hz)[:, self.channel]
            if self.noise_std > 0.0:
                y = y + self.rng.normal(0.0, self.noise_std, n)
            t = (self.step + 1 + np.arange(n)) * self.h
            self.step += n
            p, q = self.integ.feed(t, y[:, None])
            z = (p + 1j * q)[:, 0, :]
            self.z = np.concatenate([self.z, z[:, 0]])
            self.scale = np.concatenate([self.scale, np.max(np.abs(z), axis=1)])


def cost(sim: Simulation, rule: StoppingRule, hist: SeriesHistory, analysis: AnalysisConfig
         ) -> tuple[float, int, Verdict]:
    """(CPU seconds of the rule's calls, periods checked, the verdict) for a fresh rule on one series, its history
    (empty) filled as an offline sweep fills it."""
    seconds, verdict, checked = 0.0, None, 0
    while verdict is None:
        target = min(checked + CHUNK_PERIODS, analysis.max_periods)
        sim.extend_to(target)
        hist.extend(sim.z[hist.n:target])
        started = time.process_time()
        verdict, checked = replay(rule, hist, sim.scale, checked, hist.n, analysis.max_periods)
        seconds += time.process_time() - started
    return seconds, checked, verdict


def grid_costs(plant: Plant, freqs: tuple[float, ...], amplitude: float, analysis: AnalysisConfig,
               noise: np.ndarray | None, repeat: int) -> dict[str, tuple[float, int]]:
    """Per criterion: (CPU seconds over the grid, each series' the least of ``repeat`` replays; periods checked)."""
    out: dict[str, tuple[float, int]] = {}
    sims = [Simulation(plant, f, amplitude, analysis.steps_per_period, 0.0 if noise is None else float(noise[i]),
                       1000 + i) for i, f in enumerate(freqs)]
    for c in CRITERIA:
        total, periods = 0.0, 0
        for sim in sims:
            runs = [cost(sim, fresh_rule(c, analysis), SeriesHistory(), analysis) for _ in range(repeat)]
            total += min(run[0] for run in runs)
            periods += runs[0][1]
        out[c] = (total, periods)
    return out


def long_run(analysis: AnalysisConfig, pc_mass: float, pc_stiffness: float, amplitude: float,
             repeat: int) -> list[float]:
    """The default rule's us/period in each band of BANDS on a series it cannot close."""
    plant = CoulombOscillator(pc_mass, pc_stiffness, LONG_FBAR * amplitude)
    sim = Simulation(plant, plant.natural_frequency_hz, amplitude, analysis.steps_per_period, 0.0, 7)
    sim.extend_to(analysis.max_periods)
    per_band: list[list[float]] = [[] for _ in BANDS]
    for _ in range(repeat):
        hist = SeriesHistory()
        hist.extend(sim.z)
        rule = AdaptiveRule(analysis.tolerance_percent, analysis.skip_periods, max_periods=analysis.max_periods)
        for i, (a, b) in enumerate(BANDS):
            started = time.process_time()
            verdict, _ = replay(rule, hist, sim.scale, a, b, analysis.max_periods)
            per_band[i].append((time.process_time() - started) / (b - a) * 1e6)
            if verdict is not None and b < analysis.max_periods:
                raise RuntimeError("the long series was closed before max_periods")
    return [min(v) for v in per_band]


def sampler_overhead(plant: Plant, frequency_hz: float, amplitude: float, analysis: AnalysisConfig,
                     noise_std: float, chunk_periods: int, repeat: int) -> tuple[float, int, int]:
    """(us per period per series, periods, series) the Autointegrator adds to its integrator: the CPU time of
    feed() with its integrator's answers (recorded on a first pass) handed back in turn instead of worked out,
    least of ``repeat`` runs, fed in chunks of ``chunk_periods`` periods until every series has its verdict."""
    steps = analysis.steps_per_period
    h = 1.0 / (steps * frequency_hz)
    n = analysis.max_periods * steps
    y = plant.run_sine(plant.initial_state(), 0.0, h, n, amplitude, frequency_hz)[:, :1]
    y = y + np.random.default_rng(11).normal(0.0, noise_std, y.shape)
    t = (1 + np.arange(n)) * h
    cut = chunk_periods * steps

    def sampler() -> Autointegrator:
        fresh = Autointegrator(frequency_hz, amplitude, (OUTPUT_CHANNEL,), analysis)
        fresh.feed(np.array([0.0]), np.zeros((1, 1)))
        return fresh

    recording, answers = sampler(), []
    integrate = recording._integrator.feed_marked

    def recorded(t_chunk: np.ndarray, y_chunk: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        answers.append(integrate(t_chunk, y_chunk))
        return tuple(a.copy() for a in answers[-1])  # type: ignore[return-value]

    recording._integrator.feed_marked = recorded  # type: ignore[method-assign]
    fed = 0
    while not recording.done:
        recording.feed(t[fed:fed + cut], y[fed:fed + cut])
        fed += cut
    spent = []
    for _ in range(repeat):
        replayed = sampler()
        replies = iter([tuple(a.copy() for a in answer) for answer in answers])
        replayed._integrator.feed_marked = lambda _t, _y, replies=replies: next(replies)  # type: ignore[method-assign]
        started = time.process_time()
        for _ in answers:
            replayed.feed(t[:0], y[:0])
        spent.append(time.process_time() - started)
        if not replayed.done or replayed.periods != recording.periods:
            raise RuntimeError("the replayed feed did not end where the recorded one did")
    series = len(analysis.harmonics)
    return min(spent) / (recording.periods * series) * 1e6, recording.periods, series


def warm_up(plant: Plant, frequency_hz: float, amplitude: float, analysis: AnalysisConfig) -> None:
    """Every criterion once on a short noisy series, untimed: the imports rules make on first use happen here."""
    sim = Simulation(plant, frequency_hz, amplitude, analysis.steps_per_period, 1e-3 * amplitude, 0)
    short = replace(analysis, max_periods=300)
    for c in CRITERIA:
        cost(sim, fresh_rule(c, short), SeriesHistory(), short)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="replays of every series (the least CPU time taken)")
    parser.add_argument("--every", type=int, default=1, help="every k-th frequency of the grid")
    parser.add_argument("--against", metavar="REV", help="the default rule against git revision REV's, in turn")
    args = parser.parse_args()
    config = load_config(CONFIG)
    case = next(c for c in config.cases if c.name == FRICTION_CASE)
    analysis, pc = case.analysis, case.plant
    amplitude = case.excitation.amplitude
    freqs = tuple(case.excitation.frequencies_hz)[:: args.every]
    linear = LinearOscillator(pc.mass, pc.stiffness, DAMPING_RATIO)
    plants: dict[str, Plant] = {"linear": linear,
                                "friction": CoulombOscillator(pc.mass, pc.stiffness, pc.friction)}
    print(f"{len(freqs)} frequencies {freqs[0]:g}..{freqs[-1]:g} Hz; eps {analysis.tolerance_percent:g} %, "
          f"n_k = {analysis.skip_periods}, l = {analysis.window}, max_periods {analysis.max_periods}; "
          f"least of {args.repeat} replays; CPU us per period per series (periods checked)")
    started = time.perf_counter()
    warm_up(plants["friction"], freqs[0], amplitude, analysis)
    columns: dict[str, dict[str, tuple[float, int]]] = {}
    steady = np.abs(linear.frequency_response(np.array(freqs))[:, 0]) * amplitude
    if args.against:
        against(args.against, plants, freqs, amplitude, analysis, steady, args.repeat)
        print(f"{time.perf_counter() - started:.0f} s")
        return
    for name, plant in plants.items():
        for label, noise in (("clean", None), ("1% noise", NOISE_RELATIVE * steady)):
            columns[f"{name} {label}"] = grid_costs(plant, freqs, amplitude, analysis, noise, args.repeat)
    print(f"{'criterion':<14}" + "".join(f"{col:>22}" for col in columns))
    worst = 0.0
    for c in CRITERIA:
        cells = []
        for col in columns.values():
            seconds, periods = col[c]
            us = seconds / periods * 1e6
            worst = max(worst, us)
            cells.append(f"{us:>10.2f} ({periods:>8})")
        print(f"{c:<14}" + "".join(f"{cell:>22}" for cell in cells))
    fn = linear.natural_frequency_hz
    noise = NOISE_RELATIVE * float(np.abs(linear.frequency_response(np.array([2.0 * fn]))[0, 0])) * amplitude
    for chunk in (1, CHUNK_PERIODS):
        us, periods, series = sampler_overhead(linear, 2.0 * fn, amplitude, analysis, noise, chunk, args.repeat)
        worst = max(worst, us)
        print(f"Autointegrator.feed beyond its integrator, linear 1% noise at 2 f_n, {series} series, chunks of "
              f"{chunk} period(s): {us:.2f} us per period per series over {periods} periods")
    bands = long_run(analysis, pc.mass, pc.stiffness, amplitude, args.repeat)
    print(f"adaptive on the friction link at Fbar {LONG_FBAR:g}, f = f_n (capped at {analysis.max_periods}): "
          + ", ".join(f"periods {a + 1}..{b}: {us:.2f} us/period" for (a, b), us in zip(BANDS, bands, strict=True)))
    worst = max(worst, *bands)
    print(f"worst: {worst:.2f} us per period per series (target <= {TARGET_US:g}: "
          f"{'met' if worst <= TARGET_US else 'NOT met'}); {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
