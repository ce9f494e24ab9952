"""A periodic multisine on a bench's sample grid: the overview measurement's excitation (docs/overview.md).

One period is a whole number N of samples at the sample rate, so each period's DFT resolves every line exactly:
line k is the frequency ``k * rate_hz / N`` (Hz) and no line leaks into another. The excited lines are odd and
spread evenly on a log axis between the start and stop frequency; between any two of them lies at least one odd
line left out. An odd-order nonlinearity of the plant puts content on those left-out odd lines, an even-order
one on the even lines, and a linear plant puts nothing on either: they are the detection lines of the
nonlinearity (an odd random-phase multisine). The phases start random and are refined by iterative clipping to a
low crest factor, so the waveform's peak is close to its rms.

Coefficients follow the convention of the rest of the instrument: a sine ``P sin(w t) + Q cos(w t)`` has the
coefficient ``P + jQ``, so the coefficient of the output over that of the input is the transfer function.
Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["DETECTION_REACH", "LINE_GAP", "Multisine", "MultisineError", "design_multisine", "sine_coefficients"]

LINE_GAP = 4
"""Least distance between two excited lines, in lines: an odd line left out lies between any two."""
DETECTION_REACH = 2
"""The detection lines of an excited line k are the lines not excited from k - 2 to k + 2: k +- 1 (even, for
even-order distortion) and k +- 2 (odd, left out, for odd-order distortion)."""
CLIP_ITERATIONS = 200
"""Rounds of clipping that refine the phases towards a low crest factor."""
CLIP_OVERSAMPLING = 16
"""Samples a period of the highest line on the grid the clipping runs on."""
CLIP_LEVEL = 0.8
"""Each round clips the waveform at this fraction of its peak before its phases are read back."""
MAX_SAMPLES = 10_000_000
"""Most samples a period may hold (a period of a 1 kHz rate and a 0.01 Hz start line already spans 400 000)."""


class MultisineError(ValueError):
    """A multisine the grid cannot hold; ``key`` names the argument of :func:`design_multisine` at fault."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key


