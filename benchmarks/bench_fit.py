"""The transfer-function fit (bodebench.core.fit) on 100-point responses with exact answers: coverage of its 95 %
intervals, its residuals and its time.

Run: python benchmarks/bench_fit.py [--seeds 200]

Plants, each sampled at 100 log-spaced frequencies over two decades around its modes, with complex Gaussian noise
of a stated standard deviation (0.2 % of |G| on each of the real and imaginary parts, seeded), fitted at their own
order:
  second order           3 wn^2 / (s^2 + 2 0.2 wn s + wn^2), wn = 2 pi 8 Hz
  second order + delay   the same times exp(-s 4 ms)
  fourth order + delay   two modes, 6 Hz (damping 0.3) and 40 Hz (damping 0.1), static gain 2, exp(-s 2 ms)
  two-mass drive         a rigid-body integrator, an anti-resonance at 30 Hz (damping 0.05) and a resonance at
                         45 Hz (damping 0.08): 4th-order denominator with the integrator, 2nd-order numerator
Printed per plant: the share of seeds in which each parameter's 95 % interval holds its true value (target 0.95,
within four binomial standard errors), the mean chi-square per degree of freedom (target about 1), and the least,
median and largest CPU time of a fit (target: the median below 0.2 s).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from bodebench.core.fit import Q95, fit_transfer_function

MEDIAN_TARGET_S = 0.2


def second_order(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    wn, zeta, k, tau = 2 * np.pi * 8.0, 0.2, 3.0, 0.004
    g = k * wn ** 2 / (s ** 2 + 2 * zeta * wn * s + wn ** 2) * np.exp(-s * tau)
    return g, np.array([k * wn ** 2, 2 * zeta * wn, wn ** 2, tau]), {"orders": (0, 2), "delay": True,
                                                                      "integrator": False}


def two_mass(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    wz, zz, wp, zp, k = 2 * np.pi * 30.0, 0.05, 2 * np.pi * 45.0, 0.08, 200.0
    num = k * np.array([1.0, 2 * zz * wz, wz ** 2]) * (wp ** 2 / wz ** 2)
    den = np.array([1.0, 2 * zp * wp, wp ** 2])
    g = np.polyval(num, s) / (s * np.polyval(den, s))
    return g, np.concatenate([num, den[1:]]), {"orders": (2, 3), "delay": False, "integrator": True}


def second_order_alone(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    wn, zeta, k = 2 * np.pi * 8.0, 0.2, 3.0
    g = k * wn ** 2 / (s ** 2 + 2 * zeta * wn * s + wn ** 2)
    return g, np.array([k * wn ** 2, 2 * zeta * wn, wn ** 2]), {"orders": (0, 2), "delay": False,
                                                                 "integrator": False}


def fourth_order_delay(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    w1, z1, w2, z2, k, tau = 2 * np.pi * 6.0, 0.3, 2 * np.pi * 40.0, 0.1, 2.0, 0.002
    den = np.polymul([1.0, 2 * z1 * w1, w1 ** 2], [1.0, 2 * z2 * w2, w2 ** 2])
    g = k * w1 ** 2 * w2 ** 2 / np.polyval(den, s) * np.exp(-s * tau)
    return g, np.concatenate([[k * w1 ** 2 * w2 ** 2], den[1:], [tau]]), {"orders": (0, 4), "delay": True,
                                                                          "integrator": False}


PLANTS = {"second order": (second_order_alone, (0.5, 50.0)), "second order + delay": (second_order, (0.5, 50.0)),
          "fourth order + delay": (fourth_order_delay, (0.6, 200.0)), "two-mass drive": (two_mass, (3.0, 300.0))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=200)
    args = parser.parse_args()
    failed = False
    for name, (plant, (f_lo, f_hi)) in PLANTS.items():
        f = np.geomspace(f_lo, f_hi, 100)
        g, truth, how = plant(2j * np.pi * f)
        sd = 2e-3 * np.abs(g)
        covered = np.zeros(truth.size)
        chi2, times = [], []
        for seed in range(args.seeds):
            rng = np.random.default_rng(seed)
            noisy = g + sd * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
            started = time.process_time()
            fit = fit_transfer_function(f, noisy, sd, *how["orders"], integrator=how["integrator"],
                                        delay=how["delay"])
            times.append(time.process_time() - started)
            covered += np.abs(fit.parameters - truth) <= Q95 * fit.standard_errors
            chi2.append(fit.chi2 / fit.dof)
        rate = covered / args.seeds
        spread = 4 * math.sqrt(0.95 * 0.05 / args.seeds)
        ok_cover = bool(np.all(np.abs(rate - 0.95) <= spread))
        ok_time = float(np.median(times)) < MEDIAN_TARGET_S
        failed |= not (ok_cover and ok_time)
        print(f"{name}: 100 points, order {how['orders'][0]}/{how['orders'][1]}"
              + (" with an integrator" if how["integrator"] else "") + (" and a delay" if how["delay"] else "")
              + f", {args.seeds} seeds")
        shares = ", ".join(f"{n} {r:.3f}" for n, r in zip(fit.names, rate, strict=True))
        print(f"  coverage of the 95 % intervals: {shares}  (target 0.95 +- {spread:.3f}: "
              f"{'met' if ok_cover else 'NOT met'})")
        print(f"  chi-square per degree of freedom: mean {np.mean(chi2):.3f} (about 1 when the model holds)")
        print(f"  CPU time of a fit: least {min(times) * 1e3:.1f} ms, median {np.median(times) * 1e3:.1f} ms, "
              f"largest {max(times) * 1e3:.1f} ms  (target: median < {MEDIAN_TARGET_S * 1e3:.0f} ms: "
              f"{'met' if ok_time else 'NOT met'})")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
