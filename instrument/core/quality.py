"""Per-point quality figures: total harmonic distortion and coherence.

- **THD** of a channel's output at one excitation frequency, from the harmonics measured:
  ``sqrt(sum_{k >= 2} |Z_k|^2) / |Z_1|`` (dimensionless; a lower bound of the true THD when harmonics that carry
  power were not measured).
- **Coherence** of one series (channel x harmonic): ``|mean Z_i|^2 / mean |Z_i|^2`` over the per-period
  coefficients ``Z_i`` of the later half of the analysed periods. It is the magnitude-squared coherence between the
  excitation and the output at ``k f``, estimated by Welch's method with non-overlapping one-period segments
  aligned to the excitation (the excitation's coefficient is the same in every segment): the share of the
  output's power at ``k f`` that is the steady response locked to the excitation, the rest being noise, drift
  or a transient not yet gone. 1 for a noise-free steady response, in [0, 1] always; for M periods of pure noise
  it is about 1/M.

Pure numerics.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["coherence", "coherence_periods", "total_harmonic_distortion"]

MIN_COHERENCE_PERIODS = 2
"""Fewest periods a coherence is stated on (NaN below)."""


def total_harmonic_distortion(fundamental: complex, harmonics: Sequence[complex]) -> float:
    """``sqrt(sum |Z_k|^2) / |Z_1|`` for the coefficients ``harmonics`` (k >= 2) over ``fundamental``
    (dimensionless); NaN when no harmonic is given, the fundamental is zero, or a coefficient is not a number."""
    values = np.asarray(list(harmonics), dtype=complex)
    magnitude = abs(fundamental)
    if values.size == 0 or not magnitude > 0.0 or not np.all(np.isfinite(values)) or not math.isfinite(magnitude):
        return math.nan
    return float(np.sqrt(np.sum(np.abs(values) ** 2)) / magnitude)


def coherence_periods(skip_periods: int, periods: int) -> tuple[int, int]:
    """The periods ``[start, stop)`` (0-based) a coherence is taken over: the later half of the analysed ones,
    ``skip_periods`` to ``periods``."""
    analysed = max(periods - skip_periods, 0)
    return periods - (analysed + 1) // 2 if analysed else periods, periods


def coherence(values: np.ndarray | Sequence[complex]) -> float:
    """``|mean Z|^2 / mean |Z|^2`` of per-period coefficients ``values``; NaN for fewer than two periods or a
    zero series."""
    z = np.asarray(values, dtype=complex)
    if z.size < MIN_COHERENCE_PERIODS or not np.all(np.isfinite(z)):
        return math.nan
    power = float(np.mean(np.abs(z) ** 2))
    if not power > 0.0:
        return math.nan
    return min(1.0, float(abs(np.mean(z)) ** 2) / power)
