"""The bench's own delays in a measured response, taken off on request: the hold's half period and a declared delay.

A bench point is the sampled-data response from the setpoint sequence to the feedback samples (drivers/PROTOCOL.md
section 7): for a linear drive ``G_d(exp(j w h))``, the zero-order-hold discretisation of G at the control period
h, times any further delay d. Its phase lags ``G(j w)`` by about half a period of the hold, ``w h / 2``, plus ``w d``.
:func:`without_chain` turns each point of harmonic k forward by ``k w (h / 2 + d)``, so its phase reads as the
plant's; the gain is left as measured. The hold also changes the gain, by ``sin(w h / 2) / (w h / 2)`` for its own
part, but the images of the staircase folded back by the sampling change it again, by an amount that depends on how
the plant rolls off beyond the measured band (for a first-order lag they give back about twice what the hold
takes), so no correction of the gain holds for every drive. What the phase keeps after the turn is that fold's
share of it, small against ``w h / 2`` below a few percent of the rate (docs/METHOD.md). A declared delay's
uncertainty (95 % half-width) goes into each point's intervals: ``|Z| * 2 pi k f * u_d``, added in quadrature.
Pure numerics.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import replace

from bodebench.core.response import FrequencyResponse, ResponsePoint

__all__ = ["chain_factor", "without_chain"]


def chain_factor(frequency_hz: float, harmonic: int, rate_hz: float, delay_s: float = 0.0) -> complex:
    """``exp(-j k w (h / 2 + d))``: the hold's half period at ``rate_hz`` and a delay of ``delay_s`` (s) at harmonic
    ``harmonic`` of ``frequency_hz`` (Hz)."""
    w = 2.0 * math.pi * harmonic * frequency_hz
    return cmath.exp(-1j * w * (0.5 / rate_hz + delay_s))


def _point_without(p: ResponsePoint, rate_hz: float, delay_s: float, delay_uncertainty_s: float) -> ResponsePoint:
    h = chain_factor(p.frequency_hz, p.harmonic, rate_hz, delay_s)
    z = complex(p.p, p.q) / h
    spread = abs(z) * 2.0 * math.pi * p.harmonic * p.frequency_hz * delay_uncertainty_s
    return replace(p, p=z.real, q=z.imag, uncertainty=math.hypot(p.uncertainty, spread),
                   uncertainty_1d=math.hypot(p.uncertainty_1d, spread))


def without_chain(response: FrequencyResponse, rate_hz: float, delay_s: float = 0.0,
                  delay_uncertainty_s: float = 0.0) -> FrequencyResponse:
    """``response`` with the hold's half period at ``rate_hz`` (Hz) and a delay of ``delay_s`` (s, known to +-
    ``delay_uncertainty_s``) turned out of every point's phase; the configuration records what was taken off
    (``chain_removed``), so a saved copy says what it is."""
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a finite number of Hz > 0, got {rate_hz!r}")
    for name, value in (("delay_s", delay_s), ("delay_uncertainty_s", delay_uncertainty_s)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite number of seconds >= 0, got {value!r}")
    config = {**response.config, "chain_removed": {"hold_rate_hz": rate_hz, "delay_s": delay_s,
                                                   "delay_uncertainty_s": delay_uncertainty_s}}
    return FrequencyResponse((_point_without(p, rate_hz, delay_s, delay_uncertainty_s) for p in response),
                             config=config, case=response.case)
