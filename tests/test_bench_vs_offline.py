"""The bench chain against the offline experiment: the same config swept on the virtual CAN bus (lockstep, the
simulated drive behind the wire protocol, through :class:`bodebench.bench.procedure.SweepProcedure`) and by the
offline :func:`bodebench.bench.offline.sweep` of its plant.

The simulated drive holds each setpoint for one controller period h and samples the plant once a period: what the
bench measures of a linear plant G(s) is its zero-order-hold discretisation G_d(z) at z = exp(j w h), the offline
experiment G(j w). The ratio G_d / G comes from an independent solver (scipy's ``cont2discrete``); with it the two
chains must agree to within the tolerance plus both stated uncertainties, at every point.
"""

from __future__ import annotations

import cmath
import math
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import signal

from bodebench.bench.offline import sweep
from bodebench.bench.procedure import SweepProcedure
from bodebench.core.response import FrequencyResponse
from bodebench.io.config import parse_config
from bodebench.io.results import load_response

RATE_HZ = 1000.0
EPS_PERCENT = 0.01

MASS = 1 / (2 * math.pi * 5) ** 2
PLANTS: dict[str, tuple[dict[str, Any], list[float], list[float]]] = {  # [plant] table, numerator, denominator
    "oscillator": ({"model": "linear", "mass": MASS, "stiffness": 1.0, "damping_ratio": 0.2},
                   [1.0], [MASS, 2 * 0.2 * math.sqrt(MASS), 1.0]),
    "lag": ({"model": "lag", "time_constant": 0.02, "gain": 2.0}, [2.0], [0.02, 1.0]),
}


def held_over_continuous(num: list[float], den: list[float], frequency_hz: float) -> complex:
    """G_d(exp(j w h)) / G(j w) for G = num/den held and sampled at RATE_HZ."""
    w, h = 2 * math.pi * frequency_hz, 1 / RATE_HZ
    num_d, den_d, _ = signal.cont2discrete((num, den), h, method="zoh")
    z = cmath.exp(1j * w * h)
    held = np.polyval(np.ravel(num_d), z) / np.polyval(den_d, z)
    return complex(held / (np.polyval(num, 1j * w) / np.polyval(den, 1j * w)))


@pytest.mark.slow
@pytest.mark.parametrize("plant", sorted(PLANTS))
def test_the_bench_chain_measures_what_the_offline_experiment_computes(tmp_path: Path, plant: str) -> None:
    table, num, den = PLANTS[plant]
    base = {
        "plant": table,
        "excitation": {"amplitude": 0.01, "frequencies_hz": [2.0, 5.0, 12.0]},
        "analysis": {"tolerance_percent": EPS_PERCENT, "steps_per_period": 400},
    }
    bench = {**base, "bench": {"transport": "can", "rate_hz": RATE_HZ, "clock": "lockstep"},
             "can": {"interface": "virtual", "channel": f"offline-{uuid.uuid4().hex[:8]}"},
             "safety": {"max_amplitude": 0.02}, "simulator": {}}
    outcomes = SweepProcedure(parse_config(bench, "bench.toml"), tmp_path).run()
    assert_bench_agrees_with_offline(tmp_path, outcomes[0].response, base, num, den, [2.0, 5.0, 12.0])


def assert_bench_agrees_with_offline(directory: Path, returned: FrequencyResponse, base: dict[str, Any],
                                     num: Sequence[float], den: Sequence[float], freqs: list[float]) -> None:
    """What a bench sweep left in ``directory`` is what it returned, and each point is the offline experiment's of
    ``base`` times the zero-order hold's ratio, within the tolerance and both points' uncertainties."""
    on_bench = load_response(directory)
    assert [(p.frequency_hz, p.p, p.q) for p in on_bench] == [(p.frequency_hz, p.p, p.q) for p in returned]
    offline = {p.frequency_hz: p for p in sweep(parse_config(base, "offline.toml").cases[0])}
    assert sorted(offline) == sorted(p.frequency_hz for p in on_bench) == freqs
    for measured in on_bench:
        computed = offline[measured.frequency_hz]
        assert measured.converged and computed.converged
        z_bench = complex(measured.p, measured.q)
        z_offline = complex(computed.p, computed.q) * held_over_continuous(num, den, measured.frequency_hz)
        allowed = EPS_PERCENT / 100 * abs(z_offline) + measured.uncertainty + computed.uncertainty
        assert abs(z_bench - z_offline) <= allowed, (measured.frequency_hz, abs(z_bench - z_offline), allowed)
