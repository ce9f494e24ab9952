"""The Python interface: sweeps from a path or a dict, results loaded back, and the exporters checked against
python-control's own evaluation, scipy.io.loadmat and the exact transfer function of a linear plant."""

from __future__ import annotations

import math
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

import control
import numpy as np
import pandas
import pytest
import scipy.io

import bodebench
from bodebench.io.config import ConfigError
from bodebench.io.results import ResultsError
from bodebench.sim.plants import LinearOscillator

ROOT = Path(__file__).resolve().parents[1]
MASS, STIFFNESS, ZETA, AMPLITUDE = 1 / (2 * math.pi * 5) ** 2, 1.0, 0.1, 0.01
FREQS = [1.0, 3.0, 4.5, 5.0, 5.5, 8.0, 20.0]


def offline(**analysis: Any) -> dict[str, Any]:
    return {
        "plant": {"model": "linear", "mass": MASS, "stiffness": STIFFNESS, "damping_ratio": ZETA},
        "excitation": {"amplitude": AMPLITUDE, "frequencies_hz": FREQS},
        "analysis": {"tolerance_percent": 0.01, **analysis},
    }


@pytest.fixture(scope="module")
def response() -> bodebench.Response:
    return bodebench.simulate(offline(harmonics=[1, 2]))


def exact(frequency_hz: np.ndarray) -> np.ndarray:
    return LinearOscillator(MASS, STIFFNESS, ZETA).frequency_response(frequency_hz)[:, 0]


def test_an_offline_sweep_from_a_dict_is_the_exact_response(response: bodebench.Response) -> None:
    first = response.select(harmonic=1)
    assert isinstance(first, bodebench.Response)
    assert list(first.frequency_hz) == FREQS
    g = exact(first.frequency_hz)
    assert np.all(np.abs(first.complex_response() - g) <= 1e-4 * np.abs(g))
    assert all(p.status == "converged" for p in first)


def test_to_frd_agrees_with_python_control(response: bodebench.Response) -> None:
    frd = response.to_frd()
    assert isinstance(frd, control.FrequencyResponseData)
    omega = 2 * np.pi * np.array(FREQS)
    assert np.array_equal(np.asarray(frd.omega), omega)
    evaluated = np.array([complex(frd(1j * w)) for w in omega])
    assert np.array_equal(evaluated, response.select(harmonic=1).complex_response())
    # and python-control's own model of the oscillator agrees with the measured data
    model = control.tf([1.0], [MASS, 2 * ZETA * math.sqrt(MASS * STIFFNESS), STIFFNESS])
    mag, phase, _ = control.frequency_response(model, omega)
    fmag, fphase, _ = frd.frequency_response(omega)
    assert np.allclose(np.asarray(fmag), np.asarray(mag), rtol=1e-4, atol=0)
    assert np.allclose(np.unwrap(np.asarray(fphase)), np.unwrap(np.asarray(phase)), atol=1e-4)
    # each point's interval goes along, in frequency order, and the exact model lies within it
    first = response.select(harmonic=1)
    assert np.array_equal(frd.gain_ci, [p.gain_ci for p in first.points])
    assert np.array_equal(frd.phase_ci_deg, [p.phase_ci_deg for p in first.points])
    exact = np.array([complex(model(1j * w)) for w in omega])
    assert np.all(np.abs(evaluated - exact) <= frd.interval_95 + 1e-12 * np.abs(exact))
    assert list(frd.converged) == [p.converged for p in first.points]
    second = response.to_frd(harmonic=2)
    assert np.array_equal(np.array([complex(second(1j * w)) for w in omega]),
                          response.select(harmonic=2).complex_response())
    with pytest.raises(ValueError, match="no points of harmonic 3"):
        response.to_frd(harmonic=3)


def test_to_mat_round_trips_through_loadmat(response: bodebench.Response, tmp_path: Path) -> None:
    path = response.to_mat(tmp_path / "r.mat")
    data = scipy.io.loadmat(str(path), simplify_cells=True)
    points = response.points
    assert np.array_equal(data["frequency_hz"], [p.frequency_hz for p in points])
    assert np.array_equal(data["harmonic"], [p.harmonic for p in points])
    assert np.array_equal(data["response"], response.complex_response())
    for name in ("gain", "gain_db", "phase_deg", "gain_ci", "gain_db_ci", "phase_ci_deg", "uncertainty", "p", "q",
                 "thd", "coherence", "periods", "periods_needed", "periods_discarded"):
        assert np.array_equal(data[name], [getattr(p, name) for p in points], equal_nan=True), name
    assert list(data["status"]) == [p.status for p in points]
    assert list(data["channel"]) == [p.channel for p in points]
    assert np.array_equal(data["converged"].astype(bool), [p.converged for p in points])
    series = data["series"]["position_h1"]
    assert np.array_equal(series["frequency_hz"], FREQS)
    assert np.array_equal(series["response"], response.select(harmonic=1).complex_response())
    assert sorted(data["series"]) == ["position_h1", "position_h2"]


