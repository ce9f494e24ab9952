"""Evidence for the default stopping rule: every criterion on the paper's 42-frequency grid, two plants.

Run: python benchmarks/bench_rules.py

Plants (parameters from configs/paper2013.toml, input amplitude A = A_F):
  linear    LinearOscillator(m, K_p, damping ratio 0.05); truth: the exact frequency_response().
  friction  CoulombOscillator(m, K_p, F_ct = 0.008), Fbar 0.8; truth: a long run, the fixed scheme settle 2000,
            average 200. It is checked against a longer one (settle 4000, average 400) and by the change of the
            per-period coefficients over the last 400 periods of the 4400 simulated.

Analysis: the config's [analysis] table (eps 0.01 %, n_k = 1, l = 5, K_f = 200, max_periods 20000), the
first harmonic of the position output. Each frequency is simulated once from rest, the way measure_frequency
does it (plant at rest, step 1/(K_f f), harmonics 1 and 2 integrated per period so that the scale passed to
the rules is the same); the per-period coefficients are kept and every criterion is replayed period by period
on its own SeriesHistory with a fresh rule, exactly as the Autointegrator calls it (a point still undecided at
max_periods takes the rule's capped verdict). A few frequencies are also run through measure_frequency itself
to show that the replay gives the same points.

Then the smallest fixed scheme "settle N, average M" (the same N and M at every frequency, N + M minimal)
whose estimate is within 0.01 dB and 0.05 deg of the truth at all 42 frequencies is searched exhaustively over
the simulated periods; the target is that the default rule's total periods are at most half of 42 (N + M).

Noise case (linear plant): white Gaussian noise of standard deviation 1 % of the steady output amplitude is
added to every sample; for "adaptive" and "full", the periods used and how often the reported ~95 %
uncertainty (Verdict.uncertainty, a half-width of the confidence region of (P, Q)) covers the true error
|Z - Z_true|, over several noise seeds.

Frequencies run in parallel on a process pool over all cores, one BLAS thread each.
Writes benchmarks/out/rules.png and rules.svg. Prints figures only.
"""

from __future__ import annotations

import math
import os
import sys
import time
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

# one BLAS thread per process: the work is spread over processes, and the rules' many tiny least-squares
# fits only slow down when OpenBLAS threads compete for the same cores (set before numpy is imported)
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from bodebench.bench.offline import OUTPUT_CHANNEL, build_plant, measure_frequency  # noqa: E402
from bodebench.core.fourier import PeriodIntegrator  # noqa: E402
from bodebench.core.rules import CAPPED, CRITERIA, SeriesHistory, StoppingRule, make_rule  # noqa: E402
from bodebench.io.config import AnalysisConfig, CaseConfig, PlantConfig, load_config  # noqa: E402
from bodebench.sim.plants import LinearOscillator, Plant  # noqa: E402

CONFIG = ROOT / "configs" / "paper2013.toml"
OUT = Path(__file__).resolve().parent / "out"
FRICTION_CASE = "fbar_0.8"
DAMPING_RATIO = 0.05
GAIN_TOL_DB = 0.01
PHASE_TOL_DEG = 0.05
REFERENCE = (2000, 200)        # friction truth: settle, average
REFERENCE_CHECK = (4000, 400)  # the longer run it is compared with
KEEP_PERIODS = REFERENCE_CHECK[0] + REFERENCE_CHECK[1]  # periods simulated at least (fixed-scheme search too)
CHUNK_PERIODS = 256
NOISE_RELATIVE = 0.01
NOISE_SEEDS = (1, 2, 3)
NOISE_CRITERIA = ("adaptive", "full")
CROSS_CHECK_HZ = (2.0, 10.03, 100.0)
HARMONICS = (1, 2)


@dataclass(frozen=True)
class Outcome:
    """One criterion's verdict on the first-harmonic series of one frequency."""

    period: int
    z: complex
    uncertainty: float
    status: str
    method: str


@dataclass(frozen=True)
class PointRun:
    """Verdicts of every replayed criterion at one frequency, and the kept per-period coefficients Z(1..)."""

    frequency_hz: float
    outcomes: dict[str, Outcome]
    series: np.ndarray
    simulated: int


def fresh_rule(criterion: str, analysis: AnalysisConfig) -> StoppingRule:
    return make_rule(criterion, tolerance_percent=analysis.tolerance_percent, skip_periods=analysis.skip_periods,
                     window=analysis.window, settle_periods=analysis.settle_periods,
                     average_periods=analysis.average_periods)


