"""The adaptive plan against fixed grids: bench time to get the summary's figures within a stated accuracy.

Run: python benchmarks/bench_adaptive.py [--accuracy 1.0]

Each plant is swept offline (the simulated plant, 200 steps a period, tolerance 0.1 %) from 1 to 100 Hz twice:
  adaptive  3 points a decade, then the plan's rounds (bandwidth, resonance peak and frequency, -90 and -180 deg
            crossings; frequencies to --accuracy percent, the peak to 0.1 dB);
  fixed     log-spaced grids of 3, 5, 8, 12, 20, 30, 50, 80 and 120 points a decade: the smallest whose figures
            all lie within the same accuracy of the exact ones.
Exact figures are solved on the plant's exact response (root finding and bounded minimisation, the tests'
``exact_figures``). Bench time: at each frequency the periods measured and settled, over the frequency (what a
stepped-sine bench spends, ramps aside). Printed per plant: points, bench seconds, the worst figure error as a
share of its accuracy (<= 1 to pass), and the ratio fixed / adaptive bench time (target: above 1, the adaptive
plan the quicker; a plant whose smallest passing grid is the coarsest is reported as such). The friction link
has no closed form: its reference is the 120-a-decade grid's figures, its accuracy twice as loose.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from test_adaptive_plan import exact_figures, second_order  # noqa: E402

from bodebench.bench.adaptive import bench_seconds  # noqa: E402
from bodebench.bench.procedure import CaseOutcome, SweepProcedure  # noqa: E402
from bodebench.core.refine import FIGURE_NAMES  # noqa: E402
from bodebench.io.config import parse_config  # noqa: E402

GRIDS = (3, 5, 8, 12, 20, 30, 50, 80, 120)
FIGURES = ("bandwidth", "resonance", "phase_90", "phase_180")
START, STOP = 1.0, 100.0


def linear(fn: float, zeta: float) -> dict[str, Any]:
    return {"model": "linear", "mass": 1.0 / (2.0 * math.pi * fn) ** 2, "stiffness": 1.0, "damping_ratio": zeta}


PLANTS: dict[str, tuple[dict[str, Any], Any, float]] = {  # [plant], exact response (None: none), amplitude
    "light resonance (7.31 Hz, zeta 0.02)": (linear(7.31, 0.02), second_order(7.31, 0.02), 0.01),
    "very light (23.7 Hz, zeta 0.005)": (linear(23.7, 0.005), second_order(23.7, 0.005), 0.01),
    "moderate (3.17 Hz, zeta 0.2)": (linear(3.17, 0.2), second_order(3.17, 0.2), 0.01),
    "well damped (13.9 Hz, zeta 0.6)": (linear(13.9, 0.6), second_order(13.9, 0.6), 0.01),
    "friction link (Fbar 0.5)": ({"model": "coulomb", "mass": 2.533e-4, "stiffness": 1.0, "friction": 0.005},
                                 None, 0.01),
}


def sweep(plant: dict[str, Any], amplitude: float, frequencies: dict[str, Any], out: Path) -> CaseOutcome:
    data = {"plant": plant, "excitation": {"amplitude": amplitude, "frequencies": frequencies},
            "analysis": {"harmonics": [1], "tolerance_percent": 0.1, "steps_per_period": 200}}
    (outcome,) = SweepProcedure(parse_config(data, "bench_adaptive.toml"), out).run()
    return outcome


def seconds_of(outcome: CaseOutcome) -> float:
    return bench_seconds(outcome.case, outcome.response)


def worst_share(outcome: CaseOutcome, exact: dict[str, tuple[float, float]], accuracy: float) -> float:
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
    args = parser.parse_args()
    print(f"{'plant':38s} {'plan':>9s} {'points':>6s} {'bench s':>8s} {'worst':>6s}   ratio fixed/adaptive")
    ratios = []
    with TemporaryDirectory() as tmp:
        for n, (name, (plant, g, amplitude)) in enumerate(PLANTS.items()):
            accuracy = args.accuracy if g is not None else 2.0 * args.accuracy
            adaptive = {"start_hz": START, "stop_hz": STOP, "per_decade": 3,
                        "adaptive": {"figures": list(FIGURES), "frequency_percent": accuracy,
                                     "gain_db": 0.1 * accuracy}}
            grown = sweep(plant, amplitude, adaptive, Path(tmp) / f"a{n}")
            fixed = {d: sweep(plant, amplitude, {"start_hz": START, "stop_hz": STOP, "per_decade": d},
                              Path(tmp) / f"f{n}-{d}") for d in GRIDS}
            if g is not None:
                solved = exact_figures(g, START, STOP, "system")
                exact = {k: (solved[k].value, solved[k].at_hz) for k in FIGURES if k in solved}
            else:  # the finest grid's figures stand in
                (finest,) = fixed[GRIDS[-1]].summary
                exact = {k: (finest.figure(FIGURE_NAMES[k]).value, finest.figure(FIGURE_NAMES[k]).at_hz)
                         for k in FIGURES}
            share = worst_share(grown, exact, accuracy)
            seconds = seconds_of(grown)
            print(f"{name:38s} {'adaptive':>9s} {len(grown.response):6d} {seconds:8.1f} {share:6.2f}")
            passing = [d for d in GRIDS[:-1] if worst_share(fixed[d], exact, accuracy) <= 1.0]
            for d in GRIDS[:-1]:
                mark = " <- smallest within accuracy" if passing and d == passing[0] else ""
                print(f"{'':38s} {f'{d}/dec':>9s} {len(fixed[d].response):6d} {seconds_of(fixed[d]):8.1f} "
                      f"{worst_share(fixed[d], exact, accuracy):6.2f}{mark}")
            if passing:
                ratio = seconds_of(fixed[passing[0]]) / seconds
                ratios.append(ratio)
                print(f"{'':38s} ratio {ratio:.2f} (target > 1)  adaptive within accuracy: {share <= 1.0}")
            else:
                print(f"{'':38s} no fixed grid below {GRIDS[-1]}/dec within accuracy; adaptive within accuracy: "
                      f"{share <= 1.0}")
    if ratios:
        print(f"ratio fixed/adaptive bench time: least {min(ratios):.2f}, median {sorted(ratios)[len(ratios) // 2]:.2f}"
              f" (target > 1)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
