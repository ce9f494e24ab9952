"""Tests of the electrohydraulic position drive (sim/hydraulic.py) and its configuration entry."""

from __future__ import annotations

import dataclasses
import inspect
import math
from typing import Any

import numpy as np
import pytest
from scipy.optimize import brentq

from bodebench.bench.offline import build_plant
from bodebench.core.fourier import PeriodIntegrator
from bodebench.io.config import ConfigError, PlantConfig, parse_config
from bodebench.sim.hydraulic import HYDRAULIC_DEFAULTS, ElectrohydraulicDrive
from bodebench.sim.models import plant_from_config

D = HYDRAULIC_DEFAULTS
POSITION, VELOCITY, SPOOL, PRESSURE = range(4)


def force(drive: ElectrohydraulicDrive, out: np.ndarray) -> np.ndarray:
    """Net hydraulic and spring force A_p P_L - K_load y on the piston, N."""
    return drive.piston_area * out[:, PRESSURE] - drive.load_stiffness * out[:, POSITION]


# --------------------------------------------------------------------------------------------- small signal


def hand_linearised_response(f: float, p: dict[str, float]) -> np.ndarray:
    """Setpoint-to-output transfer functions at f (Hz), derived by hand as polynomial ratios.

    About P_L = 0, x_v = 0 the flow is Q_L ~ K_qv x_v with K_qv = K_q sqrt(P_s/2) (the pressure term is of second
    order in the small quantities). With c = V_t/(4 beta) and Laplace variable s:
        (m s^2 + b s + K) Y = A_p P,   c s P = K_qv X - A_p s Y - C_l P
        => Y/X = A_p K_qv / Dh,  Dh = (m s^2 + b s + K)(c s + C_l) + A_p^2 s
        X = w_v^2/(s^2 + 2 zeta w_v s + w_v^2) * K_loop (R - Y)
    Closing the loop with N = K_loop w_v^2 A_p K_qv and D = Dv Dh + N:
        Y/R = N/D, V/R = s N/D, X/R = K_loop w_v^2 Dh/D, P/R = (m s^2 + b s + K) N/(A_p D).
    Returns [Y/R, V/R, X/R, P/R] as complex numbers.
    """
    wv = 2.0 * math.pi * p["valve_natural_frequency_hz"]
    kqv = p["valve_gain"] * math.sqrt(p["supply_pressure"] / 2.0)
    c = p["total_volume"] / (4.0 * p["bulk_modulus"])
    mech = np.array([p["piston_mass"], p["viscous_damping"], p["load_stiffness"]])
    dv = np.array([1.0, 2.0 * p["valve_damping_ratio"] * wv, wv * wv])
    dh = np.polyadd(np.polymul(mech, [c, p["leakage"]]), [p["piston_area"] ** 2, 0.0])
    n = p["loop_gain"] * wv * wv * p["piston_area"] * kqv
    d = np.polyadd(np.polymul(dv, dh), [n])
    s = 2j * math.pi * f
    den = np.polyval(d, s)
    return np.array([
        n / den,
        s * n / den,
        p["loop_gain"] * wv * wv * np.polyval(dh, s) / den,
        np.polyval(mech, s) * n / (p["piston_area"] * den),
    ])


def first_harmonic_of_last_period(t: np.ndarray, y: np.ndarray, f: float) -> np.ndarray:
    """Complex first-harmonic amplitude P + jQ of every column over the last whole period."""
    integ = PeriodIntegrator(f, [1], y.shape[1])
    p, q = integ.feed(np.concatenate([[0.0], t]), np.vstack([np.zeros((1, y.shape[1])), y]))
    return p[-1, :, 0] + 1j * q[-1, :, 0]


@pytest.mark.parametrize("load_stiffness", [0.0, 2e5])
@pytest.mark.parametrize("f", [2.0, 13.0, 40.0, 77.0, 150.0])
def test_small_signal_matches_hand_linearised_model(f: float, load_stiffness: float) -> None:
    params = {**D, "coulomb_friction": 0.0, "load_stiffness": load_stiffness}
    drive = ElectrohydraulicDrive(**params)
    amplitude = 1e-7  # m: far from every saturation; the flow's pressure term stays ~1e-5 of the linear one
    steps = 200
    periods = max(3, math.ceil(0.5 * f))  # >= 0.5 s: the slowest mode (|Re| >= 30 1/s) has decayed to < 1e-6
    h = 1.0 / (steps * f)
    y = drive.run_sine(drive.initial_state(), 0.0, h, periods * steps, amplitude, f)
    t = (1 + np.arange(periods * steps)) * h
    measured = first_harmonic_of_last_period(t, y, f) / amplitude
    expected = hand_linearised_response(f, params)
    assert np.all(np.abs(measured / expected - 1.0) < 1e-3), (measured, expected)