def sine_coefficients(record: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """The coefficients P + jQ (record units) of ``lines`` (DFT indices) in one period ``record`` of N samples,
    sample n at n/N of the period: the DFT X_k times 2j/N. Exact for any sum of sines on the period's lines.
    ``record`` may be (N,) or (N, channels); the result is (lines,) or (lines, channels)."""
    n = record.shape[0]
    return np.fft.rfft(record, axis=0)[lines] * (2j / n)


@dataclass(frozen=True)
class Multisine:
    """One period of a multisine: ``u[n] = sum over lines of line_amplitude * sin(2 pi k n / N + phase_k)``.

    rate_hz: the sample rate, Hz; samples: N, the samples a period; lines: the excited DFT indices (odd,
    ascending); phases: their phases, rad; line_amplitude: every line's amplitude (peak of its sine), input units.
    """

    rate_hz: float
    samples: int
    lines: tuple[int, ...]
    phases: tuple[float, ...]
    line_amplitude: float

    @property
    def resolution_hz(self) -> float:
        """The spacing of the lines, rate_hz / N, Hz (one over the period)."""
        return self.rate_hz / self.samples

    @property
    def period_s(self) -> float:
        """The period, s."""
        return self.samples / self.rate_hz

    @property
    def frequencies_hz(self) -> np.ndarray:
        """The excited lines' frequencies, Hz."""
        return np.asarray(self.lines, dtype=float) * self.resolution_hz

    @property
    def coefficients(self) -> np.ndarray:
        """Each excited line's coefficient P + jQ, input units: ``line_amplitude * exp(j phase)``."""
        return self.line_amplitude * np.exp(1j * np.asarray(self.phases))

    def waveform(self) -> np.ndarray:
        """The N samples of one period, input units."""
        return _waveform(self.samples, np.asarray(self.lines), self.coefficients)

    @functools.cached_property
    def _extremes(self) -> tuple[float, float, float]:
        u = self.waveform()
        step = np.abs(np.diff(np.concatenate([u, u[:1]])))
        return float(np.max(np.abs(u))), float(np.sqrt(np.mean(u * u))), float(np.max(step))

    @property
    def peak(self) -> float:
        """The largest |u[n]| of the period, input units."""
        return self._extremes[0]

    @property
    def rms(self) -> float:
        """The root mean square of the period's samples, input units."""
        return self._extremes[1]

    @property
    def crest_factor(self) -> float:
        """peak / rms (dimensionless; sqrt(2) for one sine)."""
        return self.peak / self.rms

    @property
    def peak_slew(self) -> float:
        """The largest change between two successive samples (the period's last to the next one's first included)
        times the rate: the steepest slope the held setpoint's staircase follows, input units per s."""
        return self._extremes[2] * self.rate_hz

    def detection_lines(self, line: int) -> tuple[int, ...]:
        """The detection lines of excited line ``line``: the lines within :data:`DETECTION_REACH` of it that are
        not excited, none at 0 and none at or above N/2."""
        excited = set(self.lines)
        return tuple(k for k in range(line - DETECTION_REACH, line + DETECTION_REACH + 1)
                     if 0 < k < self.samples / 2 and k not in excited)


def _waveform(samples: int, lines: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """N samples of the sum of sines whose coefficients P + jQ are ``coefficients`` on ``lines``."""
    spectrum = np.zeros(samples // 2 + 1, dtype=complex)
    spectrum[lines] = coefficients * (samples / 2j)
    return np.fft.irfft(spectrum, n=samples)


def _log_spread_lines(first: int, last: int, per_decade: int) -> list[int]:
    """Odd lines from ``first`` up to ``last``, ``per_decade`` a decade on a log axis, each at least
    :data:`LINE_GAP` above the previous one."""
    ratio = 10.0 ** (1.0 / per_decade)
    top = last - 1 + last % 2  # the highest odd line allowed
    lines = [first]
    i = 1
    while True:
        target = first * ratio ** i
        i += 1
        nearest = 2 * round((target - 1.0) / 2.0) + 1  # the odd line nearest the target
        k = max(min(nearest, top), lines[-1] + LINE_GAP)
        if k > top or target > (top + 1.0) * (1.0 + 1e-9):
            return lines
        lines.append(k)


def _clipped_phases(samples: int, lines: np.ndarray, phases: np.ndarray) -> np.ndarray:
    """Phases of equal-amplitude lines refined by iterative clipping: each round clips the waveform at
    :data:`CLIP_LEVEL` of its peak and keeps the phases the clipped waveform has on the lines; the round of least
    crest factor wins. The rounds run on the least power-of-two grid of at least :data:`CLIP_OVERSAMPLING` samples
    a period of the highest line (N where that is fewer), whose peak is within a few percent of the full grid's."""
    grid = min(samples, 1 << math.ceil(math.log2(CLIP_OVERSAMPLING * int(lines[-1]))))
    best, best_crest = phases, math.inf
    for _ in range(CLIP_ITERATIONS):
        u = _waveform(grid, lines, np.exp(1j * phases))
        peak = float(np.max(np.abs(u)))
        crest = peak / float(np.sqrt(np.mean(u * u)))
        if crest < best_crest:
            best, best_crest = phases, crest
        clipped = np.clip(u, -CLIP_LEVEL * peak, CLIP_LEVEL * peak)
        phases = np.angle(sine_coefficients(clipped, lines))
    return best


@functools.lru_cache(maxsize=8)
def design_multisine(rate_hz: float, start_hz: float, stop_hz: float, lines_per_decade: int, peak: float,
                     seed: int = 0) -> Multisine:
    """The overview's multisine: odd lines log-spread from about ``start_hz`` to ``stop_hz`` (Hz),
    ``lines_per_decade`` a decade where the grid allows (at least :data:`LINE_GAP` lines apart), on a period of a
    whole number of samples at ``rate_hz`` (Hz); random phases (``seed``) refined to a low crest factor; scaled so
    that the waveform's peak is ``peak`` (input units).

    The first line's index is the least odd number from which the log spread holds LINE_GAP lines between two
    excited ones (at least 3, so that an odd line below it is left out too); the period is that many periods of
    ``start_hz``, rounded to whole samples, so the first line lies within half a sample's share of ``start_hz``.
    :class:`MultisineError` where the grid cannot hold it: ``stop_hz`` not above the first line, a period of more
    than :data:`MAX_SAMPLES` samples, or ``stop_hz`` not below half the rate.
    """
    if not 0 < start_hz < stop_hz:
        raise MultisineError("stop_hz", f"{stop_hz:g} Hz must be above start_hz ({start_hz:g} Hz), both > 0")
    if not stop_hz < rate_hz / 2:
        raise MultisineError("stop_hz", f"{stop_hz:g} Hz must be below half the sample rate ({rate_hz / 2:g} Hz)")
    ratio = 10.0 ** (1.0 / lines_per_decade)
    first = max(3, math.ceil(LINE_GAP / (ratio - 1.0)))
    first += 1 - first % 2
    samples = round(rate_hz * first / start_hz)
    if samples > MAX_SAMPLES:
        raise MultisineError("start_hz", f"{start_hz:g} Hz needs a period of {samples} samples (more than "
                                         f"{MAX_SAMPLES}): raise it or lower the sample rate")
    resolution = rate_hz / samples
    last = min(math.floor(stop_hz / resolution + 1e-9), (samples - 1) // 2 - DETECTION_REACH)
    lines = _log_spread_lines(first, last, lines_per_decade)
    if len(lines) < 2:
        raise MultisineError("stop_hz", f"{stop_hz:g} Hz leaves one line: the lines start at "
                                        f"{first * resolution:g} Hz, the next lies {LINE_GAP * resolution:g} Hz "
                                        "above it at least")
    index = np.asarray(lines)
    start = np.random.default_rng(seed).uniform(-math.pi, math.pi, index.size)
    phases = _clipped_phases(samples, index, start)
    unit_peak = float(np.max(np.abs(_waveform(samples, index, np.exp(1j * phases)))))
    return Multisine(rate_hz=float(rate_hz), samples=samples, lines=tuple(lines),
                     phases=tuple(float(p) for p in phases), line_amplitude=peak / unit_peak)
