"""The average waveform of one period on a grid of a whole number of samples a period, for the fold bound.

On such a grid every period is sampled at the same phases, so the folds of a nonlinear response onto the measured
harmonics stand still and no spread between periods shows them (:mod:`~bodebench.core.benchgrid`). The samples
themselves show more than the solved harmonics do: averaged phase by phase over the latest quarter of the periods,
the waveform's discrete spectrum reaches harmonic N/2, next to the harmonics N -+ k that fold onto k.
:func:`waveform_fold_bound` reads the level of the spectrum from N/4 to N/2 there, where a spectrum falling faster
than 1 / j**2 (a response whose acceleration jumps, such as the friction link's) is far below what the solved
harmonics alone extend to.

Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from bodebench.core.benchgrid import fold_bound

__all__ = ["MAX_BINS", "MAX_PHASE_SLIP", "MIN_PERIODS", "PhaseAverage", "grid_stands_still", "waveform_fold_bound"]

MAX_BINS = 4096
"""The most samples a period a phase average is kept for (its snapshots hold about 80 copies of the bins): beyond,
the harmonics that fold lie above the 4,000th, and the bound from the solved harmonics stands alone."""

MAX_PHASE_SLIP = 0.25
"""The most (in samples) the grid may slip against the bins over the averaged periods, ``|N - round(N)|`` times
their number, for the average to stand for the waveform; beyond it the bins blur the harmonics near N/2."""

MIN_PERIODS = 8
"""The fewest periods :meth:`PhaseAverage.recent` averages."""

_SNAPSHOT_GROWTH = 1.125  # the running sums are kept at periods 1, 2, ... 8 and then about 12.5 % apart


def grid_stands_still(samples_per_period: float, highest: int) -> bool:
    """Whether a phase average can show the tail at N = ``samples_per_period`` samples a period with harmonics up to
    ``highest`` measured: N within :data:`MAX_PHASE_SLIP` of a whole number over :data:`MIN_PERIODS` periods, at
    least four bins a cycle of the harmonic above the highest, at most :data:`MAX_BINS` bins."""
    return (abs(samples_per_period - round(samples_per_period)) * MIN_PERIODS <= MAX_PHASE_SLIP
            and 4 * (highest + 1) <= samples_per_period <= MAX_BINS)


def _snapshot_periods(limit: int) -> list[int]:
    """The periods at which :class:`PhaseAverage` keeps its running sums, up to ``limit``."""
    out, p = [], 1
    while p <= limit:
        out.append(p)
        p = max(p + 1, int(p * _SNAPSHOT_GROWTH))
    return out


class PhaseAverage:
    """Sums of the samples by phase bin, round(N') bins a period of f, with snapshots of the running sums.

    frequency_hz: f (Hz); t0: the instant of phase zero (s); samples_per_period: N = rate / f; columns: the columns
    fed; max_periods: the longest record it keeps snapshots for. A sample at t falls in period floor(f (t - t0))
    and in bin round(N' x) mod N' of its phase x in [0, 1). :meth:`recent` gives the average over the latest
    quarter of a record (from the last snapshot before it).
    """

    def __init__(self, frequency_hz: float, t0: float, samples_per_period: float, columns: int,
                 max_periods: int) -> None:
        self.frequency_hz, self.t0 = frequency_hz, t0
        self.samples_per_period = samples_per_period
        self.bins = int(round(samples_per_period))
        self._sums = np.zeros((self.bins, columns))
        self._counts = np.zeros(self.bins)
        self._due = _snapshot_periods(max_periods + 1)
        self._next = 0  # index into _due of the next snapshot
        self._snapshots: dict[int, tuple[np.ndarray, np.ndarray]] = {0: (self._sums.copy(), self._counts.copy())}
        self.period = 0  # the period of the latest sample added

    def add(self, t: np.ndarray, y: np.ndarray) -> None:
        """Samples at t (s, increasing) with values y (n, columns); a snapshot is kept at each due period's start."""
        x = self.frequency_hz * (np.asarray(t, dtype=float) - self.t0)
        period = np.floor(x)
        keep = period >= 0
        if not keep.all():
            x, period, y = x[keep], period[keep], y[keep]
        if not x.size:
            return
        b = np.rint((x - period) * self.bins).astype(np.int64) % self.bins
        start = 0
        while self._next < len(self._due) and period[-1] >= self._due[self._next]:
            due = self._due[self._next]
            split = int(np.searchsorted(period, due, side="left"))
            self._add(b[start:split], y[start:split])
            self._snapshots[due] = (self._sums.copy(), self._counts.copy())
            start = split
            self._next += 1
        self._add(b[start:], y[start:])
        self.period = int(period[-1])

    def _add(self, b: np.ndarray, y: np.ndarray) -> None:
        if b.size:
            np.add.at(self._sums, b, y)
            self._counts += np.bincount(b, minlength=self.bins)

    def recent(self, periods: int) -> np.ndarray | None:
        """(bins, columns) the average waveform over the latest quarter of ``periods`` periods and every period
        added since (from the last snapshot at or before its start), or None: fewer than :data:`MIN_PERIODS` periods,
        a bin with no sample, or a grid that slips by more than :data:`MAX_PHASE_SLIP` samples over them."""
        if periods < MIN_PERIODS:
            return None
        start = max(p for p in self._snapshots if p <= periods - periods // 4)
        spanned = self.period + 1 - start
        if abs(self.samples_per_period - self.bins) * spanned > MAX_PHASE_SLIP:
            return None
        sums, counts = self._snapshots[start]
        n = self._counts - counts
        if not (n > 0).all():
            return None
        return (self._sums - sums) / n[:, None]


def waveform_fold_bound(waveform: np.ndarray, measured: Sequence[int], samples_per_period: float, harmonic: int,
                        periods: int, decay: float = 2.0) -> float:
    """A bound (output units) on what the rate folds onto measured ``harmonic``, from one period's average
    waveform on a whole grid (N' values of one column): its discrete harmonics m up to N'/2 above the measured ones
    (``2 X_m / N'``, X the DFT; near N'/2 each holds m and N' - m together, so it errs large) go to
    :func:`~bodebench.core.benchgrid.fold_bound`, which extends the level of the upper half of them, N'/4 to N'/2,
    as C / j**decay to the harmonics that fold."""
    n = waveform.size
    top = n // 2
    first = max(measured) + 1
    if top < first + 1:
        return math.inf
    spectrum = 2.0 * np.fft.rfft(waveform)[first: top + 1] / n
    return fold_bound(spectrum, range(first, top + 1), samples_per_period, harmonic, periods, decay)
