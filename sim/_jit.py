"""numba's ``njit`` where numba is installed; without it the step loops run as the plain Python they are written in.

The results agree to round-off; plain Python is about 170 times slower per step (``benchmarks/bench_speed.py``),
which a bench sweep does not notice (its simulated drive takes one step per setpoint) but an offline experiment
does. ``pip install 'bodebench[sim]'`` installs numba.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["HAVE_NUMBA", "njit"]

F = TypeVar("F", bound=Callable[..., Any])

_numba_njit: Any
try:
    from numba import njit as _numba_njit
except ImportError:
    _numba_njit = None

HAVE_NUMBA = _numba_njit is not None
"""Whether the step loops are compiled."""


def njit(*args: Any, **kwargs: Any) -> Any:
    """``numba.njit`` (same arguments), or, without numba, a decorator that returns the function unchanged."""
    if _numba_njit is not None:
        return _numba_njit(*args, **kwargs)
    if len(args) == 1 and callable(args[0]) and not kwargs:
        return args[0]

    def keep(function: F) -> F:
        return function

    return keep
