"""What a bench's own grid and surroundings do to a point that no spread between periods can show.

Two effects repeat identically, or nearly, in every period, so the per-period coefficients agree with each other and
the stated interval shrinks while the value is off:

- **A periodic disturbance** at a frequency d (mains hum at 50 or 60 Hz and its 2nd and 3rd harmonics, a pump's
  ripple) adds to harmonic k of a point at f a phasor that turns by ``2 pi (d / f - k)`` every period. Averaged over
  n periods it is smaller than itself by about ``1 / (pi n |d/f - k|)``; when ``|d - k f| < f / n`` it has not turned
  even once: it is a constant the average keeps, indistinguishable from the response. Such a point is flagged
  ``disturbed``; the plan can move the frequency so the disturbance turns at least once in ``MIN_BEAT_PERIODS``
  periods (its pass through the periods then shows in their spread and in the stated interval).
- **Aliasing**: at N = rate / f samples a period, harmonic j of a nonlinear response is indistinguishable from
  harmonic ``|j - m N|``. When N is a whole number (or a fraction with a small denominator) some harmonic
  ``j = m N +- k`` folds exactly onto a measured harmonic k, every period alike. :func:`folding_harmonic` names the
  lowest such j; below ``FOLD_ORDER`` the loader warns, since a strongly nonlinear response still has content there.
  :func:`move_off_folds` (``[analysis] folds = "move"``) moves such a frequency by the least that makes every fold
  through the first ``FOLD_IMAGES`` images of the rate turn against its harmonic: the folded content then differs
  from period to period, the average thins it, and the spread and the stated interval see what is left.

  What folds exactly cannot be told apart from the response, but the record shows what lies above the measured
  harmonics: the bench's integrator solves harmonics up to :func:`alias_fit_order` (which also stops them leaking
  into the measured ones on any grid), and :func:`fold_bound` extends their level to the harmonics the rate folds,
  for a point to carry in its interval or to end ``alias_limited`` (on a whole grid
  :mod:`~bodebench.core.phase_average` shows the level up to N/2 as well).

Pure numerics: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from bodebench.core.response import ResponsePoint
from bodebench.status import PointStatus

__all__ = ["DISTURBANCE_HARMONICS", "FIT_ORDER_MAX", "FOLD_IMAGES", "FOLD_ORDER", "FOLD_TURN", "LINE_TURNS",
           "MIN_BEAT_PERIODS", "alias_fit_order", "disturbance_lines", "flag_disturbed", "fold_beat", "fold_bound",
           "folding_harmonic", "folding_notes", "line_leak", "lines_beyond_fit", "lines_near", "lines_on_fit",
           "lines_on_harmonics", "mark_untied", "move_off_disturbances", "move_off_folds", "nearest_line",
           "seen_at", "turning_amplitude"]

DISTURBANCE_HARMONICS = 3
"""Each listed disturbance frequency counts with its harmonics up to this one (mains: 50, 100, 150 Hz)."""

MIN_BEAT_PERIODS = 50.0
"""A moved frequency lets every disturbance line turn once against each measured harmonic within this many
periods."""

FOLD_ORDER = 32
"""Harmonics up to this order of a nonlinear response are taken as able to matter when they fold onto a measured
one."""


def disturbance_lines(disturbance_hz: Sequence[float]) -> tuple[float, ...]:
    """Every disturbance line (Hz): each listed frequency and its harmonics up to ``DISTURBANCE_HARMONICS``."""
    return tuple(sorted({m * d for d in disturbance_hz for m in range(1, DISTURBANCE_HARMONICS + 1)}))


def lines_beyond_fit(lines: Sequence[float], frequency_hz: float, samples_per_period: float, solved: int
                     ) -> tuple[float, ...]:
    """The disturbance ``lines`` (Hz) as samples at ``samples_per_period`` times ``frequency_hz`` see them (folded
    into 0 .. half the rate; as they are where the rate is unknown, 0), those nearest a whole harmonic of f above
    harmonic ``solved`` (the highest each period is solved for): the lines whose leak :func:`line_leak` bounds, each
    amplitude read from what the solved harmonics leave of the record at the line."""
    return lines_near(lines, frequency_hz, samples_per_period, solved, math.inf)


def lines_on_fit(lines: Sequence[float], frequency_hz: float, samples_per_period: float, measured: Sequence[int],
                 solved: int) -> tuple[float, ...]:
    """The disturbance ``lines`` (Hz, as the samples see them) nearest a whole harmonic j of f that each period is
    solved for (1 .. ``solved``) but not ``measured``: the solve takes such a line into harmonic j's coefficient,
    which turns with it, and :func:`line_leak` bounds what it leaks into the measured ones, its amplitude read by
    :func:`turning_amplitude`."""
    return lines_on_harmonics(lines, frequency_hz, samples_per_period,
                              [j for j in range(1, solved + 1) if j not in measured])


def lines_on_harmonics(lines: Sequence[float], frequency_hz: float, samples_per_period: float,
                       harmonics: Sequence[int]) -> tuple[float, ...]:
    """The disturbance ``lines`` (Hz, as the samples see them) whose nearest whole harmonic of f is one of
    ``harmonics``: on a measured one, the line turns that harmonic's own per-period coefficients, which
    :func:`turning_amplitude` reads it from, and :func:`line_leak` bounds what it leaks into the other measured
    ones (the harmonic it lies on is :func:`flag_disturbed`'s)."""
    return tuple(d for d in lines_near(lines, frequency_hz, samples_per_period, 0, max(harmonics, default=0))
                 if round(d / frequency_hz) in harmonics)


def seen_at(line_hz: float, rate_hz: float) -> float:
    """A line (Hz) as samples at ``rate_hz`` see it: folded into 0 .. half the rate (as it is where the rate is
    unknown, 0)."""
    return abs(line_hz - rate_hz * round(line_hz / rate_hz)) if rate_hz > 0 else abs(line_hz)


def lines_near(lines: Sequence[float], frequency_hz: float, samples_per_period: float, above: float, up_to: float
               ) -> tuple[float, ...]:
    """The disturbance ``lines`` (Hz) as samples at ``samples_per_period`` times ``frequency_hz`` see them (folded
    into 0 .. half the rate; as they are where the rate is unknown, 0) whose nearest whole harmonic j of f has
    ``above < j <= up_to``."""
    rate = samples_per_period * frequency_hz
    seen = {seen_at(d, rate) for d in lines}
    return tuple(sorted(d for d in seen if d > 0 and above < round(d / frequency_hz) <= up_to))


def turning_amplitude(coefficients: np.ndarray, line_harmonics: float, spread: float = 2.0) -> float:
    """The amplitude of a disturbance line at ``line_harmonics`` times f (x, delta = x - j its distance from the
    nearest whole harmonic j) that a solved harmonic j's per-period ``coefficients`` (complex, output units, in
    period order) take in, read from how they turn: a line adds ``b exp(i 2 pi delta m)`` to period m's coefficient
    (``|b| = h |sin(pi delta)| / (pi |delta|)``, h its amplitude), fitted with a constant as
    ``a + beta (exp(i 2 pi delta m) - 1) / (i 2 pi delta)``, well posed however little the line turns over the
    periods (``beta = i 2 pi delta b``), so ``h = |beta| / (2 |sin(pi delta)|)``. ``|beta|`` is taken ``spread``
    standard errors above its estimate (the scatter about the fit, as the periods' noise), so that noise reads as a
    line rather than hide one. 0 for fewer than 3 periods or a line on the harmonic itself (it leaks nothing)."""
    m = coefficients.shape[0]
    delta = line_harmonics - round(line_harmonics)
    turn = abs(math.sin(math.pi * delta))
    if m < 3 or turn == 0.0:
        return 0.0
    index = np.arange(m) - 0.5 * (m - 1)
    # (exp(i 2 pi delta m) - 1) / (i 2 pi delta), exact where delta m is small
    basis = index * np.sinc(delta * index) * np.exp(1j * math.pi * delta * index)
    basis = basis - basis.mean()
    centred = coefficients - coefficients.mean()
    norm = float(np.vdot(basis, basis).real)
    beta = complex(np.vdot(basis, centred)) / norm
    scatter = float(np.sum(np.abs(centred - beta * basis) ** 2)) / (m - 2)
    return (abs(beta) + spread * math.sqrt(scatter / norm)) / (2.0 * turn)


LINE_TURNS = 2.0
"""A disturbance line that has turned this many times against the harmonics over a point's periods shows its leak
in the spread between them: :func:`line_leak` bounds it only before."""


def line_leak(amplitude: float, line_harmonics: float, harmonic: int, periods: int) -> float:
    """The most a disturbance line of ``amplitude`` at ``line_harmonics`` times f (x) leaks into the average of
    ``periods`` periods of ``harmonic`` k while it has turned fewer than :data:`LINE_TURNS` times against the
    harmonics (0 after). Each period takes ``amplitude sin(pi delta) / pi (1 / |x - k| + 1 / (x + k))`` of it
    (delta = x - j, j the nearest whole harmonic), turned by delta cycles from the period before, and the average of
    n such turns is at most ``1 / (n sin(pi delta))`` of one (the envelope of the Dirichlet kernel). A line that
    stands still (n |delta| small) leaks a constant no spread shows; a line exactly on a whole harmonic leaks into no
    other (on its own it is :func:`flag_disturbed`'s)."""
    delta = line_harmonics - round(line_harmonics)
    if delta == 0.0 or periods * abs(delta) >= LINE_TURNS:
        return 0.0
    return amplitude * min(abs(math.sin(math.pi * delta)), 1.0 / periods) / math.pi * (
        1.0 / abs(line_harmonics - harmonic) + 1.0 / (line_harmonics + harmonic))


def nearest_line(frequency_hz: float, harmonic: int, lines: Sequence[float]) -> float:
    """The disturbance line (Hz) closest to harmonic ``harmonic`` of ``frequency_hz`` (NaN when there is none)."""
    target = harmonic * frequency_hz
    return min(lines, key=lambda d: abs(d - target)) if lines else math.nan


def flag_disturbed(points: Sequence[ResponsePoint], lines: Sequence[float]) -> list[ResponsePoint]:
    """``points`` with every point whose harmonic lies within its resolution of a disturbance line (``|d - k f| <
    f / n`` for the n periods it took) marked ``disturbed`` and not converged: whatever of the disturbance reached
    the output is in its value, and its interval cannot show it."""
    out = []
    for p in points:
        d = nearest_line(p.frequency_hz, p.harmonic, lines)
        if math.isfinite(d) and p.periods and abs(d - p.harmonic * p.frequency_hz) * p.periods < p.frequency_hz:
            p = replace(p, converged=False, within_eps=False, status=PointStatus.DISTURBED)
        out.append(p)
    return out


def mark_untied(points: Sequence[ResponsePoint]) -> list[ResponsePoint]:
    """``points`` marked ``untied`` and not converged: measured on the realtime clock by a drive that gives no way to
    date the sine on its own clock, so the host's latency is in their phase."""
    return [replace(p, converged=False, within_eps=False, status=PointStatus.UNTIED) for p in points]


FOLD_IMAGES = 8
"""Images m fs of the sample rate, m = 1 .. this, whose folds :func:`move_off_folds` keeps turning: harmonics up to
about this many times the samples a period (a fold through a higher image comes from a harmonic of a response too
high to matter, and keeping every image turning is impossible at few samples a period)."""

FOLD_TURN = 0.1
"""A fold through image m must turn at least ``FOLD_TURN / m`` cycles a period against the harmonic it lands on
(once in 10 periods for the first image, whose harmonics are the strongest): fast enough that the average of a
few dozen periods thins it and their spread shows it."""


def fold_beat(rate_hz: float, frequency_hz: float) -> float:
    """How fast the folds of a grid turn, against :data:`FOLD_TURN`: min over images m = 1 .. ``FOLD_IMAGES`` of m
    times the distance of m N (N = rate / f samples a period) from a whole number. Harmonic j folded through image m
    lands at ``|j - m N|`` harmonics, off a whole one by that distance (cycles a period), whatever j is."""
    n = rate_hz / frequency_hz
    return min(m * abs(m * n - round(m * n)) for m in range(1, FOLD_IMAGES + 1))


def move_off_folds(rate_hz: float, frequencies_hz: Sequence[float], harmonics: Sequence[int],
                   lines: Sequence[float] = ()) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """The plan moved so that every frequency's folds turn (:func:`fold_beat` at least :data:`FOLD_TURN`): each
    frequency whose samples a period N lie too near a fraction with a denominator up to ``FOLD_IMAGES`` moves to
    the nearest N that does not (the larger first: a lower frequency, never fewer samples a period) and keeps its
    harmonics off the disturbance ``lines`` as :func:`move_off_disturbances` does. Returns the frequencies and one
    line saying how many moved and by how much."""
    step = FOLD_TURN / (4 * FOLD_IMAGES * FOLD_IMAGES)

    def free(g: float) -> bool:
        return fold_beat(rate_hz, g) >= FOLD_TURN and not _near_lines(g, harmonics, lines)

    moved: list[float] = []
    largest = 0.0
    for f in frequencies_hz:
        g = f
        if not free(f):
            n = rate_hz / f
            for i in range(1, int(0.5 / step) + 1):  # the nearest free N, more samples a period first
                candidates = [rate_hz / (n + side * i * step) for side in (1, -1)]
                g = next((c for c in candidates if free(c)), f)
                if g != f:
                    break
            largest = max(largest, abs(g - f) / f)
        moved.append(g)
    count = sum(g != f for g, f in zip(moved, frequencies_hz, strict=True))
    if not count:
        return tuple(moved), ()
    return tuple(moved), (f"{count} of {len(moved)} frequencies moved, by at most {100 * largest:.2g} %, off sample "
                          f"counts at which the rate ({rate_hz:g} Hz) folds high harmonics of a nonlinear response "
                          "exactly onto measured ones: each fold now turns within the periods averaged, where their "
                          "spread sees it",)


def _near_lines(frequency_hz: float, harmonics: Sequence[int], lines: Sequence[float]) -> list[tuple[int, float]]:
    """(k, d) for each measured harmonic k of ``frequency_hz`` closer to a disturbance line d than ``f /
    MIN_BEAT_PERIODS``."""
    return [(k, d) for k in harmonics for d in lines if abs(d - k * frequency_hz) * MIN_BEAT_PERIODS < frequency_hz]


def move_off_disturbances(frequencies_hz: Sequence[float], harmonics: Sequence[int], lines: Sequence[float]
                          ) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """The plan moved so that no measured harmonic of any frequency lies closer to a disturbance line than ``f /
    MIN_BEAT_PERIODS``: each frequency too close moves away from the line, by the least that frees it from all
    lines (at most a few percent). Returns the frequencies and one line per move saying why."""
    moved: list[float] = []
    notes: list[str] = []
    for f in frequencies_hz:
        g = f
        for _ in range(8):  # moving off one line can approach another: a few rounds settle it
            close = _near_lines(g, harmonics, lines)
            if not close:
                break
            k, d = close[0]
            # k g' - d = +-g'/B  ->  g' = d / (k -+ 1/B); away from the line, on the side g already is
            side = 1.0 if k * g >= d else -1.0
            g = d / (k - side / MIN_BEAT_PERIODS) * (1.0 + side * 1e-9)
        if g != f:
            k_lines = ", ".join(f"{k} x {f:g} Hz = {k * f:g} Hz" for k, _ in _near_lines(f, harmonics, lines))
            notes.append(f"{f:g} Hz moved to {g:.6g} Hz: {k_lines} lay within {100 / MIN_BEAT_PERIODS:g} % of a "
                         f"disturbance line ({', '.join(f'{d:g}' for d in lines)} Hz)")
        moved.append(g)
    return tuple(moved), tuple(notes)


def folding_notes(rate_hz: float, frequencies_hz: Sequence[float], harmonics: Sequence[int]) -> tuple[str, ...]:
    """One line for each frequency at which the sample rate folds a harmonic up to ``FOLD_ORDER`` exactly onto a
    measured one."""
    notes = []
    for f in frequencies_hz:
        fold = folding_harmonic(rate_hz, f, harmonics)
        if fold is not None:
            notes.append(f"{f:g} Hz: at {rate_hz / f:.6g} samples a period, harmonic {fold[0]} of a nonlinear "
                         f"response folds exactly onto measured harmonic {fold[1]} in every period, where no interval "
                         "can see it; a frequency a little off this one spreads it over the periods instead "
                         "([analysis] folds = \"move\"), and folds = \"bound\" bounds it in every interval")
    return tuple(notes)


def folding_harmonic(rate_hz: float, frequency_hz: float, harmonics: Sequence[int], order: int = FOLD_ORDER,
                     resolution: float = 1e-3) -> tuple[int, int] | None:
    """(j, k): the lowest harmonic j <= ``order`` of ``frequency_hz`` that the sample rate folds onto a measured
    harmonic k to within ``resolution`` of a harmonic spacing (a beat slower than 1 / resolution periods); None when
    none does. j folds onto |j - m N| for N = rate / f samples a period."""
    n = rate_hz / frequency_hz
    best: tuple[int, int] | None = None
    for m in range(1, int((order + max(harmonics)) / n) + 2):
        x = m * n
        nearest = round(x)
        if abs(x - nearest) > resolution:
            continue
        for k in harmonics:
            for j in (nearest - k, nearest + k):
                if j > max(harmonics) and j <= order and j != k and (best is None or j < best[0]):
                    best = (j, k)
    return best


FIT_ORDER_MAX = 8
"""The highest harmonic the bench's integrator solves for (:func:`alias_fit_order`)."""


def alias_fit_order(samples_per_period: float, highest: int) -> int:
    """K': the harmonics the bench's integrator solves for at ``samples_per_period`` samples a period: up to a quarter
    of them (each solved harmonic keeps four samples a cycle, so the per-period solve stays well conditioned on a
    jittered grid), at most :data:`FIT_ORDER_MAX`, at least the ``highest`` measured one."""
    if not math.isfinite(samples_per_period) or samples_per_period <= 0:
        return highest
    return max(highest, min(FIT_ORDER_MAX, int(samples_per_period // 4)))


def fold_bound(mean: np.ndarray, high_harmonics: Sequence[int], samples_per_period: float, harmonic: int,
               periods: int, decay: float = 2.0) -> float:
    """A bound (output units) on what the sampling folds onto measured ``harmonic`` and the average of ``periods``
    periods keeps of it.

    mean: the averaged coefficient of each of ``high_harmonics`` (the solved harmonics above the measured ones). Their
    sizes over the upper half of them are extended as C / j**decay (C the largest size times its harmonic to that
    power): the spectrum of a continuous output falls at least as fast as j**-2, of one with a continuous slope as
    j**-3 (the bound from a whole grid's averaged waveform takes ``[analysis] fold_decay``). What noise or a
    transient leaves in the average counts as content (a bound errs large, never small): noise adds about
    ``(K' / N)**decay`` of its own average to the bound.
    At N samples a period harmonic j folds onto ``|j - m N|``; each j = m N -+ k (m = 1 .. :data:`FOLD_IMAGES`, as
    the plan's moves) counts with C / j**decay times what an average of ``periods`` periods keeps of a phasor turning
    d cycles a period against the harmonic (d: the distance of m N -+ k from a whole number), at most
    ``min(1, 1 / (2 periods d))``: whole where the fold stands still, less where it turns. Not covered: folds through
    higher images, and a discontinuous output (a step in every period), whose spectrum falls only as 1 / j."""
    n = len(high_harmonics)
    if not n or not math.isfinite(samples_per_period) or samples_per_period <= 0 or periods < 1:
        return 0.0
    top = slice(n // 2, n)
    orders = np.asarray(high_harmonics, dtype=float)[top]
    envelope = float(np.max(np.abs(np.asarray(mean)[top]) * orders ** decay))
    if not envelope > 0.0:
        return 0.0
    images = np.arange(1, FOLD_IMAGES + 1) * samples_per_period
    folded = np.concatenate((images - harmonic, images + harmonic))
    turn = np.abs(folded - np.round(folded))  # cycles a period the fold turns against the harmonic
    kept = np.minimum(1.0, 1.0 / np.maximum(2.0 * periods * turn, 1e-300))  # what the average of the periods keeps
    above = folded > orders[-1]
    return envelope * float(np.sum(kept[above] / np.round(folded[above]) ** decay))
