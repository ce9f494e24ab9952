"""Modal extrapolation: the limit of a sequence ``Z(i) = Z_inf + sum_r a_r lambda_r**i`` from a linear-prediction
fit (:func:`extrapolate_modes`), its forecast of the periods that follow, and the error bound by which two
windows' fits confirm a limit (:func:`_confirmed_bound`: the second estimator of
:class:`~bodebench.core.rules.adaptive.AdaptiveRule`).

Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from bodebench.core.rules.intervals import _ROUND_OFF
from bodebench.core.rules.least_squares import _DESIGNS, _design, _least_squares

_MIN_TURN = 0.5  # |1 - lambda| of a slowly decaying mode that the fit may extrapolate through
_MAX_DECAY = 0.5  # the most a fitted mode may keep of itself over its window
_FIT_WINDOW_SHARE = 4  # each of the modal fit's two windows holds 1/this of the analysed periods (min_window at least)

_RESIDUALS_IN_BOUND = 2.0  # a confirmed limit's error bound holds the larger window residual this many times


class ModalFit(NamedTuple):
    """A modal fit of a window: its limit and rms residual (both output units); ``alpha`` the recurrence's
    coefficients (none for a window settled to round-off) and ``tail`` the window's last values (oldest first),
    from which it forecasts what follows. A named tuple: made at every fit, it costs half a frozen dataclass."""

    limit: complex
    residual: float
    alpha: tuple[float, ...] = ()
    tail: tuple[complex, ...] = ()

    def forecast(self, steps: int) -> np.ndarray:
        """The ``steps`` values the recurrence forecasts after the window (output units)."""
        return _forecast(self.tail, self.alpha, self.limit, steps)

    def forecast_error(self, following: np.ndarray) -> float:
        """The largest |forecast - value| over the values that followed the window (output units; NaN where a
        forecast is not a number; 0 where none followed): ``max(abs(forecast - following))`` without making the
        forecast an array."""
        values = following.tolist()
        limit = self.limit
        if len(self.alpha) == 2:  # the two-mode fit's recurrence (as _recurrence runs it), unrolled in locals
            c0, c1 = self.alpha
            p1, p0 = self.tail[0] - limit, self.tail[1] - limit
            s0, s1 = c0 * p0 + c1 * p1, c1 * p0
            worst = total = 0.0
            for v in values:
                y = s0
                s0, s1 = s1 + y * c0, y * c1
                error = abs(limit + y - v)
                total += error
                if error > worst:
                    worst = error
            return worst if total == total else math.nan  # a NaN anywhere makes the sum NaN
        forecast = _recurrence(self.tail, self.alpha, limit, len(values)) if self.alpha else [limit] * len(values)
        errors = [abs(f - v) for f, v in zip(forecast, values, strict=True)]
        total = sum(errors)
        return max(errors, default=0.0) if total == total else math.nan


def extrapolate_modes(z: np.ndarray, modes: int, max_decay: float = _MAX_DECAY) -> ModalFit | None:
    """Limit of a sequence ``Z(i) = Z_inf + sum_r a_r lambda_r**i`` from a least-squares linear-prediction fit.

    The real recurrence ``Z(i) = c + sum_r alpha_r Z(i-r)`` is fitted to P and Q
    jointly; ``Z_inf = c / (1 - sum alpha)``. The fit is only trusted where the
    data show the transient dying: every mode must shrink to at most
    ``max_decay`` of itself over the fitted stretch (a mode on or outside the
    unit circle, a beat of a conservative link or a growing response, has no
    limit). None when the sequence is too short, holds a value that is not
    finite, or no limit is shown.
    """
    return _modal_fit(z, modes, max_decay)[0]


def _modal_fit(z: np.ndarray, modes: int, max_decay: float, finite: bool = False) -> tuple[ModalFit | None, float]:
    """:func:`extrapolate_modes`, and the window (periods) over which the slowest mode it refused for not having
    decayed would decay to ``max_decay`` at its fitted rate (inf for a mode on or outside the unit circle; 0 where
    no mode was refused). finite: the caller knows every value of z to be finite (else it is checked here)."""
    n = z.size
    if n - modes < modes + 3:
        return None, 0.0
    z = np.ascontiguousarray(z, dtype=complex)
    values = np.empty(2 * n + 2)  # (P(1), Q(1), ..., P(n), Q(n), 1, 0): the intercepts' entries last
    values[:-2] = z.view(np.float64)
    values[-2] = 1.0
    values[-1] = 0.0
    if not (finite or np.isfinite(values).all()):  # LAPACK, handed one, may print a complaint or return zeros
        return None, 0.0
    if _may_be_settled(z):
        mean = complex(z.sum() / n)
        if float(np.abs(z - mean).max()) <= _ROUND_OFF * abs(mean):  # settled to round-off: no mode to fit
            return ModalFit(mean, 0.0), 0.0
    design = _DESIGNS.get((n, modes)) or _design(n, modes)
    columns = modes + 2
    # the design matrix's columns (Z lagged by 1..modes, the two intercepts) and Z itself over the rows (P then Q
    # of Z(modes+1..n)), gathered at once; the transpose is a column-major view, the layout LAPACK works in
    xy = values[design.gather]
    sol = _least_squares(xy, design)
    found = sol[:columns].tolist()
    alpha = found[:modes]
    # a mode must have decayed over the window, unless it is damped and turns far enough from 1 that the
    # limit does not hang on its decay rate (a rotating mode's mean is its limit); size ** n is taken only
    # below 1, where it cannot overflow
    needed = 0.0
    for lam in _mode_roots(alpha):
        size = abs(lam)
        if size >= 1.0:
            if max_decay < 1.0 or n * math.log(size) > math.log(max_decay):
                return None, math.inf
        elif size ** n > max_decay and abs(1.0 - lam) < _MIN_TURN:
            needed = max(needed, math.log(max_decay) / math.log(size))
    if needed:
        return None, needed
    den = 1.0 - (sum(alpha) if modes < 8 else float(sol[:modes].sum()))  # numpy's sum is Python's below 8 terms
    # the residual of the solution returned (LAPACK's own sum of squares is that of the exact least-squares
    # solution, which a badly scaled design can put orders of magnitude lower): with -1 after the solution, the
    # product with the gathered columns and values is (design @ solution - values), row by row
    sol[columns] = -1.0
    resid = sol[:columns + 1].dot(xy)  # the method: numpy's function adds a dispatch to the same product
    limit = complex(found[modes], found[modes + 1]) / den
    residual = math.sqrt(float(resid.dot(resid)) / resid.size) / abs(den)
    return ModalFit(limit, residual, tuple(alpha), tuple(z[n - modes:].tolist())), 0.0


def _may_be_settled(z: np.ndarray) -> bool:
    """False where the window's first and last values differ by more than a window settled to round-off
    (every value within _ROUND_OFF |mean| of its mean) allows: 2 _ROUND_OFF |mean| <= 2 _ROUND_OFF |Z(1)| (1 + 2
    _ROUND_OFF), with a margin for the round-off of the comparison. True also where the first or last value is
    not a number, and where |Z(1)| is so small that the bound itself rounds (below 1e-280)."""
    first, last = z.item(0), z.item(-1)  # Python complex numbers
    size = abs(first)
    return not (abs(first - last) > 2.0 * _ROUND_OFF * (1.0 + 1e-6) * size and size > 1e-280)


def _mode_roots(alpha: Sequence[float]) -> list[complex]:
    """The modes lambda_r of the recurrence: roots of z^m - alpha_1 z^(m-1) - ... - alpha_m (closed form to m = 2)."""
    if len(alpha) == 1:
        return [complex(alpha[0])]
    if len(alpha) == 2:
        a1, a2 = float(alpha[0]), float(alpha[1])
        disc = a1 * a1 + 4.0 * a2
        if disc < 0.0:
            half = 0.5 * math.sqrt(-disc)
            return [complex(0.5 * a1, half), complex(0.5 * a1, -half)]
        q = 0.5 * (a1 + math.copysign(math.sqrt(disc), a1))  # the larger root; the other from the product -a2
        return [complex(q), complex(-a2 / q)] if q != 0.0 else [0j, 0j]
    return [complex(v) for v in np.roots(np.concatenate([[1.0], -np.asarray(alpha, dtype=float)]))]


def _forecast(last: Sequence[complex], alpha: Sequence[float], limit: complex, steps: int) -> np.ndarray:
    """The next ``steps`` values of the recurrence Z(i) - Z_inf = sum_r alpha_r (Z(i-r) - Z_inf) from its last ones
    (``last``, oldest first), as an array."""
    if steps == 0 or len(alpha) == 0:
        return np.full(steps, limit, dtype=complex)
    return np.array(_recurrence(last, alpha, limit, steps), dtype=complex)


def _recurrence(last: Sequence[complex], alpha: Sequence[float], limit: complex, steps: int) -> list[complex]:
    """The next ``steps`` values of the recurrence from its last ones (oldest first), as a list.

    Run as a direct-form-II-transposed filter on Python scalars: state[m] = sum over r > m of alpha_r times the
    deviation r - m periods back, the next deviation is state[0] (the same arithmetic as scipy.signal.lfilter,
    without the import of scipy.signal in every process that fits a mode).
    """
    coef = [float(v) for v in alpha]
    order = len(coef)
    past = [complex(v) - limit for v in last[::-1]]  # the most recent deviation first
    state = [sum(coef[m + k] * past[k] for k in range(order - m)) for m in range(order)]
    out = []
    for _ in range(steps):
        y = state[0]
        for m in range(order - 1):
            state[m] = state[m + 1] + y * coef[m]
        state[order - 1] = y * coef[order - 1]
        out.append(limit + y)
    return out


def _confirmed_bound(first: ModalFit, second: ModalFit, prediction_error: float) -> float:
    """The error bound of the limit that the fits of two consecutive windows confirm (output units): the gap
    between their limits plus twice the larger residual, and at least the error of the older window's fit in
    forecasting the newer window (``prediction_error``; a NaN there leaves the rest)."""
    bound = abs(first.limit - second.limit) + _RESIDUALS_IN_BOUND * max(first.residual, second.residual)
    return max(bound, prediction_error)
