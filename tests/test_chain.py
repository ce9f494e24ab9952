"""Taking the bench's hold and a declared delay off a response: against scipy's zero-order-hold discretisation of
a known plant (what a bench measures, PROTOCOL.md section 7) and the plant's own G(j w)."""

from __future__ import annotations

import cmath
import math

import numpy as np
import pytest
from scipy import signal

from bodebench.core.chain import chain_factor, without_chain
from bodebench.core.response import FrequencyResponse, ResponsePoint

LAG = ([2.0], [0.02, 1.0])  # G(s) = 2 / (0.02 s + 1)
RATE = 2000.0


def g(f: float) -> complex:
    return complex(np.polyval(LAG[0], 2j * math.pi * f) / np.polyval(LAG[1], 2j * math.pi * f))


def g_d(f: float, rate: float = RATE) -> complex:
    num, den, _ = signal.cont2discrete(LAG, 1 / rate, method="zoh")
    z = cmath.exp(2j * math.pi * f / rate)
    return complex(np.polyval(np.ravel(num), z) / np.polyval(den, z))


def point(f: float, z: complex, harmonic: int = 1, u: float = 1e-6) -> ResponsePoint:
    return ResponsePoint(frequency_hz=f, harmonic=harmonic, channel="position", amplitude=1.0, p=z.real, q=z.imag,
                         periods=10, converged=True, status="converged", uncertainty=u, uncertainty_1d=u / 2,
                         within_eps=True)


@pytest.mark.parametrize("f", [1.0, 7.0, 20.0, 60.0])
def test_the_holds_delay_taken_off_a_bench_response_leaves_the_plants_phase_to_a_few_percent_of_it(f: float) -> None:
    """G_d against G: the bench response lags by about w h / 2; turned forward by that, what is left of the phase
    is under 2 % of what was taken off, and the gain is the bench's as measured."""
    (corrected,) = without_chain(FrequencyResponse([point(f, g_d(f))]), RATE)
    z = complex(corrected.p, corrected.q)
    removed = math.pi * f / RATE
    assert abs(cmath.phase(g_d(f) / g(f))) > 0.9 * removed  # the lag that is there
    assert abs(cmath.phase(z / g(f))) < 0.02 * removed
    assert abs(z) == pytest.approx(abs(g_d(f)), rel=1e-15)


def test_a_declared_delay_comes_off_exactly_and_its_uncertainty_widens_the_intervals() -> None:
    f, d, u_d = 30.0, 0.0012, 0.0001
    z = 0.4 - 0.3j
    delayed = point(f, z * chain_factor(f, 3, RATE, d), harmonic=3)
    response = FrequencyResponse([delayed], config={"a": 1}, case="c")
    (out,) = without_chain(response, RATE, d, u_d)
    assert complex(out.p, out.q) == pytest.approx(z, rel=1e-12)
    spread = abs(z) * 2 * math.pi * 3 * f * u_d
    assert out.uncertainty == pytest.approx(math.hypot(delayed.uncertainty, spread))
    assert without_chain(response, RATE, d).config["chain_removed"] == {"hold_rate_hz": RATE, "delay_s": d,
                                                                        "delay_uncertainty_s": 0.0}


def test_nonsense_is_refused() -> None:
    with pytest.raises(ValueError, match="rate_hz"):
        without_chain(FrequencyResponse(), 0.0)
    with pytest.raises(ValueError, match="delay_s"):
        without_chain(FrequencyResponse(), RATE, -1.0)
