"""The excitation as the setpoint's frames carry it: the rounding of each signal type, computed in one step, is the
frame's own (encode then decode, value by value); the staircase's fundamental over the sine's, against direct sums;
a point taken against it, against the two-channel convention."""

from __future__ import annotations

import cmath
import math
from pathlib import Path

import cantools
import numpy as np
import pytest

from bodebench.core.response import ResponsePoint
from bodebench.core.setpoint_rounding import rounding_ratios, taken_against
from bodebench.drivers.codec import Message, Signal
from bodebench.drivers.dbc import DbcMessage

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize(("kind", "scale", "offset"), [("int16", 5e-4, 0.0), ("int32", 1e-9, 0.0),
                                                      ("uint16", 0.01, -300.0), ("int8", 0.1, 0.05),
                                                      ("float32", 1.0, 0.0), ("float32", 1e-3, 2.0),
                                                      ("float64", 1.0, 0.0)])
def test_the_rounding_in_one_step_is_the_frames_own(kind: str, scale: float, offset: float) -> None:
    message = Message("setpoint", 0x201, signals=(Signal("setpoint", 0, kind, scale=scale, offset=offset),))
    rng = np.random.default_rng(7)
    span = {"int8": 10.0, "uint16": 300.0, "int32": 1.5}.get(kind, 15.0)
    values = offset + (rng.uniform(0.05, 0.95, 2000) * span if kind == "uint16" else rng.uniform(-1, 1, 2000) * span)
    frames = [message.decode(message.encode({"setpoint": float(v)}))["setpoint"] for v in values]
    assert np.array_equal(message.carried("setpoint", values), np.array(frames))


def test_a_dbc_signal_rounds_in_one_step_as_its_frames_do() -> None:
    db = cantools.database.load_file(str(ROOT / "configs" / "real_can.dbc"))
    message = DbcMessage(db.get_message_by_name("HostSetpoint"), {"setpoint": "Setpoint", "counter": "SetpointCounter"})
    values = np.random.default_rng(3).uniform(-9.9, 9.9, 500)
    frames = [message.decode(message.encode({"setpoint": float(v), "counter": 0}))["setpoint"] for v in values]
    assert np.allclose(message.carried("setpoint", values), frames, rtol=0, atol=1e-12)


def _direct(quantum: float, amplitude: float, f: float, h: float, tick0: int, t0: float, n: int) -> complex:
    """The ratio by plain sums over the ticks of periods 1..n."""
    ticks = [c for c in range(0, int((t0 + n / f) / h) + 2) if t0 - 1e-12 <= c * h < t0 + n / f - 1e-12]
    c = np.array(ticks, dtype=float)
    sent = amplitude * np.sin(2 * math.pi * f * (c - tick0) * h)
    carried = np.round(sent / quantum) * quantum
    w = np.exp(-2j * math.pi * f * (c * h - t0))
    return complex(np.sum(carried * w) / np.sum(sent * w))


@pytest.mark.parametrize(("rate_hz", "f"), [(1000.0, 5.0), (1000.0, 7.3), (2000.0, 60.0)])
def test_the_staircases_fundamental_over_the_sines_is_the_plain_sums(rate_hz: float, f: float) -> None:
    h, amplitude, quantum, tick0 = 1.0 / rate_hz, 0.01, 0.01 / 20, 37
    t0 = tick0 * h + 2 / f  # after two periods of ramp
    ratios = rounding_ratios(lambda v: np.round(v / quantum) * quantum, amplitude, f, h, tick0, t0, (1, 3, 17, 40))
    for n, rho in ratios.items():
        assert abs(rho - _direct(quantum, amplitude, f, h, tick0, t0, n)) < 1e-12
        assert 1e-4 < abs(rho - 1) < 0.05  # 20 steps: a few tenths of a percent
    fine = rounding_ratios(lambda v: v, amplitude, f, h, tick0, t0, (17,))
    assert abs(fine[17] - 1) < 1e-12


def test_a_point_is_taken_against_the_staircase_as_two_channel_mode_takes_a_reference() -> None:
    """Harmonic k's coefficient Y: Y conj(rho)^k / |rho|^(k+1), two-channel mode's formula with the reference's
    fundamental rho (the sine's amplitude left to the point's own); one whose rho is within a hundredth of its
    tolerance is left as measured."""
    rho = 1.003 * cmath.exp(0.002j)
    points = [ResponsePoint(frequency_hz=5.0, harmonic=k, channel="y", amplitude=1.0, p=0.3 * k, q=-0.1,
                            periods=20, converged=True, status="converged", uncertainty=1e-5, uncertainty_1d=8e-6,
                            within_eps=True, tolerance_percent=0.01) for k in (1, 2, 3)]
    for p, taken in zip(points, taken_against(points, {20: rho}), strict=True):
        expected = complex(p.p, p.q) * rho.conjugate() ** p.harmonic / abs(rho) ** (p.harmonic + 1)
        assert abs(complex(taken.p, taken.q) - expected) < 1e-15
        assert taken.uncertainty == pytest.approx(p.uncertainty / abs(rho))
    assert taken_against(points, {20: 1 + 5e-9j}) == points  # 5e-9 < 1 % of 0.01 %