def replay_point(plant: Plant, frequency_hz: float, amplitude: float, analysis: AnalysisConfig,
                 criteria: tuple[str, ...], keep_periods: int, noise_std: float = 0.0,
                 seed: int = 0) -> PointRun:
    """Simulate one frequency from rest and replay every criterion on its first-harmonic coefficients.

    Simulates until every criterion has a verdict (or max_periods) and at least ``keep_periods`` periods;
    noise_std (output units) adds white Gaussian noise to every sample.
    """
    rng = np.random.default_rng(seed)
    channel = plant.output_names.index(OUTPUT_CHANNEL)
    steps = analysis.steps_per_period
    h = 1.0 / (steps * frequency_hz)
    integ = PeriodIntegrator(frequency_hz, HARMONICS, 1)
    integ.feed(np.array([0.0]), np.zeros((1, 1)))
    state = plant.initial_state()
    hist = SeriesHistory()
    scale: list[np.ndarray] = []
    rules = {c: fresh_rule(c, analysis) for c in criteria}
    checked = dict.fromkeys(criteria, 0)
    outcomes: dict[str, Outcome] = {}
    step = 0
    while True:
        pending = [c for c in criteria if c not in outcomes]
        target = max(keep_periods, analysis.max_periods if pending else 0)
        if hist.n >= target:
            break
        periods = min(CHUNK_PERIODS, target - hist.n)
        n = periods * steps
        y = plant.run_sine(state, step * h, h, n, amplitude, frequency_hz)[:, channel]
        if noise_std > 0.0:
            y = y + rng.normal(0.0, noise_std, n)
        t = (step + 1 + np.arange(n)) * h
        step += n
        p, q = integ.feed(t, y[:, None])
        z = (p + 1j * q)[:, 0, :]  # (periods, harmonics)
        hist.extend(z[:, 0])
        scale.append(np.max(np.abs(z), axis=1))  # the Autointegrator's reference: largest coefficient
        reference = np.concatenate(scale)
        for c in pending:
            rule = rules[c]
            for k in range(checked[c] + 1, hist.n + 1):
                verdict = rule.check(hist, k, float(reference[k - 1]))
                if verdict is None and k >= analysis.max_periods:
                    verdict = rule.capped(hist, k, float(reference[k - 1]))
                if verdict is not None:
                    outcomes[c] = Outcome(verdict.period, complex(verdict.p, verdict.q), verdict.uncertainty,
                                          verdict.status, verdict.method)
                    break
            checked[c] = hist.n
    return PointRun(frequency_hz, outcomes, hist.values[:keep_periods].copy(), hist.n)


