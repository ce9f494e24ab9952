"""Identifying the friction link: tick arithmetic, the settled-motion model, the calibration table, the paper's
procedure, the fit and the command.

Expected values come from elsewhere: the paper's worked tick example and hand-counted ticks, the exact linear
response, the instrument's own autointegration from rest (an independent route to the settled harmonic), the
parameters of the simulated links, and statistics of added noise.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from concurrent.futures import Executor
from pathlib import Path

import numpy as np
import pytest

from bodebench.analysis import calibration
from bodebench.analysis.calibration import (
    DEFAULT_FBAR_GRID,
    DEFAULT_OFFSET_GRID,
    STEPS_PER_PERIOD,
    CalibrationError,
    FrictionLink,
    SteadyStateError,
    compute_calibration,
    crossing_ratio,
    load_calibration,
)
from bodebench.analysis.identify import (
    NO_CROSSING,
    IdentificationError,
    crossing_frequency,
    decade_tick,
    fit_link,
    link_parameters,
    measured_curve,
    paper_procedure,
    predicted_response,
    tick_frequencies,
)
from bodebench.apps.cli import main
from bodebench.bench.offline import default_executor, measure_frequency, sweep
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.io.config import CaseConfig, parse_config
from bodebench.io.results import save_response

AMPLITUDE = 0.01  # A_F
STIFFNESS = 1.0  # K_p
DISC_PER_SIGMA = math.sqrt(-2.0 * math.log(0.05))  # the 95 % disc radius of (p, q) per component sigma
LINE_PER_SIGMA = 1.959963984540054  # the 95 % half-width along one direction per component sigma


def mass_of(f_n: float, stiffness: float = STIFFNESS) -> float:
    return stiffness / (2.0 * math.pi * f_n) ** 2


def friction_case(fbar: float, f_n: float, freqs: list[float], stiffness: float = STIFFNESS,
                  zeta: float = 0.0) -> CaseConfig:
    data = {
        "plant": {"model": "coulomb", "mass": mass_of(f_n, stiffness), "stiffness": stiffness,
                  "friction": fbar * AMPLITUDE, "damping_ratio": zeta},
        "excitation": {"amplitude": AMPLITUDE, "frequencies_hz": freqs},
        "analysis": {"harmonics": [1]},
    }
    return parse_config(data).cases[0]


def tick_grid(f_n: float) -> list[float]:
    """Decade ticks from f_n/20 to 12 f_n."""
    return [t for t in (decade_tick(i) for i in range(-30, 40)) if f_n / 20.0 <= t <= 12.0 * f_n]


def arbitrary_grid(f_n: float, seed: int) -> list[float]:
    """22 frequencies from f_n/8 to 8 f_n, log-spaced and jittered by up to 4 %: no ticks, no f_n."""
    rng = np.random.default_rng(seed)
    grid = np.geomspace(f_n / 8.0, 8.0 * f_n, 22) * rng.uniform(0.96, 1.04, 22)
    return sorted(float(f"{f:.6g}") for f in grid)


def paper_grid(f_n: float) -> list[float]:
    """Ticks plus points every 2 % of f_n around resonance (as the 2013 grid adds 10.03, 10.1, ... near 10 Hz)."""
    dense = [round(f_n * x, 6) for x in (0.86, 0.88, 0.9, 0.92, 0.94, 0.96, 0.98, 1.02, 1.06)]
    return sorted(set(tick_grid(f_n) + dense))


GRIDS = {"ticks": lambda f_n, stiffness: tick_grid(f_n),
         "arbitrary": lambda f_n, stiffness: arbitrary_grid(f_n, int(100 * f_n + 10 * stiffness)),
         "paper": lambda f_n, stiffness: paper_grid(f_n)}

_SWEEPS: dict[tuple, FrequencyResponse] = {}


@pytest.fixture(scope="module")
def pool() -> Iterator[Executor]:
    executor = default_executor(2)
    yield executor
    executor.shutdown(cancel_futures=True)


def measured(pool: Executor, fbar: float, f_n: float, grid: str, stiffness: float = STIFFNESS,
             zeta: float = 0.0) -> FrequencyResponse:
    """The instrument's sweep of a simulated link (the paper's settings: eps 0.01 %, K_f 200), cached."""
    key = (fbar, f_n, grid, stiffness, zeta)
    if key not in _SWEEPS:
        freqs = GRIDS[grid](f_n, stiffness)
        _SWEEPS[key] = sweep(friction_case(fbar, f_n, freqs, stiffness, zeta), pool)
    return _SWEEPS[key]


# ------------------------------------------------------------------------------------------ tick arithmetic


def test_decade_ticks() -> None:
    assert [decade_tick(i) for i in (-10, -9, -1, 0, 1, 8, 9, 10, 17, 18)] == \
        [0.09, 0.1, 0.9, 1.0, 2.0, 9.0, 10.0, 20.0, 90.0, 100.0]


@pytest.mark.parametrize("f90,below,above", [
    (3.6, [2, 1, 0.8, 0.6], [5, 6, 8, 10]),  # the paper's example
    (0.95, [0.8, 0.7, 0.5, 0.3], [2, 3, 5, 7]),
    (4.0, [2, 1, 0.8, 0.6], [6, 7, 9, 20]),  # on a tick: nearest are 3 and 5
    (12.0, [9, 8, 6, 4], [30, 40, 60, 80]),
    (7.99, [6, 5, 3, 1], [9, 10, 30, 50]),
    (0.101, [0.09, 0.08, 0.06, 0.04], [0.3, 0.4, 0.6, 0.8]),
])
def test_tick_frequencies_count_from_the_nearest_tick(f90: float, below: list[float], above: list[float]) -> None:
    got_below, got_above = tick_frequencies(f90)
    assert got_below == pytest.approx(below, rel=1e-12)
    assert got_above == pytest.approx(above, rel=1e-12)


def test_crossing_frequency_interpolates_linearly_in_frequency() -> None:
    f = np.array([1.0, 2.0, 4.0, 5.0])
    assert crossing_frequency(f, np.array([-80.0, -85.0, -100.0, -120.0])) == [(2.0 + 2.0 * 5.0 / 15.0, 1)]
    assert crossing_frequency(f, np.array([-10.0, -20.0, -30.0, -40.0])) == []


# ------------------------------------------------------------------------------- the settled-motion model


def test_settled_motion_without_friction_is_the_linear_response() -> None:
    for zeta in (0.05, 0.3):
        link = FrictionLink(0.0, zeta)
        for r in (0.2, 0.9, 1.0, 2.5):
            exact = 1.0 / complex(1.0 - r * r, 2.0 * zeta * r)
            assert link.steady_state(r).z1 == pytest.approx(exact, rel=1e-9)


@pytest.mark.parametrize("fbar,ratio", [(0.3, 0.6), (0.6, 0.35), (0.8, 0.7), (0.8, 1.3), (0.95, 3.0),
                                        (0.4, 1.4)])
def test_settled_motion_matches_autointegration_from_rest(fbar: float, ratio: float) -> None:
    """The shooting solution against the instrument run from rest until the adaptive rule stops at eps 1e-5 %."""
    f_n = 7.0
    case = friction_case(fbar, f_n, [ratio * f_n])
    case = dataclasses.replace(case, analysis=dataclasses.replace(
        case.analysis, tolerance_percent=1e-5, steps_per_period=STEPS_PER_PERIOD, max_periods=5000))
    (point,) = measure_frequency(case, ratio * f_n)
    assert point.converged
    z = FrictionLink(fbar).steady_state(ratio).z1 * AMPLITUDE / STIFFNESS
    assert complex(point.p, point.q) == pytest.approx(z, rel=2e-6)


def test_predicted_response_is_what_the_instrument_measures(pool: Executor) -> None:
    """The model at the simulated link's own parameters against its sweep (K_p = 2, so units matter)."""
    response = measured(pool, 0.85, 12.0, "ticks", stiffness=2.0)
    points = [p for p in response.points if p.converged]
    f = [p.frequency_hz for p in points]
    g = predicted_response(0.85, 12.0, f, 2.0, AMPLITUDE)
    assert g == pytest.approx([complex(p.p, p.q) / p.amplitude for p in points], rel=1e-4)
    # the same link driven through an input scaled by 1/4 before the force (A_i = 4 A_F)
    assert predicted_response(0.85, 12.0, f, 2.0, AMPLITUDE, 4.0 * AMPLITUDE) == pytest.approx(g / 4.0, rel=1e-12)