def test_to_dataframe_has_a_row_per_point(response: bodebench.Response) -> None:
    frame = response.to_dataframe()
    assert isinstance(frame, pandas.DataFrame)
    assert len(frame) == len(response)
    assert list(frame["status"]) == [p.status for p in response]
    assert np.array_equal(frame["gain_db"].to_numpy(), response.gain_db)
    assert np.array_equal(frame["response"].to_numpy(), response.complex_response())


def test_a_missing_exporter_library_is_named(response: bodebench.Response, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "control", None)  # import control now raises ImportError
    with pytest.raises(bodebench.MissingDependency,
                       match=r"to_frd needs the control package: pip install 'bodebench\[export\]'"):
        response.to_frd()
    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(bodebench.MissingDependency, match="pip install pandas"):
        response.to_dataframe()


def test_simulate_writes_what_load_reads_and_refuses_to_overwrite(tmp_path: Path) -> None:
    config = tmp_path / "lag.toml"
    config.write_text('[plant]\nmodel = "lag"\ntime_constant = 0.01\n'
                      '[excitation]\namplitude = 1.0\nfrequencies_hz = [1.0, 16.0, 100.0]\n')
    measured = bodebench.simulate(config, tmp_path / "out", jobs=2)
    loaded = bodebench.load(tmp_path / "out")
    assert isinstance(loaded, bodebench.Response)
    # rows are in the order measured (frequencies ran on two processes), the sweep's points in frequency order
    assert sorted((p.frequency_hz, p.p, p.q) for p in loaded) == [(p.frequency_hz, p.p, p.q) for p in measured]
    w = 2 * np.pi * loaded.frequency_hz
    assert np.allclose(loaded.complex_response(), 1 / (1 + 0.01j * w), rtol=1e-4, atol=0)
    with pytest.raises(ResultsError, match="results already here"):
        bodebench.simulate(config, tmp_path / "out")


def test_bad_arguments_are_one_line_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"<dict>: plant\.mass: must be > 0"):
        bodebench.simulate({**offline(), "plant": {"model": "linear", "mass": -1.0}})
    two = {**offline(), "cases": {"a": {"analysis": {"tolerance_percent": 0.1}}, "b": {}}}
    with pytest.raises(ValueError, match=r"2 cases \(a, b\); choose one with case="):
        bodebench.simulate(two)
    with pytest.raises(ValueError, match="no case 'c'"):
        bodebench.simulate(two, case="c")
    with pytest.raises(ValueError, match="jobs must be an integer >= 1"):
        bodebench.simulate(offline(), jobs=-1)
    with pytest.raises(ConfigError, match="bench: missing"):
        bodebench.run(offline(), tmp_path / "x")
    with pytest.raises(ResultsError, match="response.json"):
        bodebench.load(tmp_path)


@pytest.mark.slow
def test_a_bench_sweep_over_the_virtual_bus_and_in_process_agree(tmp_path: Path) -> None:
    bench = {**offline(), "excitation": {"amplitude": AMPLITUDE, "frequencies_hz": [2.0, 5.0]},
             "bench": {"transport": "can", "rate_hz": 1000.0, "clock": "lockstep"},
             "can": {"interface": "virtual", "channel": f"api-{uuid.uuid4().hex[:8]}"},
             "safety": {"max_amplitude": 0.02}, "simulator": {}}
    wired = bodebench.run(bench, tmp_path / "bus")
    assert [(p.p, p.q) for p in bodebench.load(tmp_path / "bus")] == [(p.p, p.q) for p in wired]
    direct = bodebench.simulate(bench)  # the same drive called without a bus, nothing written
    assert len(direct) == len(wired) == 2
    for a, b in zip(wired, direct, strict=True):
        assert a.frequency_hz == b.frequency_hz and a.status == b.status == "converged"
        assert abs(complex(a.p, a.q) - complex(b.p, b.q)) <= 2e-4 * abs(complex(b.p, b.q))


@pytest.mark.slow
def test_the_example_script_measures_the_exact_response(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, str(ROOT / "examples" / "api_sweep.py"), str(tmp_path)],
                          capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    data = scipy.io.loadmat(str(tmp_path / "api_sweep.mat"), simplify_cells=True)
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        import api_sweep
    finally:
        sys.path.pop(0)
    f = np.asarray(data["frequency_hz"], dtype=float)
    assert list(f) == api_sweep.CONFIG["excitation"]["frequencies_hz"]
    plant = LinearOscillator(api_sweep.MASS, api_sweep.STIFFNESS, api_sweep.ZETA)
    truth = plant.frequency_response(f)[:, 0]
    assert np.all(np.abs(data["response"] - truth) <= 1e-4 * np.abs(truth))
    assert bodebench.load(tmp_path / "sweep").points[0].frequency_hz == f[0]
    assert "python-control: |G(10 Hz)|" in done.stdout


def test_every_exported_name_resolves() -> None:
    assert sorted(bodebench.__all__) == sorted(["__version__", *bodebench._EXPORTS])
    for name in bodebench.__all__:
        assert getattr(bodebench, name) is not None
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        bodebench.nope  # noqa: B018