def errors(z: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gain error dB, phase error deg) of estimates z against truth (elementwise)."""
    r = z / truth
    return 20.0 * np.log10(np.abs(r)), np.degrees(np.angle(r))


def meets(gain_db: np.ndarray, phase_deg: np.ndarray) -> np.ndarray:
    return (np.abs(gain_db) <= GAIN_TOL_DB) & (np.abs(phase_deg) <= PHASE_TOL_DEG)


def smallest_fixed(series: np.ndarray, truth: np.ndarray) -> tuple[int, int] | None:
    """Smallest N + M such that the mean of Z over periods N+1..N+M meets the tolerance at every frequency.

    series: (frequencies, L) per-period coefficients; the search covers N + M <= L (smallest N reported).
    """
    length = series.shape[1]
    cum = np.zeros((series.shape[0], length + 1), dtype=complex)
    cum[:, 1:] = np.cumsum(series / truth[:, None], axis=1)  # normalised: the ratio to the truth
    lo, hi = 10.0 ** (-GAIN_TOL_DB / 10.0), 10.0 ** (GAIN_TOL_DB / 10.0)  # bounds on |ratio|^2
    tan_tol = math.tan(math.radians(PHASE_TOL_DEG))
    for total in range(1, length + 1):
        settle = np.arange(total)
        r = (cum[:, total, None] - cum[:, :total]) / (total - settle)[None, :]
        mag2 = r.real ** 2 + r.imag ** 2
        ok = (mag2 >= lo) & (mag2 <= hi) & (r.real > 0) & (np.abs(r.imag) <= tan_tol * r.real)
        good = np.flatnonzero(ok.all(axis=0))
        if good.size:
            return int(good[0]), total - int(good[0])
    return None


def rule_label(criterion: str, analysis: AnalysisConfig) -> str:
    if criterion == "fixed":
        return f"fixed({analysis.settle_periods},{analysis.average_periods})"
    return criterion


def summarise(name: str, runs: list[PointRun], truth: np.ndarray, criteria: tuple[str, ...],
              analysis: AnalysisConfig) -> dict[str, dict[str, np.ndarray]]:
    """Print the per-criterion table of one plant; returns per-criterion arrays for the chart."""
    table: dict[str, dict[str, np.ndarray]] = {}
    print(f"{'criterion':<14} {'total':>8} {'max':>6} {'capped':>6} {'worst |dG| dB':>14} "
          f"{'worst |dphi| deg':>16}  meets {GAIN_TOL_DB:g} dB / {PHASE_TOL_DEG:g} deg")
    for c in criteria:
        periods = np.array([r.outcomes[c].period for r in runs])
        z = np.array([r.outcomes[c].z for r in runs])
        capped = sum(r.outcomes[c].status == CAPPED for r in runs)
        g, ph = errors(z, truth)
        ok = meets(g, ph)
        verdict = "yes" if ok.all() else f"no ({int((~ok).sum())}/{len(runs)} points fail)"
        print(f"{rule_label(c, analysis):<14} {int(periods.sum()):>8} {int(periods.max()):>6} {capped:>6} "
              f"{np.max(np.abs(g)):>14.2e} {np.max(np.abs(ph)):>16.2e}  {verdict}")
        table[c] = {"periods": periods, "gain": g, "phase": ph}
    return table


def fixed_search(name: str, runs: list[PointRun], truth: np.ndarray, default_total: int) -> int | None:
    """Print the smallest uniform fixed scheme and the target comparison; returns N + M."""
    series = np.stack([r.series for r in runs])
    start = time.perf_counter()
    found = smallest_fixed(series, truth)
    elapsed = time.perf_counter() - start
    if found is None:
        print(f"smallest fixed scheme: none with N + M <= {series.shape[1]} meets the tolerance at every point "
              f"(searched in {elapsed:.1f} s)")
        return None
    settle, average = found
    budget = len(runs) * (settle + average)
    print(f"smallest fixed scheme meeting {GAIN_TOL_DB:g} dB / {PHASE_TOL_DEG:g} deg everywhere: settle N = "
          f"{settle}, average M = {average} (N + M = {settle + average}; 42 (N + M) = {budget}; "
          f"searched in {elapsed:.1f} s)")
    verdict = "met" if default_total <= budget / 2 else "NOT met"
    print(f"target: adaptive total {default_total} <= 42 (N + M) / 2 = {budget / 2:g}: {verdict} "
          f"(ratio {default_total / budget:.3f})")
    return settle + average


def submit_grid(pool: Executor, plant: Plant, freqs: tuple[float, ...], amplitude: float,
                analysis: AnalysisConfig, criteria: tuple[str, ...], keep: int,
                noise: np.ndarray | None = None, seed: int = 0) -> list[Future[PointRun]]:
    return [pool.submit(replay_point, plant, f, amplitude, analysis, criteria, keep,
                        0.0 if noise is None else float(noise[i]), seed * 1000 + i)
            for i, f in enumerate(freqs)]


def cross_check(pool: Executor, cases: dict[str, CaseConfig], runs: dict[str, list[PointRun]],
                freqs: tuple[float, ...]) -> None:
    """measure_frequency on a few frequencies against the replay of the default rule."""
    futures = {(name, f): pool.submit(measure_frequency, cases[name], f) for name in cases for f in CROSS_CHECK_HZ}
    print("replay vs measure_frequency (adaptive, harmonic 1):")
    for (name, f), fut in futures.items():
        point = next(p for p in fut.result() if p.harmonic == 1)
        mine = runs[name][freqs.index(f)].outcomes["adaptive"]
        z = complex(point.p, point.q)
        print(f"  {name:<9} f = {f:>6g} Hz: periods {point.periods:>5} vs {mine.period:>5}, "
              f"|dZ|/|Z| = {abs(z - mine.z) / abs(z):.1e}")


def chart(tables: dict[str, dict[str, dict[str, np.ndarray]]], freqs: np.ndarray,
          fixed_totals: dict[str, int | None], analysis: AnalysisConfig) -> list[Path]:
    """Periods and errors per frequency, one column per plant; returns the files written."""
    OUT.mkdir(parents=True, exist_ok=True)
    names = list(tables)
    fig, axes = plt.subplots(3, len(names), figsize=(7 * len(names), 11), sharex=True, squeeze=False)
    colours = plt.get_cmap("tab10")
    floor = 1e-8
    for col, name in enumerate(names):
        for i, (c, data) in enumerate(tables[name].items()):
            style = {"color": colours(i % 10), "marker": "o.sv^<>dPX"[i % 10], "markersize": 3,
                     "linewidth": 2.2 if c == "adaptive" else 0.9, "label": rule_label(c, analysis)}
            axes[0, col].plot(freqs, data["periods"], **style)
            axes[1, col].plot(freqs, np.maximum(np.abs(data["gain"]), floor), **style)
            axes[2, col].plot(freqs, np.maximum(np.abs(data["phase"]), floor), **style)
        if fixed_totals[name] is not None:
            axes[0, col].axhline(fixed_totals[name], color="k", linestyle="--", linewidth=1,
                                 label=f"smallest uniform fixed N+M = {fixed_totals[name]}")
        axes[1, col].axhline(GAIN_TOL_DB, color="k", linestyle=":", linewidth=1, label=f"{GAIN_TOL_DB:g} dB")
        axes[2, col].axhline(PHASE_TOL_DEG, color="k", linestyle=":", linewidth=1, label=f"{PHASE_TOL_DEG:g} deg")
        axes[0, col].set_title(name)
        axes[0, col].set_ylabel("periods")
        axes[1, col].set_ylabel(f"|gain error|, dB (floor {floor:g})")
        axes[2, col].set_ylabel(f"|phase error|, deg (floor {floor:g})")
        axes[2, col].set_xlabel("frequency, Hz")
        for ax in axes[:, col]:
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.grid(True, which="both", linewidth=0.3)
        for ax in axes[:, col]:
            dashed = [line for line in ax.get_lines() if line.get_linestyle() in ("--", ":")]
            ax.legend(handles=dashed, fontsize=7, loc="lower right")
    rules = axes[1, 0].get_lines()[:len(tables[names[0]])]
    fig.legend(handles=rules, loc="lower center", ncol=len(rules), fontsize=8, frameon=False)
    fig.suptitle(f"Stopping rules, first harmonic, eps = {analysis.tolerance_percent:g} %, "
                 f"n_k = {analysis.skip_periods}, l = {analysis.window}")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    files = [OUT / "rules.png", OUT / "rules.svg"]
    plt.rcParams["svg.hashsalt"] = "bench_rules"  # stable element ids: reruns give the same file
    for path in files:
        fig.savefig(path, dpi=120, metadata={"Date": None} if path.suffix == ".svg" else None)
    plt.close(fig)
    return files


def main() -> None:
    started = time.perf_counter()
    config = load_config(CONFIG)
    friction_case = next(c for c in config.cases if c.name == FRICTION_CASE)
    analysis = friction_case.analysis
    amplitude = friction_case.excitation.amplitude
    freqs = tuple(friction_case.excitation.frequencies_hz)
    pc = friction_case.plant
    linear_plant = LinearOscillator(pc.mass, pc.stiffness, DAMPING_RATIO)
    friction_plant = build_plant(pc)
    linear_case = replace(friction_case, name="linear",
                          plant=PlantConfig(model="linear", mass=pc.mass, stiffness=pc.stiffness,
                                            damping_ratio=DAMPING_RATIO))
    f_arr = np.array(freqs)
    exact = linear_plant.frequency_response(f_arr)[:, linear_plant.output_names.index(OUTPUT_CHANNEL)] * amplitude

    print(f"grid: {len(freqs)} frequencies {freqs[0]:g}..{freqs[-1]:g} Hz; eps = {analysis.tolerance_percent:g} %, "
          f"n_k = {analysis.skip_periods}, l = {analysis.window}, K_f = {analysis.steps_per_period}, "
          f"max_periods = {analysis.max_periods}; first harmonic of {OUTPUT_CHANNEL}, A = {amplitude:g}")
    print(f"linear:   m = {pc.mass:g}, K_p = {pc.stiffness:g}, damping ratio {DAMPING_RATIO:g}; "
          "truth = frequency_response()")
    print(f"friction: m = {pc.mass:g}, K_p = {pc.stiffness:g}, F_ct = {pc.friction:g} (Fbar "
          f"{pc.friction / amplitude:g}); truth = fixed scheme settle {REFERENCE[0]} average {REFERENCE[1]}")

    with ProcessPoolExecutor() as pool:
        futures = {
            "linear": submit_grid(pool, linear_plant, freqs, amplitude, analysis, CRITERIA, KEEP_PERIODS),
            "friction": submit_grid(pool, friction_plant, freqs, amplitude, analysis, CRITERIA, KEEP_PERIODS),
        }
        noise_std = NOISE_RELATIVE * np.abs(exact)
        noisy = [submit_grid(pool, linear_plant, freqs, amplitude, analysis, NOISE_CRITERIA, 0, noise_std, s)
                 for s in NOISE_SEEDS]
        runs = {name: [f.result() for f in fs] for name, fs in futures.items()}
        noisy_runs = [[f.result() for f in fs] for fs in noisy]
        cross_check(pool, {"linear": linear_case, "friction": friction_case}, runs, freqs)

    # the friction truth and its own check
    fr = np.stack([r.series for r in runs["friction"]])
    ref = fr[:, REFERENCE[0]:sum(REFERENCE)].mean(axis=1)
    ref_check = fr[:, REFERENCE_CHECK[0]:sum(REFERENCE_CHECK)].mean(axis=1)
    g, ph = errors(ref, ref_check)
    tail = fr[:, -REFERENCE_CHECK[1]:]
    change = np.max(np.abs(np.diff(tail, axis=1)), axis=1) / np.abs(ref_check)
    print(f"friction reference check: settle {REFERENCE[0]}/average {REFERENCE[1]} vs settle "
          f"{REFERENCE_CHECK[0]}/average {REFERENCE_CHECK[1]}: worst |dG| = {np.max(np.abs(g)):.1e} dB, "
          f"worst |dphi| = {np.max(np.abs(ph)):.1e} deg, worst |Z - Z_check|/|Z| = "
          f"{np.max(np.abs(ref - ref_check) / np.abs(ref_check)):.1e}; largest period-to-period change "
          f"|Z(i) - Z(i-1)|/|Z| over periods {KEEP_PERIODS - REFERENCE_CHECK[1] + 1}..{KEEP_PERIODS}: "
          f"{np.max(change):.1e} (at {freqs[int(np.argmax(change))]:g} Hz)")

    truths = {"linear": exact, "friction": ref}
    tables: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    fixed_totals: dict[str, int | None] = {}
    for name in ("linear", "friction"):
        print()
        print(f"== {name} ==")
        tables[name] = summarise(name, runs[name], truths[name], CRITERIA, analysis)
        fixed_totals[name] = fixed_search(name, runs[name], truths[name],
                                          int(tables[name]["adaptive"]["periods"].sum()))

    print()
    print(f"== linear with white noise, std {NOISE_RELATIVE:.0%} of the steady amplitude, seeds {NOISE_SEEDS} ==")
    print(f"{'criterion':<10} {'mean total':>10} {'max':>6} {'capped':>6} {'worst |dG| dB':>14} "
          f"{'worst |dphi| deg':>16} {'meets':>7} {'covered':>9} {'no CI':>6}")
    for c in NOISE_CRITERIA:
        outcomes = [[r.outcomes[c] for r in seed_runs] for seed_runs in noisy_runs]
        periods = np.array([[o.period for o in row] for row in outcomes])
        z = np.array([[o.z for o in row] for row in outcomes])
        unc = np.array([[o.uncertainty for o in row] for row in outcomes])
        capped = sum(o.status == CAPPED for row in outcomes for o in row)
        g, ph = errors(z, exact[None, :])
        err = np.abs(z - exact[None, :])
        covered = int(np.sum(err <= unc))  # NaN uncertainty never covers
        total = z.size
        print(f"{c:<10} {periods.sum(axis=1).mean():>10.0f} {periods.max():>6} {capped:>6} "
              f"{np.max(np.abs(g)):>14.2e} {np.max(np.abs(ph)):>16.2e} {int(meets(g, ph).sum()):>3}/{total:<3} "
              f"{covered:>4}/{total:<4} {int(np.isnan(unc).sum()):>6}")
        print(f"{'':<10} coverage {covered / total:.0%} (target >= 90 %); median |Z - Z_true| / uncertainty "
              f"= {np.nanmedian(err / unc):.2f}")

    files = chart(tables, f_arr, fixed_totals, analysis)
    print()
    print(f"chart: {', '.join(str(p.relative_to(ROOT)) for p in files)}")
    print(f"done in {time.perf_counter() - started:.1f} s")


if __name__ == "__main__":
    main()