def test_linearized_plant_agrees_with_hand_derivation() -> None:
    params = {**D, "load_stiffness": 3e5, "leakage": 5e-12}
    drive = ElectrohydraulicDrive(**params)
    freqs = np.array([0.3, 7.0, 55.0, 400.0])
    g = drive.linearized().frequency_response(freqs)
    for i, f in enumerate(freqs):
        expected = hand_linearised_response(float(f), params)
        np.testing.assert_allclose(g[i], expected, rtol=1e-9)


def test_derived_quantities() -> None:
    drive = ElectrohydraulicDrive()
    k_h = 4.0 * D["bulk_modulus"] * D["piston_area"] ** 2 / D["total_volume"]
    assert drive.natural_frequency_hz == pytest.approx(math.sqrt(k_h / D["piston_mass"]) / (2 * math.pi), rel=1e-12)
    # The defaults describe the intended class of drive.
    assert 30.0 <= drive.natural_frequency_hz <= 80.0
    f = np.linspace(0.1, 60.0, 6000)
    gain = np.abs(np.array([hand_linearised_response(float(x), dict(D))[0] for x in f]))
    bandwidth = f[np.argmax(gain < 10 ** (-3 / 20))]
    assert 10.0 <= bandwidth <= 20.0
    assert drive.velocity_gain == pytest.approx(D["loop_gain"] * drive.max_velocity, rel=1e-12)
    assert drive.piston_area * D["supply_pressure"] == pytest.approx(10.5e3)


# --------------------------------------------------------------------------------------------- saturation


def plateau_velocity(p: dict[str, float]) -> float:
    """Steady velocity at full spool (K_load = 0): K_q sqrt((P_s - P_L)/2) = A_p v + C_l P_L, A_p P_L = F_c + b v."""
    ps, kq, ap, b, cl, fc = (p[k] for k in ("supply_pressure", "valve_gain", "piston_area", "viscous_damping",
                                            "leakage", "coulomb_friction"))

    def residual(v: float) -> float:
        pl = (fc + b * v) / ap
        return kq * math.sqrt((ps - pl) / 2.0) - ap * v - cl * pl

    top = 10.0 if b == 0 else (ps * ap - fc) / b
    return brentq(residual, 0.0, top, xtol=1e-15, rtol=1e-14)


@pytest.mark.parametrize("extra", [
    {"viscous_damping": 0.0, "leakage": 0.0, "coulomb_friction": 0.0},
    {},
    {"viscous_damping": 8000.0, "leakage": 1e-11, "coulomb_friction": 1000.0, "supply_pressure": 100e5},
])
@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_large_step_saturates_flow(extra: dict[str, float], direction: float) -> None:
    params = {**D, "load_stiffness": 0.0, **extra}
    drive = ElectrohydraulicDrive(**params)
    h = 1e-4
    out = drive.run_held(drive.initial_state(), np.full(2500, 0.5 * direction), h)
    plateau = out[1500:2500]  # 0.15 s .. 0.25 s: position error still > 1/K_loop, spool at its stop
    v_expected = plateau_velocity(params)
    if not extra or extra.get("leakage", 1.0) != 0.0:
        assert v_expected < 0.99 * drive.max_velocity  # the pressure drop and leakage matter here
    else:
        assert v_expected == pytest.approx(D["valve_gain"] * math.sqrt(D["supply_pressure"] / 2) / D["piston_area"])
    np.testing.assert_allclose(plateau[:, VELOCITY], direction * v_expected, rtol=1e-6)
    assert np.all(plateau[:, SPOOL] == direction)
    assert np.max(np.abs(out[:, SPOOL])) <= 1.0
    expected_pl = (params["coulomb_friction"] + params["viscous_damping"] * v_expected) / params["piston_area"]
    np.testing.assert_allclose(plateau[:, PRESSURE], direction * expected_pl, rtol=1e-6,
                               atol=1e-9 * params["supply_pressure"])


