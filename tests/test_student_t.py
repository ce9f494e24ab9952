"""Student's t quantile in plain Python, against scipy's independent implementation and the closed forms."""

from __future__ import annotations

import math
import subprocess
import sys
from statistics import NormalDist

import numpy as np
import pytest
from scipy.special import stdtr, stdtrit

from bodebench.core.student_t import t_cdf, t_quantile

PROBABILITIES = (0.6, 0.75, 0.9, 0.95, 0.975, 0.99, 0.995, 0.999, 0.9999)


@pytest.mark.parametrize("dofs", [range(1, 200), range(200, 3000, 7), (5000, 10_000, 30_000, 10**5, 10**6, 10**8)],
                         ids=["1-199", "200-2999", "large"])
def test_the_quantile_agrees_with_scipy(dofs: range | tuple[int, ...]) -> None:
    worst = 0.0
    for dof in dofs:
        for p in PROBABILITIES:
            ours, theirs = t_quantile(p, dof), float(stdtrit(dof, p))
            assert t_quantile(1.0 - p, dof) == -ours  # symmetric
            worst = max(worst, abs(ours - theirs) / theirs)
    assert worst <= 1e-11


@pytest.mark.parametrize("p", [0.6, 0.9, 0.975, 0.999, 1 - 1e-6])
def test_closed_forms(p: float) -> None:
    tail = 1.0 - p
    assert t_quantile(p, 1) == pytest.approx(math.tan(math.pi * (p - 0.5)), rel=1e-9)  # Cauchy
    assert t_quantile(p, 2) == pytest.approx((2 * p - 1) / math.sqrt(2 * p * tail), rel=1e-12)
    # four degrees of freedom: F(t) = 1/2 + (3/4) s (1 - s^2/3), s = t / sqrt(t^2 + 4), a cubic in s
    s = next(r.real for r in np.roots([-0.25, 0.0, 0.75, 0.5 - p]) if abs(r.imag) < 1e-12 and 0 < r.real < 1)
    assert t_quantile(p, 4) == pytest.approx(2 * s / math.sqrt(1 - s * s), rel=1e-10)
    # the normal limit
    assert t_quantile(p, 1e12) == pytest.approx(NormalDist().inv_cdf(p), rel=1e-11)


@pytest.mark.parametrize("dof", [1, 2, 3, 6, 42, 500, 999])
def test_the_cdf_inverts_the_quantile_and_agrees_with_scipy(dof: int) -> None:
    for p in PROBABILITIES:
        assert t_cdf(t_quantile(p, dof), dof) == pytest.approx(p, rel=1e-13)
    for t in (-40.0, -3.0, -1.0, -0.1, 0.0, 0.3, 1.96, 5.0, 40.0):
        expected = float(stdtr(dof, t))
        assert t_cdf(t, dof) == pytest.approx(expected, rel=1e-10)


def test_bad_arguments_are_refused() -> None:
    for p in (0.0, 1.0, -0.1, math.nan):
        with pytest.raises(ValueError, match="probability"):
            t_quantile(p, 5)
    for dof in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="degrees of freedom"):
            t_quantile(0.9, dof)
        with pytest.raises(ValueError, match="degrees of freedom"):
            t_cdf(1.0, dof)


def test_the_measuring_processes_do_not_import_scipy_special() -> None:
    """The stated intervals need the t quantile; a measuring process gets it without scipy.special's import."""
    code = ("import sys; from bodebench.core.rules.intervals import _line_factor; print(_line_factor(42)); "
            "print('scipy.special' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert float(out[0]) == pytest.approx(float(stdtrit(42, 0.975)), rel=1e-12)
    assert out[1] == "False"
