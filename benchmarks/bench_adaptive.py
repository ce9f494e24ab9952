"""The adaptive plan against fixed grids: bench time to get the summary's figures, and the curve between the
points, within a stated accuracy.

Run: python benchmarks/bench_adaptive.py [--accuracy 1.0] [--jobs 2]

Each plant is swept offline (the simulated plant, 200 steps a period, tolerance 0.1 %) from 1 to 100 Hz, under two
requirements, each asked of the adaptive plan and judged on the fixed grids alike:
  figures            bandwidth, resonance peak and frequency, -90 and -180 deg crossings: frequencies to
                     --accuracy percent, the peak to a tenth of it in dB (the plan with ``curve = false``);
  figures and curve  those, and the gain and phase drawn straight between neighbouring points (log frequency)
                     within 1 dB and 10 deg of the exact curve at three points inside each interval (the plan's
                     defaults); plants with an exact response only.
  adaptive  3 points a decade, then the plan's rounds;
  fixed     log-spaced grids of 3 to 80 points a decade, each at three offsets (the grid's first point moved by a
            third of a step: where a resonance falls between the points is not known before the sweep); a grid
            passes when it meets the requirement at every offset.
Exact figures: the tests' ``exact_figures`` (root finding and bounded minimisation on the analytic response). The
friction link has no closed form: its reference is a 120-a-decade grid's figures (one offset), and it is judged on
its figures only. Bench time: at each frequency the periods measured and settled, over the frequency (what a
stepped-sine bench spends, ramps aside). Printed per plant: points, bench seconds, the worst figure error and the
worst curve error as shares of their accuracies (<= 1 to pass), and the ratio fixed / adaptive bench time (target:
above 1, the adaptive plan the quicker; where no grid up to 80 a decade passes, the 80-a-decade grid's time bounds it
from below).
"""

from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import Executor, ProcessPoolExecutor
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from test_adaptive_plan import Response, curve_share, exact_figures, second_order  # noqa: E402

from bodebench.bench.adaptive import bench_seconds  # noqa: E402
from bodebench.bench.procedure import CaseOutcome, SweepProcedure  # noqa: E402
from bodebench.core.refine import FIGURE_NAMES  # noqa: E402
from bodebench.io.config import parse_config  # noqa: E402

GRIDS = (3, 5, 8, 12, 20, 30, 50, 80)
OFFSETS = (0.0, 1 / 3, 2 / 3)
REFERENCE_GRID = 120
FIGURES = ("bandwidth", "resonance", "phase_90", "phase_180")
START, STOP = 1.0, 100.0
CURVE_GAIN_DB, CURVE_PHASE_DEG = 1.0, 10.0


def linear(fn: float, zeta: float) -> dict[str, Any]:
    return {"model": "linear", "mass": 1.0 / (2.0 * math.pi * fn) ** 2, "stiffness": 1.0, "damping_ratio": zeta}


PLANTS: dict[str, tuple[dict[str, Any], Response | None]] = {  # [plant], exact response (None: none)
    "light resonance (7.31 Hz, zeta 0.02)": (linear(7.31, 0.02), second_order(7.31, 0.02)),
    "very light (23.7 Hz, zeta 0.005)": (linear(23.7, 0.005), second_order(23.7, 0.005)),
    "moderate (3.17 Hz, zeta 0.2)": (linear(3.17, 0.2), second_order(3.17, 0.2)),
    "well damped (13.9 Hz, zeta 0.6)": (linear(13.9, 0.6), second_order(13.9, 0.6)),
    "friction link (Fbar 0.8)": ({"model": "coulomb", "mass": 2.533e-4, "stiffness": 1.0, "friction": 0.008}, None),
}


def sweep(plant: dict[str, Any], frequencies: dict[str, Any] | list[float], out: Path,
          executor: Executor | None) -> CaseOutcome:
    plan = {"frequencies": frequencies} if isinstance(frequencies, dict) else {"frequencies_hz": frequencies}
    data = {"plant": plant, "excitation": {"amplitude": 0.01, **plan},
            "analysis": {"harmonics": [1], "tolerance_percent": 0.1, "steps_per_period": 200}}
    (outcome,) = SweepProcedure(parse_config(data, "bench_adaptive.toml"), out, executor=executor).run()
    return outcome


def grid(per_decade: int, offset: float) -> list[float]:
    """A log-spaced grid from START to STOP, its points moved up by ``offset`` of a step (the ends kept)."""
    inside = [START * 10.0 ** ((i + offset) / per_decade) for i in range(1, 10 * per_decade)]
    return [START, *sorted({float(f"{f:.6g}") for f in inside if START < f < STOP}), STOP]


def seconds_of(outcome: CaseOutcome) -> float:
    return bench_seconds(outcome.case, outcome.response)