def test_no_settled_motion_at_resonance_below_pi_over_4() -> None:
    with pytest.raises(SteadyStateError, match="no settled motion"):
        FrictionLink(0.5).steady_state(1.0)


def test_model_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match="fbar"):
        FrictionLink(-0.1)
    with pytest.raises(ValueError, match="damping_ratio"):
        FrictionLink(0.5, math.nan)
    with pytest.raises(ValueError, match="ratio"):
        FrictionLink(0.5).steady_state(0.0)


# ------------------------------------------------------------------------------------ the calibration table


def test_shipped_calibration_matches_a_fresh_computation() -> None:
    table = load_calibration()
    assert table.parameters["steps_per_period"] == STEPS_PER_PERIOD
    assert table.software and table.software != "unknown"
    assert tuple(table.fbar) == DEFAULT_FBAR_GRID and tuple(table.offset) == DEFAULT_OFFSET_GRID
    assert table.fbar[0] > math.pi / 4 and table.fbar[-1] == 0.99
    lo, hi = table.offset_range
    assert lo <= 0.125 and hi >= 8.0  # 6 decade ticks either side of any f_-90
    for i in (0, 20, len(table.fbar) - 1):
        fbar = float(table.fbar[i])
        r90 = crossing_ratio(fbar)
        assert table.r90[i] == pytest.approx(r90, rel=1e-10)
        link = FrictionLink(fbar)
        assert link.steady_state(r90).phase_deg == pytest.approx(-90.0, abs=1e-7)
        for j in (0, 45, len(table.offset) - 1):
            fresh = link.steady_state(float(table.offset[j]) * r90).phase_deg
            assert table.phase_deg[i, j] == pytest.approx(fresh, abs=1e-7)


