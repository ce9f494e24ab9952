"""Throughput of the per-period Fourier integrators (instrument/core/fourier.py): the trapezoid alone and the bench's
ExactPeriodIntegrator (the trapezoid's moments solved for a constant, a drift and harmonics 1 .. 3 on any grid), with
the basis the bench uses (harmonics up to bodebench.core.benchgrid.alias_fit_order of the samples a period: 8 here)
and with the measured harmonics alone.

Run: python benchmarks/bench_sampler.py

Feeds 1e6 jittered samples of 1 and 4 channels, harmonics (1, 2, 3), in chunks of 100 and of 10,000 samples, and
prints samples per second per channel (time points processed per second; each carries every channel) against the
target: at least 100,000 samples/s per channel at chunk size 100 (a 10 kHz drive's stream with a tenth of a CPU).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bodebench.core.benchgrid import alias_fit_order  # noqa: E402
from bodebench.core.fourier import ExactPeriodIntegrator, PeriodIntegrator  # noqa: E402

N_SAMPLES = 1_000_000
SAMPLE_RATE_HZ = 10_000.0
FREQUENCY_HZ = 37.0  # about 270 samples per period, edges between samples
HARMONICS = (1, 2, 3)
TARGET = 100_000  # samples/s per channel at chunk size 100
BENCH_ORDER = alias_fit_order(SAMPLE_RATE_HZ / FREQUENCY_HZ, max(HARMONICS))
INTEGRATORS = {"trapezoid": PeriodIntegrator, "exact 1..3": ExactPeriodIntegrator,
               f"exact 1..{BENCH_ORDER}": ExactPeriodIntegrator}


def make_stream(n_channels: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Jittered sample times (s) and a noisy multi-tone signal of shape (N_SAMPLES, n_channels)."""
    rng = np.random.default_rng(seed)
    h = 1.0 / SAMPLE_RATE_HZ
    t = (np.arange(N_SAMPLES) + rng.uniform(-0.2, 0.2, N_SAMPLES)) * h
    t[0] = 0.0
    w = 2.0 * np.pi * FREQUENCY_HZ
    y = np.empty((N_SAMPLES, n_channels))
    for ch in range(n_channels):
        y[:, ch] = (ch + 1) * np.sin(w * t + 0.3 * ch) + 0.2 * np.sin(2 * w * t) + 0.01 * rng.normal(size=N_SAMPLES)
    return t, y


def run(kind: str, n_channels: int, chunk: int) -> tuple[float, int]:
    """Feed the whole stream in chunks to the integrator ``kind``; return (seconds, periods emitted)."""
    t, y = make_stream(n_channels)
    integ = (ExactPeriodIntegrator(FREQUENCY_HZ, HARMONICS, n_channels, t0=0.0, fit_order=BENCH_ORDER)
             if kind.endswith(f"..{BENCH_ORDER}") else INTEGRATORS[kind](FREQUENCY_HZ, HARMONICS, n_channels, t0=0.0))
    start = time.perf_counter()
    for i in range(0, N_SAMPLES, chunk):
        integ.feed(t[i : i + chunk], y[i : i + chunk])
    return time.perf_counter() - start, integ.periods_done


def main() -> None:
    print(f"{N_SAMPLES:.0e} samples at {SAMPLE_RATE_HZ:g} Hz, f = {FREQUENCY_HZ:g} Hz, harmonics {HARMONICS}")
    print(f"{'integrator':>12} {'channels':>8} {'chunk':>7} {'seconds':>8} {'periods':>8} "
          f"{'samples/s per channel':>22}  target at chunk 100: {TARGET:,}")
    for kind in INTEGRATORS:
        for n_channels in (1, 4):
            for chunk in (100, 10_000):
                seconds, periods = run(kind, n_channels, chunk)
                rate = N_SAMPLES / seconds
                verdict = ("met" if rate >= TARGET else "NOT met") if chunk == 100 else ""
                print(f"{kind:>12} {n_channels:>8} {chunk:>7} {seconds:>8.3f} {periods:>8} {rate:>22,.0f}  {verdict}")


if __name__ == "__main__":
    main()
