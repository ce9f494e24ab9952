"""The adaptive plan against fixed grids: bench time to get the summary's figures, and the curve between the
points, within a stated accuracy.

Run: python benchmarks/bench_adaptive.py [--accuracy 1.0] [--jobs 2]

Each plant is swept offline (the simulated plant, 200 steps a period, tolerance 0.1 %) from 1 to 100 Hz:
  adaptive  3 points a decade, then the plan's rounds (bandwidth, resonance peak and frequency, -90 and -180 deg
            crossings; frequencies to --accuracy percent, the peak to a tenth of it in dB; the curve to 1 dB and
            10 deg between neighbouring points, the plan's defaults);
  fixed     log-spaced grids of 3 to 80 points a decade, each at three offsets (the grid's first point moved by a
            third of a step: where a resonance falls between the points is not known before the sweep); a grid
            passes when it meets the same requirements at every offset.
Requirements, against the exact response (the tests' ``exact_figures``: root finding and bounded minimisation): each
figure within its accuracy, and the gain and phase drawn straight between neighbouring points (log frequency)
within 1 dB and 10 deg of the exact curve at three points inside each interval. Bench time: at each frequency the
periods measured and settled, over the frequency (what a stepped-sine bench spends, ramps aside). Printed per plant:
points, bench seconds, the worst figure error and the worst curve error as shares of their accuracies (<= 1 to
pass), and the ratio fixed / adaptive bench time (target: above 1, the adaptive plan the quicker; where no grid up
to 80 a decade passes, the 80-a-decade grid's time bounds it from below). The friction link has no closed form:
its reference is a 120-a-decade grid's figures, and its curve is not judged.
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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--accuracy", type=float, default=1.0, help="frequency accuracy, percent")
    parser.add_argument("--jobs", type=int, default=2, help="processes for the offline sweeps")
    args = parser.parse_args()
    print(f"{'plant':38s} {'plan':>9s} {'points':>6s} {'bench s':>8s} {'figures':>7s} {'curve':>6s}")
    ratios = []
    with TemporaryDirectory() as tmp, ProcessPoolExecutor(args.jobs) as pool:
        for n, (name, (plant, g)) in enumerate(PLANTS.items()):
            accuracy = args.accuracy
            adaptive = {"start_hz": START, "stop_hz": STOP, "per_decade": 3,
                        "adaptive": {"figures": list(FIGURES), "frequency_percent": accuracy,
                                     "gain_db": 0.1 * accuracy, "max_points": 200}}
            grown = sweep(plant, adaptive, Path(tmp) / f"a{n}", pool)
            if g is not None:
                solved = exact_figures(g, START, STOP, "system")
                exact = {k: (solved[k].value, solved[k].at_hz) for k in FIGURES if k in solved}
                offsets = OFFSETS
            else:  # no closed form: the finest grid's figures stand in, one offset
                (finest,) = sweep(plant, grid(REFERENCE_GRID, 0.0), Path(tmp) / f"r{n}", pool).summary
                exact = {k: (finest.figure(FIGURE_NAMES[k]).value, finest.figure(FIGURE_NAMES[k]).at_hz)
                         for k in FIGURES}
                offsets = (0.0,)
                name += f" (reference: {REFERENCE_GRID}/dec)"
            seconds = seconds_of(grown)
            figures, curve = figure_share(grown, exact, accuracy), curve_share(grown.response, g)
            print(f"{name:38s} {'adaptive':>9s} {len(grown.response):6d} {seconds:8.1f} {figures:7.2f} {curve:6.2f}")
            smallest = finest = None
            for d in GRIDS:
                runs = [sweep(plant, grid(d, u), Path(tmp) / f"f{n}-{d}-{k}", pool) for k, u in enumerate(offsets)]
                worst_figures = max(figure_share(r, exact, accuracy) for r in runs)
                worst_curve = max(curve_share(r.response, g) for r in runs)
                mean_s = finest = sum(seconds_of(r) for r in runs) / len(runs)
                passes = worst_figures <= 1.0 and not worst_curve > 1.0
                mark = " <- smallest within accuracy at every offset" if passes and smallest is None else ""
                print(f"{'':38s} {f'{d}/dec':>9s} {len(runs[0].response):6d} {mean_s:8.1f} {worst_figures:7.2f} "
                      f"{worst_curve:6.2f}{mark}")
                if passes and smallest is None:
                    smallest = mean_s
                    break
            met = figures <= 1.0 and not curve > 1.0
            if smallest is not None:
                ratios.append(smallest / seconds)
                print(f"{'':38s} ratio {smallest / seconds:.2f} (target > 1); adaptive within accuracy: {met}")
            else:  # the finest grid tried bounds the ratio from below
                assert finest is not None
                ratios.append(finest / seconds)
                print(f"{'':38s} ratio > {finest / seconds:.2f} (no fixed grid up to {GRIDS[-1]}/dec within accuracy "
                      f"at every offset); adaptive within accuracy: {met}")
    if ratios:
        print(f"ratio fixed/adaptive bench time (lower bounds where no grid passed): least {min(ratios):.2f}, "
              f"median {sorted(ratios)[len(ratios) // 2]:.2f} (target > 1)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
