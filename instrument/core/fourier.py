"""Per-period Fourier coefficients by the trapezoidal rule (docs/METHOD.md section 1).

A :class:`PeriodIntegrator` takes a stream of timestamped multi-channel samples and, for every whole
period of the reference frequency, returns the Fourier coefficients

    P_k(i) = 2 f * integral over period i of y(t) sin(2 pi k f (t - t0)) dt
    Q_k(i) = 2 f * integral over period i of y(t) cos(2 pi k f (t - t0)) dt

where the integral is the trapezoidal rule applied to the product of signal and reference function.
Period i (i = 1, 2, ...) spans [t0 + (i - 1)/f, t0 + i/f] seconds. Period edges that fall between two
samples get a virtual sample, linearly interpolated between its neighbours, so that every period's
integral covers exactly its own interval. Results do not depend on how the stream is split into chunks.

With ``max_gap`` (periods), :meth:`PeriodIntegrator.feed_marked` also tells which periods are whole: a period is
not whole when any part of it lies between two samples further apart than ``max_gap`` (a gap in the stream that
the trapezoidal rule would bridge by a straight line).

A :class:`GridPeriodIntegrator` is the same rule for the samples of a computation: a uniform grid of N steps per
period with t0 on it. Every period then holds exactly N + 1 samples, two of them on its edges, and its coefficients
are one matrix product of those samples with the trapezoidal weights ``(2/N) w_j sin(2 pi k j/N)`` and
``(2/N) w_j cos(2 pi k j/N)`` (w_j = 1/2 on the edges, 1 inside).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence

import numpy as np

__all__ = ["LINE_GAIN_MAX_SAMPLES_PER_PERIOD", "LINE_GAIN_PERIODS", "LINE_GAIN_SAMPLES", "ExactPeriodIntegrator",
           "GridPeriodIntegrator", "PeriodIntegrator", "line_gains"]

_TWO_PI = 2.0 * math.pi


class PeriodIntegrator:
    """Trapezoidal Fourier coefficients of each whole period of a sampled multi-channel signal.

    Attributes:
        frequency_hz: reference frequency f in Hz.
        harmonics: harmonic numbers k (positive integers), in the order of the last output axis.
        n_channels: number of signal channels.
        t0: start of period 1 in seconds; the reference functions have zero phase at t0.
        periods_done: number of complete periods emitted so far.
        max_gap: longest interval between two samples a whole period may contain, in periods (inf: any).
    """

    _LEAST_HARMONIC = 1  # harmonic 0 (P = 0, Q = twice the mean) is for the moments of ExactPeriodIntegrator

    def __init__(self, frequency_hz: float, harmonics: Sequence[int], n_channels: int, t0: float = 0.0,
                 max_gap: float = math.inf) -> None:
        freq = float(frequency_hz)
        if not math.isfinite(freq) or freq <= 0.0:
            raise ValueError(f"frequency_hz must be a finite positive number of Hz, got {frequency_hz!r}")
        if isinstance(harmonics, (str, bytes)) or not isinstance(harmonics, Sequence):
            raise ValueError(f"harmonics must be a sequence of positive integers, got {harmonics!r}")
        if len(harmonics) == 0:
            raise ValueError("harmonics must contain at least one harmonic number")
        for k in harmonics:
            if isinstance(k, bool) or not isinstance(k, numbers.Integral) or k < self._LEAST_HARMONIC:
                raise ValueError(f"harmonics must be positive integers, got {k!r} in {list(harmonics)!r}")
        if isinstance(n_channels, bool) or not isinstance(n_channels, numbers.Integral) or n_channels < 1:
            raise ValueError(f"n_channels must be a positive integer, got {n_channels!r}")
        start = float(t0)
        if not math.isfinite(start):
            raise ValueError(f"t0 must be a finite number of seconds, got {t0!r}")
        gap = float(max_gap)
        if not gap > 0.0:
            raise ValueError(f"max_gap must be a positive number of periods, got {max_gap!r}")

        self.frequency_hz: float = freq
        self.harmonics: tuple[int, ...] = tuple(int(k) for k in harmonics)
        self.n_channels: int = int(n_channels)
        self.t0: float = start
        self.periods_done: int = 0
        self.max_gap: float = gap

        self._k: np.ndarray = np.asarray(self.harmonics, dtype=np.float64)
        n_h = len(self.harmonics)
        # State carried between feed() calls: the last sample and the partial sums of its period.
        self._has_last: bool = False
        self._t_last: np.ndarray = np.empty(1)
        self._u_last: np.ndarray = np.empty(1)
        self._p_last: np.ndarray = np.empty(1, dtype=np.int64)
        self._y_last: np.ndarray = np.empty((self.n_channels, 1))
        self._ws_last: np.ndarray = np.empty((self.n_channels, n_h, 1))
        self._wc_last: np.ndarray = np.empty((self.n_channels, n_h, 1))
        self._acc_p: np.ndarray = np.zeros((self.n_channels, n_h))
        self._acc_q: np.ndarray = np.zeros((self.n_channels, n_h))
        self._gap_open: bool = False  # the period in progress holds part of a gap longer than max_gap

    # ------------------------------------------------------------------ input checks

    def _check(self, t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t_arr = np.asarray(t, dtype=np.float64)
        if t_arr.ndim != 1:
            raise ValueError(f"t must be a 1-D array of seconds, got shape {t_arr.shape}")
        n = t_arr.shape[0]
        y_arr = np.asarray(y, dtype=np.float64)
        if y_arr.ndim == 1 and self.n_channels == 1:
            y_arr = y_arr.reshape(-1, 1)
        if y_arr.shape != (n, self.n_channels):
            expected = f"({n}, {self.n_channels})" + (f" or ({n},)" if self.n_channels == 1 else "")
            raise ValueError(f"y must have shape {expected} to match t of length {n}, got shape {y_arr.shape}")
        if n == 0:
            return t_arr, y_arr
        finite_t = np.isfinite(t_arr)
        if not finite_t.all():
            i = int(np.argmin(finite_t))
            raise ValueError(f"t[{i}] = {t_arr[i]!r} is not a finite time")
        finite_y = np.isfinite(y_arr).all(axis=1)
        if not finite_y.all():
            i = int(np.argmin(finite_y))
            raise ValueError(f"y[{i}] = {y_arr[i]!r} contains a non-finite value")
        if self._has_last:
            if not t_arr[0] > self._t_last[0]:
                raise ValueError(
                    f"t[0] = {t_arr[0]!r} is not later than the last sample of the previous call "
                    f"({self._t_last[0]!r}); t must be strictly increasing"
                )
        elif t_arr[0] > self.t0:
            raise ValueError(
                f"the first sample t[0] = {t_arr[0]!r} s is after t0 = {self.t0!r} s, so period 1 would be "
                "incomplete; the stream must start at or before t0"
            )
        if n > 1:
            bad = np.flatnonzero(~(np.diff(t_arr) > 0.0))
            if bad.size:
                i = int(bad[0]) + 1
                raise ValueError(
                    f"t[{i}] = {t_arr[i]!r} is not later than t[{i - 1}] = {t_arr[i - 1]!r}; "
                    "t must be strictly increasing"
                )
        return t_arr, y_arr

    def _empty_marked(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        shape = (0, self.n_channels, len(self.harmonics))
        return np.zeros(shape), np.zeros(shape), np.zeros(0, dtype=bool)

    # ------------------------------------------------------------------ streaming

    def feed(self, t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Integrate a chunk of samples and return the coefficients of the periods it completes.

        Args:
            t: (n,) sample times in seconds, strictly increasing (also across calls). The very first
                sample fed must be at or before t0; samples before t0 are ignored except for the part
                of the segment straddling t0 that lies after it.
            y: (n, n_channels) samples (or (n,) when n_channels == 1), in the signal's own units.

        Returns:
            (P, Q), each of shape (m, n_channels, n_harmonics), in the signal's units, for the m periods
            completed by this chunk (m may be 0). Row j is period ``periods_done_before + j + 1``.

        Raises:
            ValueError: t not 1-D, not finite or not strictly increasing (the offending index is named),
                y of the wrong shape or not finite, or a first sample later than t0.
        """
        p, q, _ = self.feed_marked(t, y)
        return p, q

    def feed_marked(self, t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`feed`, and with it a (m,) boolean array: True for each period completed that is whole (no part of
        it between two samples further apart than ``max_gap``), False for one a gap touched."""
        t_arr, y_arr = self._check(t, y)
        if t_arr.shape[0] == 0:
            return self._empty_marked()

        f = self.frequency_hz
        u_new = (t_arr - self.t0) * f  # time since t0 in periods
        fl_new = np.floor(u_new)
        # Arrays run with the sample axis last (contiguous), (channel, harmonic, sample) where both apply.
        # Phase from the fractional part of u keeps the argument small on long runs.
        phase = self._k[:, None] * (_TWO_PI * (u_new - fl_new))[None, :]
        # Periods before period 1 (index -1 and below) are all merged into index -1 and later discarded.
        p_new = np.maximum(fl_new, -1.0).astype(np.int64)
        y_new = np.ascontiguousarray(y_arr.T)
        ws_new = y_new[:, None, :] * np.sin(phase)[None, :, :]
        wc_new = y_new[:, None, :] * np.cos(phase)[None, :, :]

        if self._has_last:
            tt = np.concatenate((self._t_last, t_arr))
            uu = np.concatenate((self._u_last, u_new))
            pp = np.concatenate((self._p_last, p_new))
            yy = np.concatenate((self._y_last, y_new), axis=-1)
            ws = np.concatenate((self._ws_last, ws_new), axis=-1)
            wc = np.concatenate((self._wc_last, wc_new), axis=-1)
            acc_p, acc_q = self._acc_p, self._acc_q
        else:
            tt, uu, pp, yy, ws, wc = t_arr, u_new, p_new, y_new, ws_new, wc_new
            acc_p = np.zeros_like(self._acc_p)
            acc_q = np.zeros_like(self._acc_q)

        self._has_last = True
        self._t_last = tt[-1:].copy()
        self._u_last = uu[-1:].copy()
        self._p_last = pp[-1:].copy()
        self._y_last = yy[:, -1:].copy()
        self._ws_last = ws[..., -1:].copy()
        self._wc_last = wc[..., -1:].copy()

        n_pts = tt.shape[0]
        if n_pts < 2:
            self._acc_p, self._acc_q = acc_p, acc_q
            return self._empty_marked()

        du = np.diff(tt) * f  # segment lengths in periods
        n_cross = np.diff(pp)  # period edges crossed by each segment
        n_edges = int(n_cross.sum())

        if n_edges == 0:
            # Whole chunk inside the current period: one trapezoid sum, no output.
            self._acc_p = acc_p + ((ws[..., :-1] + ws[..., 1:]) * du).sum(axis=-1)
            self._acc_q = acc_q + ((wc[..., :-1] + wc[..., 1:]) * du).sum(axis=-1)
            self._gap_open = self._gap_open or bool(np.any(du > self.max_gap))
            return self._empty_marked()

        sums_p, sums_q, first_period = self._integrate_with_edges(uu, pp, yy, ws, wc, du, n_cross)
        sums_p[0] += acc_p
        sums_q[0] += acc_q

        # The last row is the period still in progress (it holds the last sample).
        self._acc_p = sums_p[-1].copy()
        self._acc_q = sums_q[-1].copy()
        skip = max(0, -first_period)  # rows of periods before period 1
        out_p = sums_p[skip:-1]
        out_q = sums_q[skip:-1]
        touched = self._touched_by_gaps(uu, pp, du, first_period, sums_p.shape[0])
        self.periods_done += out_p.shape[0]
        return out_p, out_q, ~touched[skip:-1]

    def _touched_by_gaps(self, uu: np.ndarray, pp: np.ndarray, du: np.ndarray, first: int, rows: int
                         ) -> np.ndarray:
        """(rows,) True for each period (row 0: period ``first``) that some part of a segment longer than
        ``max_gap`` lies in; the last row's flag is carried to the next call (its period is still in progress)."""
        touched = np.zeros(rows, dtype=bool)
        gaps = np.flatnonzero(du > self.max_gap)
        if gaps.size:
            lo = pp[gaps]
            # a segment ending exactly on an edge has nothing in the period that edge opens
            hi = np.maximum(lo, pp[gaps + 1] - (uu[gaps + 1] == pp[gaps + 1]))
            marks = np.zeros(rows + 1, dtype=np.int64)
            np.add.at(marks, lo - first, 1)
            np.add.at(marks, hi - first + 1, -1)
            touched = np.cumsum(marks[:-1]) > 0
        touched[0] |= self._gap_open
        self._gap_open = bool(touched[-1])
        return touched

    def _integrate_with_edges(
        self,
        uu: np.ndarray,
        pp: np.ndarray,
        yy: np.ndarray,
        ws: np.ndarray,
        wc: np.ndarray,
        du: np.ndarray,
        n_cross: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """Sum the trapezoids of every period touched, segments that cross a period edge split at it.

        ``yy`` (channel, sample), ``ws``/``wc`` (channel, harmonic, sample). Returns per-period sums of P and Q,
        (period, channel, harmonic) for period indices first_period .. pp[-1] (0-based), and first_period.
        """
        first = int(pp[0])
        n_c, n_h = ws.shape[0], ws.shape[1]
        sums_p = np.zeros((n_c, n_h, int(pp[-1]) - first + 1))
        sums_q = np.zeros_like(sums_p)

        # Segments inside one period, summed per period (a segment's period is the one its first sample is in;
        # they come in order, so groups of equal periods are runs).
        seg_p = (ws[..., :-1] + ws[..., 1:]) * du
        seg_q = (wc[..., :-1] + wc[..., 1:]) * du
        crossing = np.flatnonzero(n_cross)
        seg_p[..., crossing] = 0.0
        seg_q[..., crossing] = 0.0
        seg_period = pp[:-1]
        starts = np.concatenate(([0], np.flatnonzero(np.diff(seg_period)) + 1))
        rows = seg_period[starts] - first
        sums_p[..., rows] = np.add.reduceat(seg_p, starts, axis=-1)
        sums_q[..., rows] = np.add.reduceat(seg_q, starts, axis=-1)

        # A segment crossing edges pp+1 .. pp+n: a virtual sample at each edge, linearly interpolated (there
        # sin(2 pi k e) = 0 and cos(2 pi k e) = 1); the piece before the first edge ends the segment's first
        # period, the piece after the last begins the next sample's, and whole periods lie between edges.
        # Each period gets at most one piece of each kind, so no sum below adds twice into one period.
        i = crossing
        ua, span, seg_du = uu[i], uu[i + 1] - uu[i], du[i]
        ya, dy = yy[:, i], yy[:, i + 1] - yy[:, i]

        def at_edge(edge: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """(fraction of the segment before the edge, the interpolated sample (channel, edge)) for the edges
            ``edge`` of the crossing segments ``seg``."""
            alpha = (edge - ua[seg]) / span[seg]
            return alpha, ya[:, seg] + alpha * dy[:, seg]

        every = np.arange(i.size)
        a_first, y_first = at_edge(pp[i] + 1.0, every)
        a_last, y_last = at_edge((pp[i] + n_cross[i]).astype(np.float64), every)
        head = a_first * seg_du
        tail = (1.0 - a_last) * seg_du
        sums_p[..., pp[i] - first] += ws[..., i] * head
        sums_q[..., pp[i] - first] += (wc[..., i] + y_first[:, None, :]) * head
        sums_p[..., pp[i + 1] - first] += ws[..., i + 1] * tail
        sums_q[..., pp[i + 1] - first] += (y_last[:, None, :] + wc[..., i + 1]) * tail

        many = np.flatnonzero(n_cross[i] > 1)  # segments longer than a period (sampling slower than f)
        if many.size:
            counts = n_cross[i[many]] - 1
            seg = np.repeat(many, counts)
            offsets = np.repeat(np.cumsum(counts) - counts, counts)
            lo = pp[i[seg]] + 1 + (np.arange(seg.size) - offsets)  # each whole period opens at edge lo
            a_lo, y_lo = at_edge(lo.astype(np.float64), seg)
            a_hi, y_hi = at_edge(lo + 1.0, seg)
            sums_q[..., lo - first] += (y_lo + y_hi)[:, None, :] * ((a_hi - a_lo) * seg_du[seg])
        return np.moveaxis(sums_p, -1, 0), np.moveaxis(sums_q, -1, 0), first


class GridPeriodIntegrator(PeriodIntegrator):
    """:class:`PeriodIntegrator` for samples on a uniform grid of ``steps_per_period`` steps per period that t0 lies
    on (the steps of a simulation at h = 1/(N f)): each chunk's whole periods are one matrix product.

    Samples must be the grid's, consecutive and in order (a sample off the grid or a skipped one is a ValueError
    naming it); the first one fed at or before t0. A grid has no gaps: every period is whole.
    """

    #: Largest distance of a sample time from its grid point, in steps, still taken for that grid point.
    GRID_TOLERANCE_STEPS = 1e-6

    def __init__(self, frequency_hz: float, harmonics: Sequence[int], n_channels: int, steps_per_period: int,
                 t0: float = 0.0) -> None:
        super().__init__(frequency_hz, harmonics, n_channels, t0)
        if isinstance(steps_per_period, bool) or not isinstance(steps_per_period, numbers.Integral) \
                or steps_per_period < 2:
            raise ValueError(f"steps_per_period must be an integer >= 2, got {steps_per_period!r}")
        self.steps_per_period: int = int(steps_per_period)
        n = self.steps_per_period
        phase = _TWO_PI * np.outer(np.arange(n + 1), self._k) / n  # (N + 1, harmonic)
        edge_weight = np.ones((n + 1, 1))
        edge_weight[[0, -1]] = 0.5
        # (N + 1, 2 harmonics): sine weights then cosine weights; sin is 0 on both edges
        self._weights: np.ndarray = (2.0 / n) * edge_weight * np.concatenate((np.sin(phase), np.cos(phase)), axis=1)
        self._weights[[0, -1], : len(self.harmonics)] = 0.0
        # what a constant 1 gives, exactly: 0, but for the cosine of a harmonic the grid aliases to DC (k a multiple
        # of N), whose every weight is 2/N w_j
        self._constant: np.ndarray = np.concatenate((np.zeros(len(self.harmonics)),
                                                     np.where(np.asarray(self.harmonics) % n == 0, 2.0, 0.0)))
        self._next_step: int | None = None  # grid index (steps since t0) the next sample must have
        self._open: np.ndarray = np.empty((0, self.n_channels))  # samples of the period in progress, its edge first

    def _grid_steps(self, t: np.ndarray) -> int:
        """The grid index of t[0], after checking that t holds consecutive grid points."""
        n = self.steps_per_period
        steps = (t - self.t0) * (self.frequency_hz * n)
        first = round(float(steps[0]))
        off = np.abs(steps - (first + np.arange(t.shape[0])))
        if off.size and not float(off.max()) <= self.GRID_TOLERANCE_STEPS:
            i = int(np.argmax(~(off <= self.GRID_TOLERANCE_STEPS)))
            raise ValueError(
                f"t[{i}] = {t[i]!r} s is not the grid point after t[{i - 1}] on the grid of {n} steps per period "
                f"from t0 = {self.t0!r} s" if i else
                f"t[0] = {t[0]!r} s is not on the grid of {n} steps per period from t0 = {self.t0!r} s")
        if self._next_step is not None and first != self._next_step:
            raise ValueError(f"t[0] = {t[0]!r} s is grid step {first}, but step {self._next_step} comes next on the "
                             f"grid of {n} steps per period from t0 = {self.t0!r} s")
        return first

    def feed_marked(self, t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t_arr, y_arr = self._check(t, y)
        if t_arr.shape[0] == 0:
            return self._empty_marked()
        first = self._grid_steps(t_arr)
        self._has_last, self._t_last = True, t_arr[-1:].copy()
        self._next_step = first + t_arr.shape[0]
        if first < 0:  # samples before t0 are not integrated
            y_arr = y_arr[-first:]
        samples = np.concatenate((self._open, y_arr)) if self._open.shape[0] else y_arr
        n = self.steps_per_period
        m = (samples.shape[0] - 1) // n if samples.shape[0] else 0
        self._open = samples[m * n:]
        if m == 0:
            return self._empty_marked()
        n_c, n_h = self.n_channels, len(self.harmonics)
        # period i's samples j = 0 .. N: rows i N .. i N + N (the edge rows shared by neighbours). Each period's
        # first sample is taken off all of them and its exact share added back: a large offset (a position far from
        # zero) then costs no precision in the sums.
        inner = samples[: m * n].reshape(m, n, n_c)
        offset = inner[:, :1, :]
        out = np.einsum("mjc,jw->mcw", inner - offset, self._weights[:n], optimize=True)
        out[:, :, n_h:] += (samples[n: m * n + 1: n] - offset[:, 0])[:, :, None] * self._weights[n, n_h:]
        out += offset[:, 0, :, None] * self._constant
        self.periods_done += m
        return (np.ascontiguousarray(out[:, :, :n_h]), np.ascontiguousarray(out[:, :, n_h:]),
                np.ones(m, dtype=bool))


class ExactPeriodIntegrator:
    """Per-period Fourier coefficients that are exact, to round-off, for a signal made of a constant, a linear drift
    and harmonics 1 .. K of f (K the highest harmonic asked for), on any sample times: a rate whose period is not a
    whole number of samples, jittered times, a period edge anywhere between two samples.

    **Any grid.** The trapezoidal rule of :class:`PeriodIntegrator` is a linear functional of the samples. Applied to
    a sampled sinusoid on a grid that does not fit the period, it misses by about (samples per period)^-3 and leaks
    one harmonic into another, the same way in every period, so no averaging removes it. Here each period's
    trapezoidal moments of the signal against the 2K + 1 test functions (1, sin and cos of harmonics 1 .. K) are
    taken together with the same moments of the 2K + 1 basis functions themselves, sampled at the very same times.
    The second set is the matrix A that maps true coefficients to what the trapezoid returns on this period's samples,
    so solving ``A c = b`` gives back the coefficients c exactly for any signal the basis spans. Content above
    harmonic K is treated as the trapezoidal rule treats it (it leaks by the rule's own small amount). Where the
    samples of a period fit its grid (a whole number of steps, edges on samples) A is the identity and the result is
    the trapezoid's.

    **Drift.** A linear drift ``a t`` of the output (thermal drift, a creeping cylinder) adds ``-a / (pi k f)`` to
    P_k in every period: a bias no spread between periods reveals. Each period's constant term (its mean) is solved
    with the harmonics, and the drift's own coefficients on this period's samples with it (a ramp sampled at the same
    times, through the same solve); the slope between the means of this whole period and the previous one (the next
    one, for the first) times those coefficients is taken off. Over a point the corrections telescope: the noise they
    add to an average of n periods falls as 1/n, not 1/sqrt(n). ``drift`` holds each period's slope per channel.

    **Edges on samples.** Period 1 starts at the first sample at or after t0 (t0' = t0 + d, d less than one sample
    interval), and each period's coefficients are turned back by ``exp(-j 2 pi k f d)`` to t0's phase. For a steady
    signal that is the same result; on a uniform grid with a whole number of samples a period every edge then falls
    on a sample, where the trapezoid needs no interpolated sample and a harmonic above K leaks into none of 1 .. K
    (only true aliasing remains), whatever t0 is.

    Same interface and conventions as :class:`PeriodIntegrator` (P multiplies sin, Q cos, period i spans
    [t0' + (i - 1)/f, t0' + i/f]); a period whose samples cannot resolve the basis (fewer samples than unknowns, a
    condition number of A above ``MAX_CONDITION``) is reported not whole, as a gap would be. The first whole period is
    returned with the second (its drift needs a neighbour).

    **Content above K.** ``fit_order`` K' > K widens the basis to harmonics 1 .. K': content of a nonlinear response
    up to K' then leaks into none of 1 .. K on any grid, and the coefficients of harmonics K + 1 .. K' of each period
    (drift taken off and turned to t0's phase like the others) are kept in ``high``: the record's own view of what
    lies above the measured harmonics, from which what the sampling folds onto them can be bounded
    (:func:`bodebench.core.benchgrid.fold_bound`).

    **Disturbance lines.** With ``lines_hz`` (frequencies as the samples see them, Hz), each period's residual, what
    the basis leaves of the signal (drift taken off as above), is projected on ``exp(-j 2 pi d (t - t0'))`` for
    each line d: the same per-sample sums of every column against each line, less the solved coefficients times
    the basis functions' own sums, so whatever the basis spans leaves nothing there on any grid. ``lines`` holds them
    (period, channel, line; channel units times seconds): summed over W periods, ``2 f |sum| / W`` is the amplitude
    of what lies at d and is not a solved harmonic (a mains line, and a harmonic of the output above K' near it).

    Cost: the moments of n_channels + 2K' + 2 columns against K' + 1 harmonics per sample, and one (2K' + 1)-square
    solve per period; with lines, as many complex sums more per sample and line.
    """

    #: Largest condition number of a period's moment matrix A for which its coefficients are taken.
    MAX_CONDITION = 1e8
    #: The same with harmonics above the measured ones in the basis: a period whose samples resolve those less well
    #: (a gap bridged, a stall) is solved for the measured ones alone, as without them.
    WIDE_MAX_CONDITION = 1e3

    def __init__(self, frequency_hz: float, harmonics: Sequence[int], n_channels: int, t0: float = 0.0,
                 max_gap: float = math.inf, fit_order: int = 0, lines_hz: Sequence[float] = ()) -> None:
        front = PeriodIntegrator(frequency_hz, harmonics, n_channels, t0, max_gap)  # checks the arguments
        self.frequency_hz: float = front.frequency_hz
        self.harmonics: tuple[int, ...] = front.harmonics
        self.n_channels: int = front.n_channels
        self.t0: float = front.t0
        self.max_gap: float = front.max_gap
        self.fit_order: int = max(max(self.harmonics), int(fit_order))
        """K': the coefficients are exact for a constant, a drift and harmonics 1 .. K' (at least the highest
        measured one)."""
        self.high_harmonics: tuple[int, ...] = tuple(range(max(self.harmonics) + 1, self.fit_order + 1))
        """The harmonics above the measured ones that the basis holds (K + 1 .. K'), whose coefficients go to
        ``high``."""
        self.unmeasured_harmonics: tuple[int, ...] = tuple(j for j in range(1, self.fit_order + 1)
                                                           if j not in self.harmonics)
        """Every harmonic the basis holds that is not measured (those between the measured ones, then
        ``high_harmonics``), whose coefficients go to ``unmeasured``."""
        self.unmeasured: np.ndarray = np.zeros((0, n_channels, len(self.unmeasured_harmonics)), dtype=complex)
        """(m, n_channels, len(unmeasured_harmonics)) each period's coefficients of the harmonics solved but not
        measured, of the last call's output (channel units; NaN above the measured ones where a period is solved for
        those up to the highest measured alone)."""
        k = self.fit_order
        out = (*self.harmonics, *self.unmeasured_harmonics)
        self._basis_size = 2 * k + 1
        # columns: the channels, the ramp (t - t0') f, then the basis; made once t0' (the first sample at or after
        # t0) is known, the samples before it held meanwhile
        self._moments: _MomentIntegrator | None = None
        self._waiting: list[tuple[np.ndarray, np.ndarray]] = []
        self.start: float = math.nan
        """t0': the first sample time at or after t0 (s), where period 1 starts (NaN until one has come)."""
        self._turn = np.ones(len(out), dtype=complex)  # exp(-j 2 pi k f (t0' - t0))
        self._scale = np.ones(self._basis_size)
        self._scale[0] = 2.0  # the constant's moment against the constant: 2 f * integral of 1 over a period
        self._sin_rows = np.asarray(out)
        self._cos_rows = self._sin_rows + k
        self.drift: np.ndarray = np.zeros((0, self.n_channels))
        """(m, n_channels) the slope (channel units per period) taken off each period of the last call's output."""
        self._previous: tuple[np.ndarray, float] | None = None  # the last whole period's means and ramp mean
        self._held: tuple[np.ndarray, ...] | None = None  # the first whole period, waiting for its neighbour
        self._emitted = 0
        self.lines_hz: tuple[float, ...] = tuple(float(d) for d in lines_hz)
        """The disturbance lines whose residual ``lines`` holds (Hz, as the samples see them)."""
        self.lines: np.ndarray = np.zeros((0, n_channels, len(self.lines_hz)), dtype=complex)
        """(m, n_channels, len(lines_hz)) each period's residual projected on each line, of the last call's output
        (channel units times seconds); NaN for a period solved for the measured harmonics alone."""
        # each open period's sums of every column against each line: period index -> (column, line)
        self._line_open: dict[int, np.ndarray] = {}
        self._line_t_last = math.nan  # the time of the last sample summed

    @property
    def high(self) -> np.ndarray:
        """(m, n_channels, len(high_harmonics)) the columns of ``unmeasured`` above the measured harmonics."""
        return self.unmeasured[:, :, len(self.unmeasured_harmonics) - len(self.high_harmonics):]

    @property
    def periods_done(self) -> int:
        """Number of complete periods emitted so far."""
        return self._emitted

    def feed(self, t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`PeriodIntegrator.feed`, with coefficients exact for a constant, a drift and harmonics 1 .. K."""
        p, q, _ = self.feed_marked(t, y)
        return p, q

    def feed_marked(self, t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`PeriodIntegrator.feed_marked`, with coefficients exact for a constant, a drift and harmonics 1 .. K;
        a period whose samples cannot resolve those is marked not whole."""
        t_arr = np.asarray(t, dtype=np.float64)
        y_arr = np.asarray(y, dtype=np.float64)
        if y_arr.ndim == 1 and self.n_channels == 1:
            y_arr = y_arr.reshape(-1, 1)
        n = t_arr.shape[0] if t_arr.ndim == 1 else -1
        if t_arr.ndim == 1 and y_arr.shape != (n, self.n_channels):
            expected = f"({n}, {self.n_channels})" + (f" or ({n},)" if self.n_channels == 1 else "")
            raise ValueError(f"y must have shape {expected} to match t of length {n}, got shape {y_arr.shape}")
        if self._moments is None:
            t_arr, y_arr = self._until_start(t_arr, y_arr)
        assert self._moments is not None or t_arr.shape[0] == 0
        nc = self.n_channels
        n_out = len(self.harmonics) + len(self.unmeasured_harmonics)
        if self._moments is None:
            self.drift = np.zeros((0, nc))
            self.unmeasured = np.zeros((0, nc, len(self.unmeasured_harmonics)), dtype=complex)
            shape = (0, nc, len(self.harmonics))
            return np.zeros(shape), np.zeros(shape), np.zeros(0, dtype=bool)
        columns = np.concatenate((y_arr, self._ramp_and_basis(t_arr)), axis=1) if t_arr.ndim == 1 else y_arr
        done_before = self._moments.periods_done
        if self.lines_hz and t_arr.ndim == 1:
            self._add_line_sums(t_arr, columns)
        p, q, whole = self._moments.feed_marked(t_arr, columns)
        n_lines = len(self.lines_hz)
        if p.shape[0] == 0:
            self.drift = np.zeros((0, nc))
            empty = np.zeros((0, nc, n_out + n_lines))
            return self._split(*self._release(empty, empty.copy(), whole))
        # moments (period, column, test): the constant's, then sin 1 .. K', then cos 1 .. K'
        moments = np.concatenate((q[..., :1], p[..., 1:], q[..., 1:]), axis=-1)
        wide = bool(self.high_harmonics)
        c, resolved = self._solve(moments, np.arange(self._basis_size),
                                  self.WIDE_MAX_CONDITION if wide else self.MAX_CONDITION)
        narrow = np.flatnonzero(~resolved) if wide else np.zeros(0, dtype=np.int64)
        if narrow.size:  # a period too sparse for the harmonics above the measured ones: the measured ones alone
            k, top = max(self.harmonics), self.fit_order
            rows = np.concatenate(([0], np.arange(1, k + 1), np.arange(top + 1, top + k + 1)))
            solved, resolved[narrow] = self._solve(moments[narrow], rows, self.MAX_CONDITION)
            c[narrow] = np.nan  # no coefficients above the measured ones
            c[narrow[:, None], rows] = solved
        whole = whole & resolved
        out_p = np.swapaxes(c[:, self._sin_rows, :], 1, 2)  # (period, channels and the ramp, harmonic)
        out_q = np.swapaxes(c[:, self._cos_rows, :], 1, 2)
        if n_lines:  # the residuals ride along as further outputs: the drift comes off them as off the harmonics
            sums = self._take_line_sums(done_before, p.shape[0])  # (period, column, line)
            basis = sums[:, nc + 1:, :]
            with np.errstate(invalid="ignore"):
                residual = sums[:, : nc + 1, :] - np.einsum("mbc,mbl->mcl", np.nan_to_num(c), basis)
            residual[narrow] = np.nan
            out_p = np.concatenate((out_p, residual.real), axis=2)
            out_q = np.concatenate((out_q, residual.imag), axis=2)
        return self._split(*self._release(out_p, out_q, whole, c[:, 0, :]))

    def _add_line_sums(self, t: np.ndarray, columns: np.ndarray) -> None:
        """Add each sample at or after t0' (weighted by the time since the sample before it) times each line's
        ``exp(-j 2 pi d (t - t0'))`` to its period's sums (period index floor((t - t0') f))."""
        previous = np.concatenate(([self._line_t_last], t[:-1]))
        self._line_t_last = float(t[-1])
        weight = np.nan_to_num(t - previous)  # the first sample ever weighs nothing
        u = (t - self.start) * self.frequency_hz
        keep = u >= 0.0
        if not keep.any():
            return
        t, u, weight, columns = t[keep], u[keep], weight[keep], columns[keep]
        period = np.floor(u).astype(np.int64)
        turn = np.exp(-2j * math.pi * np.outer(t - self.start, self.lines_hz)) * weight[:, None]  # (sample, line)
        starts = np.concatenate(([0], np.flatnonzero(np.diff(period)) + 1))
        for a, b in zip(starts, (*starts[1:], period.size), strict=True):
            block = columns[a:b].T @ turn[a:b]  # (column, line)
            index = int(period[a])
            if index in self._line_open:
                self._line_open[index] += block
            else:
                self._line_open[index] = block

    def _take_line_sums(self, first: int, count: int) -> np.ndarray:
        """(count, column, line) the sums of periods ``first`` .. ``first + count - 1`` (0-based), taken out (zeros
        for a period no sample fell in)."""
        width = self.n_channels + 1 + self._basis_size
        out = np.zeros((count, width, len(self.lines_hz)), dtype=complex)
        for i in range(count):
            block = self._line_open.pop(first + i, None)
            if block is not None:
                out[i] = block
        for index in [i for i in self._line_open if i < first]:  # periods before period 1
            del self._line_open[index]
        return out

    def _solve(self, moments: np.ndarray, rows: np.ndarray, max_condition: float) -> tuple[np.ndarray, np.ndarray]:
        """Each period's ``A c = b`` on the basis functions and test functions ``rows`` (indices into 1, sin 1 ..
        K', cos 1 .. K'), from its moments (period, column, test): c (period, len(rows), channels and the ramp),
        and which periods resolve them (A finite, its condition number at most ``max_condition``)."""
        nc = self.n_channels
        a = np.swapaxes(moments[:, nc + 1:, :], 1, 2)[:, rows][:, :, rows]  # (period, test, basis)
        b = np.swapaxes(moments[:, : nc + 1, :], 1, 2)[:, rows]  # (period, test, channels and the ramp)
        with np.errstate(all="ignore"):
            resolved = np.isfinite(a).all(axis=(1, 2))
            resolved[resolved] = np.linalg.cond(a[resolved]) <= max_condition
        a[~resolved] = np.diag(self._scale[rows])  # unresolved periods are discarded: anything invertible will do
        return np.linalg.solve(a, b), resolved

    def _split(self, p: np.ndarray, q: np.ndarray, whole: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The measured harmonics' coefficients returned, the others solved kept in ``unmeasured`` (those above the
        measured ones in ``high``), the lines' residuals in ``lines``."""
        n = len(self.harmonics)
        top = n + len(self.unmeasured_harmonics)
        self.unmeasured = p[:, :, n:top] + 1j * q[:, :, n:top]
        self.lines = p[:, :, top:] + 1j * q[:, :, top:]
        return np.ascontiguousarray(p[:, :, :n]), np.ascontiguousarray(q[:, :, :n]), whole

    def _release(self, p: np.ndarray, q: np.ndarray, whole: np.ndarray, means: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Take each period's drift off (p, q: (m, channels + the ramp, harmonic); means: (m, channels + the ramp))
        and return the periods ready: all but a first whole period still waiting for its neighbour."""
        nc = self.n_channels
        if self._held is not None and means is not None:  # the held first period goes out with the rest
            hp, hq, hw, hm = self._held
            p, q, whole, means = (np.concatenate((hp, p)), np.concatenate((hq, q)), np.concatenate((hw, whole)),
                                  np.concatenate((hm, means)))
            self._held = None
        m = p.shape[0]
        if m == 0 or means is None:
            return p[:, :nc], q[:, :nc], whole
        slope = np.zeros((m, nc))
        previous = self._previous
        waiting = -1  # index of the first whole period when no earlier one exists
        for i in range(m):
            if not whole[i]:
                continue
            if previous is not None:
                slope[i] = (means[i, :nc] - previous[0]) / (means[i, nc] - previous[1])
            elif waiting < 0:
                waiting = i
            else:  # the first whole period's slope: the one to its neighbour
                slope[waiting] = slope[i] = (means[i, :nc] - means[waiting, :nc]) / (means[i, nc] - means[waiting, nc])
            if waiting < 0 or i > waiting:
                previous = (means[i, :nc], float(means[i, nc]))
            if waiting >= 0 and i > waiting:
                waiting = -1
        if previous is None and waiting >= 0:  # a first whole period and no neighbour yet: hold it and what follows
            self._held = (p[waiting:], q[waiting:], whole[waiting:], means[waiting:])
            p, q, whole, slope = p[:waiting], q[:waiting], whole[:waiting], slope[:waiting]
        self._previous = previous
        z = (p[:, :nc] - slope[:, :, None] * p[:, nc:nc + 1] + 1j * (q[:, :nc] - slope[:, :, None] * q[:, nc:nc + 1]))
        if self.start != self.t0:
            z[:, :, : self._turn.size] *= self._turn
        self.drift = slope
        self._emitted += z.shape[0]
        return np.ascontiguousarray(z.real), np.ascontiguousarray(z.imag), whole

    def _until_start(self, t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Before period 1 has a start: hold the samples until one at or after t0 comes, then make the moment
        integrator from it and return every sample held, this chunk's included, to be fed to it."""
        if t.ndim != 1:
            raise ValueError(f"t must be a 1-D array of seconds, got shape {t.shape}")
        if t.shape[0] == 0:
            return t, y
        if not self._waiting and not t[0] <= self.t0:
            raise ValueError(f"the first sample t[0] = {t[0]!r} s is after t0 = {self.t0!r} s, so period 1 would be "
                             "incomplete; the stream must start at or before t0")
        self._waiting.append((t, y))
        at = np.flatnonzero(t >= self.t0)
        if not at.size:
            return t[:0], y[:0]
        self.start = float(t[at[0]])
        k = self.fit_order
        self._moments = _MomentIntegrator(self.frequency_hz, tuple(range(k + 1)),
                                          self.n_channels + 1 + self._basis_size, self.start, self.max_gap)
        self._turn = np.exp(-2j * math.pi * self.frequency_hz * (self.start - self.t0) * self._sin_rows)
        held = self._waiting
        self._waiting = []
        if len(held) == 1:
            return held[0]
        return np.concatenate([h[0] for h in held]), np.concatenate([h[1] for h in held])

    def _ramp_and_basis(self, t: np.ndarray) -> np.ndarray:
        """(n, 2K + 2) at times t: the ramp (t - t0') f, then the basis: 1, sin(2 pi j f (t - t0')) for j = 1 .. K,
        then the cosines."""
        u = (t - self.start) * self.frequency_hz
        phase = np.outer(_TWO_PI * (u - np.floor(u)), np.arange(1, self.fit_order + 1))
        return np.concatenate((u[:, None], np.ones((t.shape[0], 1)), np.sin(phase), np.cos(phase)), axis=1)


LINE_GAIN_PERIODS = 32
"""Periods :func:`line_gains` feeds at most (as many sample phases against the period as a bench's grid goes through
in that many periods), and no more than :data:`LINE_GAIN_SAMPLES` samples' worth."""
LINE_GAIN_SAMPLES = 8000
"""Samples :func:`line_gains` feeds at most (at least three periods)."""
LINE_GAIN_MAX_SAMPLES_PER_PERIOD = 1000.0
"""Above this many samples a period :func:`line_gains` gives 0: the solve lets through no more than the
continuous-time leak to within 4e-7 of a line up to harmonic 16 (measured at 1000.7 samples, 3.4e-6 at 400.7)."""


def line_gains(frequency_hz: float, harmonics: Sequence[int], fit_order: int, samples_per_period: float,
               lines_hz: Sequence[float]) -> np.ndarray:
    """(harmonic, line) the most a line of unit amplitude at each of ``lines_hz`` (Hz) puts into one period's
    coefficient of each of ``harmonics`` (output units per unit of line) in :class:`ExactPeriodIntegrator` solving
    harmonics 1 .. ``fit_order`` on a uniform grid of ``samples_per_period`` samples a period: what the per-period
    solve on sampled data lets through of a frequency outside its basis, which no continuous-time formula gives (it
    stays about N^-3 of the line, N the samples a period, however close the line lies to a whole harmonic). Found by
    construction: the line fed as a cosine and as a sine (two columns) for up to :data:`LINE_GAIN_PERIODS` periods
    off the grid's phase; each period's two answers are the columns of a 2 x 2 real matrix whose largest singular
    value is the worst over the line's phase; the largest over the periods (the grid's sample phase against the
    period moves from one to the next where it is not whole)."""
    count = len(lines_hz)
    if not count or not 0 < samples_per_period <= LINE_GAIN_MAX_SAMPLES_PER_PERIOD:
        return np.zeros((len(harmonics), count))
    rate = samples_per_period * frequency_hz
    periods = max(3, min(LINE_GAIN_PERIODS, int(LINE_GAIN_SAMPLES / samples_per_period)))
    t = (np.arange(int((periods + 3) * samples_per_period)) - 0.63) / rate  # from just before t0 = 0
    phase = 2.0 * math.pi * np.outer(t, lines_hz)  # (sample, line)
    columns = np.empty((t.size, 2 * count))
    columns[:, 0::2], columns[:, 1::2] = np.cos(phase), np.sin(phase)
    integrator = ExactPeriodIntegrator(frequency_hz, harmonics, 2 * count, 0.0, fit_order=fit_order)
    p, q = integrator.feed(t, columns)  # (period, column, harmonic)
    if not p.shape[0]:
        return np.full((len(harmonics), count), math.inf)
    a, c, b, d = p[:, 0::2], q[:, 0::2], p[:, 1::2], q[:, 1::2]  # [[a, b], [c, d]]: (period, line, harmonic)
    square = a * a + b * b + c * c + d * d
    largest = np.sqrt(0.5 * (square + np.sqrt(np.maximum(square * square - 4.0 * (a * d - b * c) ** 2, 0.0))))
    return np.swapaxes(np.max(largest, axis=0), 0, 1)


class _MomentIntegrator(PeriodIntegrator):
    """:class:`PeriodIntegrator` that also takes harmonic 0 (the constant: P = 0, Q = 2 f * the integral)."""

    _LEAST_HARMONIC = 0
