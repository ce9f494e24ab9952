"""The small-matrix exponential the plants use, against scipy's general routine and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from bodebench.sim._kernels import expm_small


@pytest.mark.parametrize("n", [1, 2, 4, 7])
@pytest.mark.parametrize("scale", [1e-4, 0.3, 3.0, 30.0])
def test_matches_scipy(n: int, scale: float) -> None:
    m = np.random.default_rng(n).normal(size=(n, n)) * scale / n
    exact = expm(m)
    assert np.allclose(expm_small(m), exact, rtol=1e-12, atol=1e-12 * np.max(np.abs(exact)))


def test_rotation_and_decay_closed_forms() -> None:
    w, t, a = 7.0, 0.37, -2.5
    rot = expm_small(np.array([[0.0, w], [-w, 0.0]]) * t)
    assert np.allclose(rot, [[math.cos(w * t), math.sin(w * t)], [-math.sin(w * t), math.cos(w * t)]], atol=1e-15)
    assert expm_small(np.array([[a]]))[0, 0] == pytest.approx(math.exp(a), rel=1e-15)
    assert np.array_equal(expm_small(np.zeros((3, 3))), np.eye(3))