@pytest.mark.parametrize("fbar,offset", [(0.7975, 1.5), (0.8625, 0.5), (0.9137, 1.07), (0.9612, 2.3),
                                         (0.9888, 0.2)])
def test_calibration_interpolates_between_nodes(fbar: float, offset: float) -> None:
    table = load_calibration()
    r90 = crossing_ratio(fbar)
    assert table.crossing_ratio(fbar) == pytest.approx(r90, rel=2e-4)
    direct = FrictionLink(fbar).steady_state(offset * r90).phase_deg
    assert table.phase(fbar, offset) == pytest.approx(direct, abs=0.05)


def test_calibrate_command_reproduces_a_direct_computation(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    fbar, offsets = (0.8, 0.86, 0.93, 0.97), (0.3, 0.9, 1.04, 3.0)
    direct = compute_calibration(fbar, offsets)
    monkeypatch.setattr(calibration, "DEFAULT_FBAR_GRID", fbar)
    monkeypatch.setattr(calibration, "DEFAULT_OFFSET_GRID", offsets)
    out = tmp_path / "cal.json"
    assert main(["calibrate", "--out", str(out), "--jobs", "1"]) == 0
    assert str(out) in capsys.readouterr().out
    assert out.read_text() == direct.to_text()
    loaded = load_calibration(out)
    assert np.array_equal(loaded.r90, direct.r90)
    assert np.max(np.abs(loaded.phase_deg - direct.phase_deg)) <= 5e-10
    data = json.loads(out.read_text())
    assert data["format"] == calibration.FORMAT_NAME and data["version"] == calibration.FORMAT_VERSION
    data["version"] = 99
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(CalibrationError, match=r"bad\.json.*version 99"):
        load_calibration(bad)
    bad.write_text(out.read_text()[:200])  # cut short, as by a crash mid-write
    with pytest.raises(CalibrationError, match=r"bad\.json: line \d+: calibration file is not valid JSON"):
        load_calibration(bad)
    with pytest.raises(CalibrationError, match=r"missing\.json: calibration file not found \(run bodebench "):
        load_calibration(tmp_path / "missing.json")


# ----------------------------------------------------------------------------------------- the procedure


def test_procedure_recovers_the_papers_validation_link(pool: Executor) -> None:
    """Fbar 0.8, f_n 5 Hz (m = 1.0132e-3, K_p = 1): the 2017 paper's synthetic case."""
    response = measured(pool, 0.8, 5.0, "paper")
    result = paper_procedure(measured_curve(response), STIFFNESS, AMPLITUDE)
    assert result.applicable, result.reason
    assert result.mass == pytest.approx(1.0132e-3, rel=0.02)
    assert result.friction == pytest.approx(0.8 * AMPLITUDE, rel=0.02)
    (fa, pa), (fb, pb) = result.bracket
    assert fa < result.f90_hz < fb and pa > -90.0 >= pb
    assert result.f90_hz == pytest.approx(crossing_ratio(0.8) * 5.0, rel=0.01)
    below, above = tick_frequencies(result.f90_hz)
    assert [r.frequency_hz for r in result.readings] == below + above
    read = [r.fbar for r in result.readings if r.fbar is not None]
    assert len(read) >= 5 and result.fbar_mean == pytest.approx(np.mean(read))
    assert result.fbar == result.fbar_right_mean  # four readings above f_-90: the right-hand mean is chosen
    assert result.f_n_hz == pytest.approx(result.f90_hz / result.r90)
    assert result.df_hz == pytest.approx(result.f_n_hz - result.f90_hz)
    assert result.mass == pytest.approx(STIFFNESS / (4.0 * math.pi ** 2 * result.f_n_hz ** 2))


@pytest.mark.parametrize("fbar,f_n,grid,why", [(0.3, 5.0, "ticks", "does not settle"),
                                               (0.3, 12.0, "arbitrary", "jumps"),
                                               (0.6, 5.0, "arbitrary", "jumps")])
def test_procedure_refuses_weak_friction(pool: Executor, fbar: float, f_n: float, grid: str, why: str) -> None:
    response = measured(pool, fbar, f_n, grid)
    result = paper_procedure(measured_curve(response), STIFFNESS, AMPLITUDE)
    assert not result.applicable
    assert result.reason.startswith(NO_CROSSING) and why in result.reason
    assert result.fbar is None and result.f_n_hz is None and result.mass is None and result.friction is None


def test_procedure_says_so_when_the_phase_never_reaches_minus_90(pool: Executor) -> None:
    response = measured(pool, 0.85, 12.0, "ticks")
    low = FrequencyResponse([p for p in response.points if p.frequency_hz < 5.0], response.config, response.case)
    result = paper_procedure(measured_curve(low), STIFFNESS, AMPLITUDE)
    assert not result.applicable and result.reason.startswith(NO_CROSSING) and "stays above" in result.reason


# ----------------------------------------------------------------------------------------------- the fit


@pytest.mark.parametrize("fbar,f_n,grid", [(0.3, 5.0, "ticks"), (0.85, 12.0, "ticks"), (0.95, 5.0, "arbitrary"),
                                           (0.3, 12.0, "arbitrary"), (0.8, 5.0, "paper")])
def test_fit_recovers_known_links(pool: Executor, fbar: float, f_n: float, grid: str) -> None:
    response = measured(pool, fbar, f_n, grid)
    curve = measured_curve(response)
    fit = fit_link(curve, STIFFNESS, AMPLITUDE)
    assert fit.applicable and fit.converged
    assert fit.friction == pytest.approx(fbar * AMPLITUDE, rel=0.02)
    assert fit.mass == pytest.approx(mass_of(f_n), rel=0.02)
    assert fit.f_n_hz == pytest.approx(f_n, rel=0.01)
    assert fit.points == len(curve) == len(response.points) - len(curve.excluded)
    assert all(e.status == "capped" for e in curve.excluded)


def test_fit_frees_stiffness_and_damping(pool: Executor) -> None:
    """K_p = 2 told as 1.6, with a viscous term zeta = 0.05 the papers' model lacks."""
    fbar, f_n, k, zeta = 0.5, 8.0, 2.0, 0.05
    curve = measured_curve(measured(pool, fbar, f_n, "arbitrary", stiffness=k, zeta=zeta))
    fit = fit_link(curve, 1.6, AMPLITUDE, fit_stiffness=True, fit_damping=True)
    assert fit.stiffness == pytest.approx(k, rel=0.02)
    assert fit.damping_ratio == pytest.approx(zeta, rel=0.05)
    assert fit.fbar == pytest.approx(fbar, rel=0.02)
    assert fit.mass == pytest.approx(mass_of(f_n, k), rel=0.02)
    for value, ci in ((fit.stiffness, fit.stiffness_ci), (fit.damping_ratio, fit.damping_ratio_ci)):
        assert ci is not None and 0.0 < ci < 0.01 * value


def noisy(response: FrequencyResponse, relative_sigma: float, seed: int) -> FrequencyResponse:
    """Each converged point's p and q perturbed by N(0, sigma), sigma = relative_sigma |p + jq|, its 95 % disc and
    one-direction half-width set to match (capped points left alone)."""
    rng = np.random.default_rng(seed)
    out = []
    for p in response.points:
        if p.converged:
            sigma = relative_sigma * p.magnitude
            dp, dq = rng.normal(0.0, sigma, 2)
            p = dataclasses.replace(p, p=p.p + dp, q=p.q + dq, uncertainty=DISC_PER_SIGMA * sigma,
                                    uncertainty_1d=LINE_PER_SIGMA * sigma)
        out.append(p)
    return FrequencyResponse(out, response.config, response.case)


@pytest.mark.slow
def test_noise_widens_the_intervals_and_they_cover_the_truth(pool: Executor) -> None:
    fbar, f_n, relative_sigma, seeds = 0.85, 12.0, 0.01, range(8)
    response = measured(pool, fbar, f_n, "arbitrary")
    clean = fit_link(measured_curve(response), STIFFNESS, AMPLITUDE)
    fits = [fit_link(measured_curve(noisy(response, relative_sigma, s)), STIFFNESS, AMPLITUDE) for s in seeds]
    for fit in fits:
        assert fit.fbar_ci > 20.0 * clean.fbar_ci and fit.f_n_ci_hz > 20.0 * clean.f_n_ci_hz
        assert 0.5 < fit.residual_rms < 1.5  # weights match the noise
    covered_fbar = sum(abs(fit.fbar - fbar) <= fit.fbar_ci for fit in fits)
    covered_fn = sum(abs(fit.f_n_hz - f_n) <= fit.f_n_ci_hz for fit in fits)
    covered_mass = sum(abs(fit.mass - mass_of(f_n)) <= fit.mass_ci for fit in fits)
    assert covered_fbar >= 6 and covered_fn >= 6 and covered_mass >= 6  # 95 % intervals, 8 trials
    # the intervals' width agrees with the scatter of the estimates (t quantile with many degrees of freedom)
    spread = np.std([fit.fbar for fit in fits], ddof=1)
    claimed = np.mean([fit.fbar_ci for fit in fits]) / 1.96
    assert 0.4 < spread / claimed < 2.5


# ------------------------------------------------------------------------------------- inputs and the command


def test_link_parameters_prefer_options_and_name_what_is_missing(pool: Executor) -> None:
    response = measured(pool, 0.85, 12.0, "ticks")
    assert link_parameters(response) == (STIFFNESS, "sidecar", AMPLITUDE, "sidecar")
    assert link_parameters(response, 3.0, 0.5) == (3.0, "option", 0.5, "option")
    bare = FrequencyResponse(response.points, {}, "bench")
    with pytest.raises(IdentificationError, match="--stiffness"):
        link_parameters(bare)
    assert link_parameters(bare, 2.0) == (2.0, "option", AMPLITUDE, "points")
    with pytest.raises(IdentificationError, match="--stiffness must be"):
        link_parameters(response, -1.0)


def test_measured_curve_refuses_mixed_amplitudes_and_missing_harmonics() -> None:
    points = [ResponsePoint(f, 1, "position", a, -0.1, -0.1, 10, True, "converged")
              for f, a in ((1.0, 1.0), (2.0, 2.0))]
    with pytest.raises(IdentificationError, match="different input amplitudes"):
        measured_curve(FrequencyResponse(points))
    with pytest.raises(IdentificationError, match="harmonic 3 not in the response"):
        measured_curve(FrequencyResponse(points[:1]), harmonic=3)


def test_identify_command_json(pool: Executor, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    response = measured(pool, 0.3, 12.0, "arbitrary")
    save_response(response, tmp_path)
    assert main(["identify", str(tmp_path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    for method in ("procedure", "fit"):
        assert {"fbar", "friction", "f_n_hz", "mass"} <= set(report["methods"][method])
    procedure, fit = report["methods"]["procedure"], report["methods"]["fit"]
    assert procedure["fbar"] is None and procedure["mass"] is None and procedure["reason"].startswith(NO_CROSSING)
    assert fit["friction"] == pytest.approx(0.3 * AMPLITUDE, rel=0.02)
    assert fit["mass"] == pytest.approx(mass_of(12.0), rel=0.02)
    assert report["reference"]["fbar"] == pytest.approx(0.3)
    assert (tmp_path / "identify.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "<svg" in (tmp_path / "identify.svg").read_text()


def test_identify_command_text(pool: Executor, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    save_response(measured(pool, 0.8, 5.0, "paper"), tmp_path)
    assert main(["identify", str(tmp_path), "--no-plot"]) == 0
    text = capsys.readouterr().out
    assert "paper procedure" in text and "fit (95 % CI)" in text and "f_-90 =" in text
    assert not (tmp_path / "identify.png").exists()


def test_identify_command_on_bad_directories(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["identify", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "response.json" in err
    point = ResponsePoint(1.0, 1, "position", 1.0, -0.1, -0.1, 10, True, "converged")
    save_response(FrequencyResponse([point], {}, "bench"), tmp_path)
    (tmp_path / "response.csv").write_text("frequency_hz,harmonic\n1,oops\n")
    assert main(["identify", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "response.csv" in err
    save_response(FrequencyResponse([point], {}, "bench"), tmp_path)
    assert main(["identify", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--stiffness" in err