def figure_share(outcome: CaseOutcome, exact: dict[str, tuple[float, float]], accuracy: float) -> float:
    """The largest |figure - exact| over its accuracy (inf: a figure the exact response has is not found)."""
    (summary,) = outcome.summary
    worst = 0.0
    for key, (value, at_hz) in exact.items():
        if not math.isfinite(value):
            continue
        figure = summary.figure(FIGURE_NAMES[key])
        if not figure.found:
            return math.inf
        allowed = 0.1 * accuracy if figure.unit == "dB" else accuracy / 100.0 * value
        worst = max(worst, abs(figure.value - value) / allowed)
        if key == "resonance":
            worst = max(worst, abs(figure.at_hz - at_hz) / (accuracy / 100.0 * at_hz))
    return worst


def compare(name: str, plant: dict[str, Any], g: Response | None, exact: dict[str, tuple[float, float]],
            offsets: tuple[float, ...], accuracy: float, with_curve: bool, out: Path, pool: Executor) -> float:
    """Print the adaptive plan's row and the fixed grids' rows up to the first that passes; the ratio of bench
    times fixed / adaptive (a lower bound where no grid passes)."""
    adaptive = {"start_hz": START, "stop_hz": STOP, "per_decade": 3,
                "adaptive": {"figures": list(FIGURES), "frequency_percent": accuracy, "gain_db": 0.1 * accuracy,
                             "max_points": 200, "curve": with_curve}}
    grown = sweep(plant, adaptive, out / "adaptive", pool)
    seconds = seconds_of(grown)
    figures = figure_share(grown, exact, accuracy)
    curve = curve_share(grown.response, g) if with_curve else math.nan
    print(f"{name:38s} {'adaptive':>9s} {len(grown.response):6d} {seconds:8.1f} {figures:7.2f} {curve:6.2f}")
    smallest = finest = None
    for d in GRIDS:
        runs = [sweep(plant, grid(d, u), out / f"{d}-{k}", pool) for k, u in enumerate(offsets)]
        worst_figures = max(figure_share(r, exact, accuracy) for r in runs)
        worst_curve = max(curve_share(r.response, g) for r in runs) if with_curve else math.nan
        mean_s = finest = sum(seconds_of(r) for r in runs) / len(runs)
        passes = worst_figures <= 1.0 and not worst_curve > 1.0
        mark = " <- smallest within accuracy at every offset" if passes else ""
        print(f"{'':38s} {f'{d}/dec':>9s} {len(runs[0].response):6d} {mean_s:8.1f} {worst_figures:7.2f} "
              f"{worst_curve:6.2f}{mark}")
        if passes:
            smallest = mean_s
            break
    met = figures <= 1.0 and not curve > 1.0
    if smallest is not None:
        print(f"{'':38s} ratio {smallest / seconds:.2f} (target > 1); adaptive within accuracy: {met}")
        return smallest / seconds
    assert finest is not None  # the finest grid tried bounds the ratio from below
    print(f"{'':38s} ratio > {finest / seconds:.2f} (no fixed grid up to {GRIDS[-1]}/dec within accuracy at every "
          f"offset); adaptive within accuracy: {met}")
    return finest / seconds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--accuracy", type=float, default=1.0, help="frequency accuracy, percent")
    parser.add_argument("--jobs", type=int, default=2, help="processes for the offline sweeps")
    args = parser.parse_args()
    ratios: dict[str, list[float]] = {"figures": [], "figures and curve": []}
    with TemporaryDirectory() as tmp, ProcessPoolExecutor(args.jobs) as pool:
        references = {}
        for n, (name, (plant, g)) in enumerate(PLANTS.items()):
            if g is not None:
                solved = exact_figures(g, START, STOP, "system")
                references[name] = {k: (solved[k].value, solved[k].at_hz) for k in FIGURES if k in solved}
            else:  # no closed form: the finest grid's figures stand in
                (finest,) = sweep(plant, grid(REFERENCE_GRID, 0.0), Path(tmp) / f"r{n}", pool).summary
                references[name] = {k: (finest.figure(FIGURE_NAMES[k]).value, finest.figure(FIGURE_NAMES[k]).at_hz)
                                    for k in FIGURES}
        for requirement, with_curve in (("figures", False), ("figures and curve", True)):
            print(f"\nrequired: {requirement}")
            print(f"{'plant':38s} {'plan':>9s} {'points':>6s} {'bench s':>8s} {'figures':>7s} {'curve':>6s}")
            for n, (name, (plant, g)) in enumerate(PLANTS.items()):
                if with_curve and g is None:
                    continue
                label = name if g is not None else f"{name} (reference: {REFERENCE_GRID}/dec)"
                offsets = OFFSETS if g is not None else (0.0,)
                ratios[requirement].append(compare(label, plant, g, references[name], offsets, args.accuracy,
                                                   with_curve, Path(tmp) / f"{requirement[-5:]}{n}", pool))
    for requirement, found in ratios.items():
        print(f"required {requirement}: ratio fixed/adaptive bench time (lower bounds where no grid passed): least "
              f"{min(found):.2f}, median {sorted(found)[len(found) // 2]:.2f} (target > 1)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
