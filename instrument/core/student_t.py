"""Student's t distribution: its quantile, in plain Python (no scipy import in the processes that measure).

The cumulative distribution comes from the regularized incomplete beta function, evaluated by its continued
fraction (modified Lentz); the quantile by Newton's method on it, started from the Cornish-Fisher expansion about
the normal quantile and kept inside a bracket. From 1000 degrees of freedom on, the expansion (to order dof**-4)
is the quantile: its error is then below the round-off of the fraction's prefactor. ``tests/test_student_t.py``
checks both against scipy's ``stdtrit`` and the cases with a closed form.

Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import math
from statistics import NormalDist

__all__ = ["t_cdf", "t_quantile"]

_TINY = 1e-300
_CF_EPS = 1e-15  # relative change of the fraction at which it has converged
_CF_MAX = 100_000
_NEWTON_EPS = 1e-8  # relative Newton step after which the next one is at round-off (convergence is quadratic)
_EXPANSION_DOF = 1000.0  # degrees of freedom from which the quantile is the Cornish-Fisher expansion alone


def _beta_continued_fraction(a: float, b: float, x: float) -> float:
    """The continued fraction of I_x(a, b) (modified Lentz), converging fast for x < (a + 1) / (a + b + 2)."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c = 1.0
    d = 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    h = d
    for m in range(1, _CF_MAX):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > _TINY else _TINY)
        c = 1.0 + aa / c
        c = c if abs(c) > _TINY else _TINY
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > _TINY else _TINY)
        c = 1.0 + aa / c
        c = c if abs(c) > _TINY else _TINY
        step = d * c
        h *= step
        if abs(step - 1.0) <= _CF_EPS:
            return h
    raise ArithmeticError(f"the incomplete beta fraction did not converge (a = {a:g}, b = {b:g}, x = {x:g})")


def _upper_tail(t: float, dof: float) -> float:
    """P(T > t) for t >= 0: I_x(dof/2, 1/2) / 2 with x = dof / (dof + t^2)."""
    if t == 0.0:
        return 0.5
    a, b = 0.5 * dof, 0.5
    t2 = t * t
    total = dof + t2
    x, y = dof / total, t2 / total  # y = 1 - x, without the cancellation
    log_total = math.log(total)
    log_front = (math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * (math.log(dof) - log_total)
                 + b * (math.log(t2) - log_total))
    if x < (a + 1.0) / (a + b + 2.0):
        return 0.5 * math.exp(log_front) * _beta_continued_fraction(a, b, x) / a
    # the other side of the symmetry I_x(a, b) = 1 - I_y(b, a), where its fraction converges fast
    return 0.5 * (1.0 - math.exp(log_front) * _beta_continued_fraction(b, a, y) / b)


def t_cdf(t: float, dof: float) -> float:
    """P(T <= t) for Student's t with ``dof`` (> 0) degrees of freedom."""
    if not dof > 0.0:
        raise ValueError(f"degrees of freedom must be > 0, got {dof!r}")
    if math.isinf(t):
        return 1.0 if t > 0 else 0.0
    tail = _upper_tail(abs(t), dof)
    return 1.0 - tail if t >= 0.0 else tail


def _density(t: float, dof: float) -> float:
    log_norm = math.lgamma(0.5 * (dof + 1.0)) - math.lgamma(0.5 * dof) - 0.5 * math.log(dof * math.pi)
    return math.exp(log_norm - 0.5 * (dof + 1.0) * math.log1p(t * t / dof))


def _cornish_fisher(z: float, dof: float) -> float:
    """The t quantile from the normal one ``z``, to order dof**-4 (Abramowitz and Stegun 26.7.5)."""
    z2 = z * z
    g1 = (z2 + 1.0) * z / 4.0
    g2 = ((5.0 * z2 + 16.0) * z2 + 3.0) * z / 96.0
    g3 = (((3.0 * z2 + 19.0) * z2 + 17.0) * z2 - 15.0) * z / 384.0
    g4 = ((((79.0 * z2 + 776.0) * z2 + 1482.0) * z2 - 1920.0) * z2 - 945.0) * z / 92160.0
    return z + g1 / dof + g2 / dof ** 2 + g3 / dof ** 3 + g4 / dof ** 4


def t_quantile(p: float, dof: float) -> float:
    """The ``p`` quantile (0 < p < 1) of Student's t with ``dof`` (> 0) degrees of freedom."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"probability must be in (0, 1), got {p!r}")
    if not dof > 0.0:
        raise ValueError(f"degrees of freedom must be > 0, got {dof!r}")
    if p == 0.5:
        return 0.0
    if p < 0.5:
        return -t_quantile(1.0 - p, dof)
    tail = 1.0 - p
    if dof == 1.0:  # Cauchy
        return 1.0 / math.tan(math.pi * tail)
    if dof == 2.0:
        return (2.0 * p - 1.0) / math.sqrt(2.0 * p * tail)
    t = _cornish_fisher(NormalDist().inv_cdf(p), dof)
    if dof >= _EXPANSION_DOF:  # the expansion's error, of order dof**-5, is below the fraction's round-off here
        return t
    if not 0.0 < t < math.inf:  # the expansion fails for very few degrees of freedom: start from one
        t = 1.0
    low, high = 0.0, math.inf  # the quantile lies in [low, high]
    for _ in range(100):
        excess = _upper_tail(t, dof) - tail  # > 0: t is below the quantile
        if excess > 0.0:
            low = t
        elif excess < 0.0:
            high = t
        else:
            return t
        step = excess / _density(t, dof)
        if abs(step) <= _NEWTON_EPS * t:
            return t + step
        t += step
        if not low < t < high:  # Newton left the bracket: halve it instead
            t = 0.5 * (low + high) if math.isfinite(high) else 2.0 * low
    return t
