"""Sweep a damped linear oscillator offline from Python and hand the response to python-control and MATLAB.

    python examples/api_sweep.py [OUT_DIR]

Measures the oscillator m y'' + c y' + K y = u at eight frequencies around its resonance, saves the results
directory and a MATLAB file in OUT_DIR (default: results/api_sweep), and prints each point's gain and phase
next to the exact transfer function 1 / (K - m w^2 + i c w).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

import bodebench

MASS, STIFFNESS, ZETA = 2.533e-4, 1.0, 0.05  # f_n = 10 Hz
CONFIG = {
    "title": "linear oscillator from the Python API",
    "plant": {"model": "linear", "mass": MASS, "stiffness": STIFFNESS, "damping_ratio": ZETA},
    "excitation": {"amplitude": 0.01, "frequencies_hz": [2.0, 5.0, 8.0, 9.5, 10.0, 10.5, 13.0, 30.0]},
    "analysis": {"harmonics": [1], "tolerance_percent": 0.01},
}


def exact(frequency_hz: np.ndarray) -> np.ndarray:
    """1 / (K - m w^2 + i c w) at f (Hz), with c = 2 zeta sqrt(K m)."""
    w = 2.0 * math.pi * frequency_hz
    c = 2.0 * ZETA * math.sqrt(STIFFNESS * MASS)
    return 1.0 / (STIFFNESS - MASS * w**2 + 1j * c * w)


def main() -> int:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results/api_sweep")
    response = bodebench.simulate(CONFIG, out / "sweep", jobs=1)  # writes response.csv and response.json
    again = bodebench.load(out / "sweep")  # the same points, read back
    assert [p.p for p in again] == [p.p for p in response]
    mat = response.to_mat(out / "api_sweep.mat")
    print(f"{len(response)} points -> {out / 'sweep'}, {mat}")
    g = exact(response.frequency_hz)
    print(f"{'f Hz':>6} {'gain dB':>10} {'exact dB':>10} {'phase deg':>10} {'exact deg':>10}  status")
    for point, truth in zip(response, g, strict=True):
        print(f"{point.frequency_hz:6g} {point.gain_db:10.5f} {20 * math.log10(abs(truth)):10.5f} "
              f"{point.phase_deg:10.4f} {math.degrees(np.angle(truth)):10.4f}  {point.status}")
    try:
        frd = response.to_frd()
    except bodebench.MissingDependency as exc:
        print(f"python-control: skipped ({exc})")
    else:
        at = frd(2j * math.pi * 10.0)  # python-control evaluates the measured data at a measured frequency
        print(f"python-control: |G(10 Hz)| = {abs(at):.6g}, exact {abs(exact(np.array(10.0))):.6g}")
    worst = float(np.max(np.abs(response.complex_response() - g) / np.abs(g)))
    print(f"worst relative error {worst:.3g} (tolerance {CONFIG['analysis']['tolerance_percent']} %)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