# --------------------------------------------------------------------------------------------- friction


def triangle_setpoints(rate: float, leg: float, legs: int, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Setpoint ramps of +-rate (m/s), each leg seconds long, sampled mid-step; returns (t_end, setpoints)."""
    n = round(leg / h)
    t_mid = (np.arange(legs * n) + 0.5) * h
    phase = t_mid % (2 * leg)
    r = rate * np.where(phase < leg, phase, 2 * leg - phase)
    return (np.arange(legs * n) + 1) * h, r


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges where mask is True."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0], strict=False))


def test_slow_ramp_sticks_while_force_inside_friction_band() -> None:
    drive = ElectrohydraulicDrive()
    fc = drive.coulomb_friction
    h = 1e-4
    _, r = triangle_setpoints(rate=1e-4, leg=0.6, legs=3, h=h)
    out = drive.run_held(drive.initial_state(), r, h)
    f = force(drive, out)
    stuck = out[:, VELOCITY] == 0.0
    stuck_runs = [(a, b) for a, b in runs(stuck) if b - a > 10]
    # Stuck at the start and again at each of the two reversals (the force swings through the band there).
    assert len(stuck_runs) == 3
    assert stuck_runs[0][0] == 0
    for a, b in stuck_runs:
        assert np.all(out[a:b, POSITION] == out[a, POSITION])  # the piston does not creep
        assert np.all(np.abs(f[a:b]) <= fc * (1 + 1e-12))
        assert abs(abs(f[b]) - fc) < 0.01 * fc  # it breaks away as the force leaves the band
    for (a, b), leg_end in zip(stuck_runs[1:], (6000, 12000), strict=False):
        assert leg_end - 200 < a < leg_end + 500 and b < leg_end + 6000
        # during the stick at a reversal the force has crossed from one edge of the band to the other
        assert f[a] * f[b] < 0
        assert abs(abs(f[a]) - fc) < 0.05 * fc
    # No sample with the force outside the band is stuck.
    assert not np.any(stuck & (np.abs(f) > fc * (1 + 1e-12)))
    # one break-away per stuck run and one stick per reversal: no chatter
    assert drive.events == 2 * len(stuck_runs) - 1


def test_ramp_following_error_matches_steady_state() -> None:
    # Steady sliding at the ramp rate v: A_p P_L = F_c + b v and K_q x_v sqrt((P_s - P_L)/2) = A_p v + C_l P_L
    # with x_v = K_loop e (the valve is static at constant flow).
    drive = ElectrohydraulicDrive()
    h, rate = 1e-4, 1e-4
    t, r = triangle_setpoints(rate=rate, leg=0.8, legs=1, h=h)
    out = drive.run_held(drive.initial_state(), r, h)
    pl = (D["coulomb_friction"] + D["viscous_damping"] * rate) / D["piston_area"]
    flow = D["piston_area"] * rate + D["leakage"] * pl
    spool = flow / (D["valve_gain"] * math.sqrt((D["supply_pressure"] - pl) / 2))
    error = spool / D["loop_gain"]
    assert out[-1, VELOCITY] == pytest.approx(rate, rel=1e-6)
    assert out[-1, PRESSURE] == pytest.approx(pl, rel=1e-6)
    assert out[-1, SPOOL] == pytest.approx(spool, rel=1e-6)
    assert rate * t[-1] - out[-1, POSITION] == pytest.approx(error, rel=1e-4)


def test_stick_slip_converges_with_substep() -> None:
    h = 1e-4
    _, r = triangle_setpoints(rate=2e-4, leg=0.3, legs=2, h=h)
    results = []
    for spp in (40, 160):
        drive = ElectrohydraulicDrive(substeps_per_period=spp)
        results.append(drive.run_held(drive.initial_state(), r, h))
    coarse, fine = results
    assert np.array_equal(coarse[:, VELOCITY] == 0.0, fine[:, VELOCITY] == 0.0)
    np.testing.assert_allclose(coarse[:, POSITION], fine[:, POSITION], rtol=0, atol=1e-10)
    np.testing.assert_allclose(coarse[:, PRESSURE], fine[:, PRESSURE], rtol=0,
                               atol=1e-7 * np.max(np.abs(fine[:, PRESSURE])))


# --------------------------------------------------------------------------------------------- input forms


@pytest.mark.parametrize("friction", [0.0, D["coulomb_friction"]])
def test_run_held_matches_run_sine_at_high_rate(friction: float) -> None:
    drive = ElectrohydraulicDrive(coulomb_friction=friction)
    f, amplitude = 4.0, 2e-3
    errors = []
    for steps in (2500, 5000):
        h = 1.0 / (steps * f)
        n = 2 * steps
        y_sine = drive.run_sine(drive.initial_state(), 0.0, h, n, amplitude, f)
        # each held setpoint is the sine at mid-step: the held input differs from the sine by O(h^2) on average
        held = amplitude * np.sin(2 * math.pi * f * (np.arange(n) + 0.5) * h)
        y_held = drive.run_held(drive.initial_state(), held, h)
        errors.append(np.max(np.abs(y_held - y_sine), axis=0) / np.max(np.abs(y_sine), axis=0))
    assert np.all(errors[1] < 3e-5)
    # second order in h: halving the step quarters the difference
    assert np.all((errors[0] / errors[1] > 3.5) & (errors[0] / errors[1] < 4.5))
    # and the held setpoint at the step start (a delay of h/2) is visibly worse
    early = drive.run_held(drive.initial_state(), amplitude * np.sin(2 * math.pi * f * np.arange(n) * h), h)
    assert np.max(np.abs(early[:, POSITION] - y_sine[:, POSITION])) > 10 * np.max(
        np.abs(y_held[:, POSITION] - y_sine[:, POSITION]))


@pytest.mark.parametrize("friction", [0.0, D["coulomb_friction"]])
def test_chunk_invariance(friction: float) -> None:
    drive = ElectrohydraulicDrive(coulomb_friction=friction)
    f, amplitude, steps = 9.0, 1e-3, 160
    h = 1.0 / (steps * f)
    n = 6 * steps
    whole_state = drive.initial_state()
    whole = drive.run_sine(whole_state, 0.0, h, n, amplitude, f)
    state = drive.initial_state()
    parts, step = [], 0
    for size in (1, 7, 200, 0, 313, n - 521):
        parts.append(drive.run_sine(state, step * h, h, size, amplitude, f))
        step += size
    chunked = np.vstack(parts)
    scale = np.max(np.abs(whole), axis=0)
    assert np.all(np.max(np.abs(chunked - whole), axis=0) <= 1e-9 * scale)
    np.testing.assert_allclose(state.x, whole_state.x, rtol=1e-9, atol=1e-9 * np.max(np.abs(whole_state.x)))
    # held input: no time dependence, so the chunks reproduce the single run exactly
    setpoints = amplitude * np.sin(np.linspace(0.0, 12.0, n))
    one = drive.run_held(drive.initial_state(), setpoints, h)
    state = drive.initial_state()
    pieces = [drive.run_held(state, setpoints[a:b], h) for a, b in ((0, 5), (5, 5), (5, 400), (400, n))]
    np.testing.assert_array_equal(np.vstack(pieces), one)


def test_rest_stays_at_rest() -> None:
    drive = ElectrohydraulicDrive()
    out = drive.run_held(drive.initial_state(), np.zeros(100), 1e-3)
    assert np.all(out == 0.0)
    assert out.shape == (100, 4)
    assert drive.output_names == ("position", "velocity", "spool", "load_pressure")


@pytest.mark.parametrize("name", ["supply_pressure", "valve_gain", "piston_area", "total_volume", "bulk_modulus",
                                  "piston_mass", "loop_gain", "valve_natural_frequency_hz"])
def test_bad_parameters_are_refused(name: str) -> None:
    with pytest.raises(ValueError, match=name):
        ElectrohydraulicDrive(**{name: 0.0})
    with pytest.raises(ValueError, match=name):
        ElectrohydraulicDrive(**{name: math.nan})


@pytest.mark.parametrize("name", ["leakage", "load_stiffness", "viscous_damping", "coulomb_friction",
                                  "valve_damping_ratio"])
def test_negative_parameters_are_refused(name: str) -> None:
    ElectrohydraulicDrive(**{name: 0.0})
    with pytest.raises(ValueError, match=name):
        ElectrohydraulicDrive(**{name: -1.0})


def test_bad_step_is_refused() -> None:
    drive = ElectrohydraulicDrive()
    with pytest.raises(ValueError, match="step h"):
        drive.run_held(drive.initial_state(), np.zeros(3), 0.0)


# --------------------------------------------------------------------------------------------- configuration


HYDRAULIC_KEYS = {
    "supply_pressure": 160e5, "valve_gain": 2.5e-7, "valve_natural_frequency_hz": 120.0, "valve_damping_ratio": 0.6,
    "piston_area": 8e-4, "total_volume": 3e-4, "bulk_modulus": 1.2e9, "leakage": 1e-12, "piston_mass": 25.0,
    "load_stiffness": 1e5, "viscous_damping": 500.0, "coulomb_friction": 80.0, "loop_gain": 40.0,
}


def config(plant: dict[str, Any]) -> dict[str, Any]:
    return {"plant": plant, "excitation": {"amplitude": 1e-3, "frequencies_hz": [1.0, 10.0]}}


def test_config_accepts_hydraulic_model() -> None:
    case = parse_config(config({"model": "hydraulic", **HYDRAULIC_KEYS})).cases[0]
    assert case.raw["plant"] == {"model": "hydraulic", **HYDRAULIC_KEYS}
    drive = build_plant(case.plant)
    assert isinstance(drive, ElectrohydraulicDrive)
    for key, value in HYDRAULIC_KEYS.items():
        assert getattr(drive, key) == value


def test_config_defaults_match_plant_defaults() -> None:
    case = parse_config(config({"model": "hydraulic"})).cases[0]
    assert case.raw["plant"] == {"model": "hydraulic", **HYDRAULIC_DEFAULTS}
    signature = inspect.signature(ElectrohydraulicDrive)
    for key, value in HYDRAULIC_DEFAULTS.items():
        assert signature.parameters[key].default == value
    drive = build_plant(case.plant)
    assert drive.linearized().frequency_response(5.0)[0] == pytest.approx(
        ElectrohydraulicDrive().linearized().frequency_response(5.0)[0], rel=1e-15)


@pytest.mark.parametrize("key", ["mass", "stiffness", "friction", "damping_ratio", "time_constant", "gain"])
def test_config_rejects_other_models_keys_for_hydraulic(key: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(config({"model": "hydraulic", key: 1.0}))
    assert str(info.value) == f'<config>: plant.{key}: not a parameter of model "hydraulic"'


@pytest.mark.parametrize("model", ["coulomb", "linear", "lag"])
def test_config_rejects_hydraulic_keys_for_other_models(model: str) -> None:
    for key in HYDRAULIC_KEYS:
        with pytest.raises(ConfigError) as info:
            parse_config(config({"model": model, key: 1.0}))
        assert str(info.value) == f'<config>: plant.{key}: not a parameter of model "{model}"'
    raw = parse_config(config({"model": model})).cases[0].raw["plant"]
    assert not set(raw) & set(HYDRAULIC_KEYS)


@pytest.mark.parametrize(("key", "value", "problem"), [
    ("piston_area", 0.0, "must be > 0, got 0.0"),
    ("supply_pressure", -1.0, "must be > 0, got -1.0"),
    ("leakage", -1e-12, "must be >= 0, got -1e-12"),
    ("coulomb_friction", "x", 'expected a number, got string "x"'),
])
def test_config_checks_hydraulic_values(key: str, value: Any, problem: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(config({"model": "hydraulic", key: value}))
    assert str(info.value) == f"<config>: plant.{key}: {problem}"


def test_plant_from_config_builds_every_model_from_a_full_table() -> None:
    # build_plant hands over every field of the table, whatever the model
    for model in ("coulomb", "linear", "lag", "hydraulic"):
        fields = dataclasses.asdict(PlantConfig(model=model))
        plant = plant_from_config(fields.pop("model"), **fields)
        assert isinstance(plant, ElectrohydraulicDrive) == (model == "hydraulic")
    with pytest.raises(ValueError, match="piston_radius"):
        plant_from_config("hydraulic", piston_radius=0.01)
