"""The least-squares solve of the modal fit: LAPACK's dgelsy called directly, with each window shape's design
(gather indices, workspace, rank cut-off) made once and kept.

The solver is chosen for its numerics (a pivoted QR keeps the direction the limit hangs on where an SVD cut-off
drops it) and called without numpy's or scipy's wrappers for speed; numpy's lstsq takes over where LAPACK
refuses its arguments. Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import functools
import types
from typing import NamedTuple

import numpy as np

from bodebench.core.rules.history import _EPS


class _Design(NamedTuple):
    """A window shape's least-squares problem: ``gather`` indexes (P(1), Q(1), ..., P(n), Q(n), 1, 0) to make,
    one row each, the design matrix's columns (Z lagged by 1..modes, the P and Q intercepts) and then the fitted
    values Z(t), over the fit's rows (P then Q of Z(modes+1..n)); ``lwork`` is LAPACK's workspace for it (0:
    its query failed) and ``cond`` the condition at which dgelsy cuts the rank."""

    gather: np.ndarray
    lwork: int
    cond: float


_DESIGNS: dict[tuple[int, int], _Design] = {}


def _design(n: int, modes: int) -> _Design:
    """The least-squares problem of a window of n values fitted with ``modes`` modes, made and kept in _DESIGNS
    for the next fit of that shape (the fit looks there first)."""
    t = np.arange(modes, n)  # 0-based index of Z(t) for the rows
    one, zero = 2 * n, 2 * n + 1
    p_rows = [2 * (t - r) for r in range(1, modes + 1)] + [np.full(t.size, one), np.full(t.size, zero), 2 * t]
    q_rows = [2 * (t - r) + 1 for r in range(1, modes + 1)] + [np.full(t.size, zero), np.full(t.size, one),
                                                               2 * t + 1]
    gather = np.concatenate((np.stack(p_rows), np.stack(q_rows)), axis=1)
    m, k = gather.shape[1], modes + 2
    cond = _EPS * max(m, k)
    work, info = _lapack().dgelsy_lwork(m, k, 1, cond)
    if len(_DESIGNS) > 1024:
        _DESIGNS.clear()
    design = _DESIGNS[(n, modes)] = _Design(gather, int(work) if info == 0 else 0, cond)
    return design


def _least_squares(xy: np.ndarray, design: _Design) -> np.ndarray:
    """The least-squares solution of x @ sol = y, x the first ``modes + 2`` rows of xy transposed and y its last
    row, by LAPACK's dgelsy: QR with column pivoting, the rank cut where the triangle's condition estimate passes
    1 / (eps max(m, k)). Returned with the m - k entries LAPACK leaves after it (an array of xy's row length; the
    caller may write there); xy is left as it was.

    The design's columns differ in scale by orders of magnitude (the lagged values against the unit intercepts,
    the transient against the limit); an SVD cut-off relative to the largest singular value there drops a
    direction the limit hangs on and leaves errors of 1e-7 of it, where the pivoted QR keeps it and solves to
    round-off. Called directly: numpy's and scipy's wrappers cost several times the solve of a small system.
    Where LAPACK reports a failure numpy's lstsq is called instead, so that it fails the way numpy does.
    """
    k = xy.shape[0] - 1
    x, y = xy[:k].T, xy[k]
    if design.lwork:
        # the pivot order is read and written: a fresh one (all free columns) each call; LAPACK works on copies
        out = _lapack().dgelsy(x, y, np.zeros(k, dtype=np.intc), design.cond, design.lwork)
        if out[4] == 0:  # else an argument refused, before any work
            return out[1]
    sol = np.zeros(y.size)
    sol[:k] = np.linalg.lstsq(x, y, rcond=None)[0]
    return sol


@functools.cache
def _lapack() -> types.ModuleType:
    """scipy's LAPACK wrappers, imported on first use (the import is slow)."""
    from scipy.linalg import lapack

    return lapack

