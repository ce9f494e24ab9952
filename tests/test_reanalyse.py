"""Raw samples kept next to the results, and ``bodebench analyse`` recomputing a sweep from them: bit for bit the
live result with the same settings, on an offline sweep and on a simulated bench sweep; with a looser tolerance,
bit for bit what a live sweep at that tolerance measures (its record is a prefix of the stricter one's)."""

from __future__ import annotations

import math
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bodebench.analysis.reanalyse import reanalyse
from bodebench.bench.procedure import SweepProcedure
from bodebench.io.config import ConfigError, parse_config
from bodebench.io.results import CSV_NAME, load_response, save_response
from bodebench.io.samples import SamplesError, load_samples, samples_path

TAU, GAIN, AMPLITUDE = 0.02, 2.0, 0.01
FREQS = [1.0, 4.0, 8.0, 25.0]


def offline(tolerance: float = 0.01, **analysis: Any) -> dict[str, Any]:
    return {
        "plant": {"model": "lag", "time_constant": TAU, "gain": GAIN},
        "excitation": {"amplitude": AMPLITUDE, "frequencies_hz": FREQS},
        "analysis": {"tolerance_percent": tolerance, "harmonics": [1, 2]} | analysis,
    }


def on_bench(channel: str) -> dict[str, Any]:
    return {**offline(0.5, harmonics=[1]), "excitation": {"amplitude": AMPLITUDE, "frequencies_hz": FREQS[:2]},
            "bench": {"transport": "can", "rate_hz": 1000.0, "clock": "lockstep",
                                       "output_channels": ["position"], "reference_channel": "setpoint_echo"},
            "can": {"interface": "virtual", "channel": channel}, "safety": {"max_amplitude": 0.02, "watchdog_s": 5.0},
            "simulator": {"jitter": 0.05, "noise": 1e-6, "seed": 7}}


def sweep(data: dict[str, Any], out: Path, **kwargs: Any) -> None:
    SweepProcedure(parse_config(data, "x.toml"), out, **kwargs).run()


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bodebench", *args], capture_output=True, text=True, timeout=600)


def test_the_samples_file_holds_the_lags_exact_response(tmp_path: Path) -> None:
    sweep(offline(), tmp_path)
    for f in FREQS:
        record = load_samples(samples_path(tmp_path, f))
        assert (record.source, record.frequency_hz, record.amplitude, record.channels) == (
            "offline", f, AMPLITUDE, ("position",))
        t, y = record.t, record.y[:, 0]
        assert np.all(np.diff(t) > 0) and sum(len(b[0]) for b in record.batches) == t.size
        # T y' + y = K A sin(w t) from rest: the steady sine plus the decaying transient
        w = 2 * math.pi * f
        steady = GAIN * AMPLITUDE / (1 + (w * TAU) ** 2) * (np.sin(w * t) - w * TAU * np.cos(w * t))
        exact = steady + GAIN * AMPLITUDE * w * TAU / (1 + (w * TAU) ** 2) * np.exp(-t / TAU)
        assert np.max(np.abs(y - exact)) <= 1e-12 * GAIN * AMPLITUDE
        periods = {p.periods for p in load_response(tmp_path).points if p.frequency_hz == f}
        assert t[-1] * f >= max(periods)  # the record covers every period the rule used


@pytest.mark.parametrize("settle", [0, 7])
def test_an_offline_sweep_analysed_again_is_bit_identical(tmp_path: Path, settle: int) -> None:
    """Also with settle periods: the record starts at rest, its period 1 where the live sampler's did."""
    data = offline()
    if settle:
        data["excitation"] = {**data["excitation"], "settle_periods": settle}
    sweep(data, tmp_path / "live")
    done = cli("analyse", str(tmp_path / "live"), "--out", str(tmp_path / "again"), "--quiet")
    assert done.returncode == 0, done.stderr
    assert f"{2 * len(FREQS)} identical to the stored points" in done.stdout
    assert (tmp_path / "again" / CSV_NAME).read_bytes() == (tmp_path / "live" / CSV_NAME).read_bytes()


def test_a_looser_tolerance_gives_what_a_live_sweep_at_it_measures(tmp_path: Path) -> None:
    sweep(offline(0.01), tmp_path / "strict")
    sweep(offline(0.5), tmp_path / "loose")
    again = reanalyse(tmp_path / "strict", tolerance_percent=0.5)
    assert not again.record_ended
    save_response(again.response, tmp_path / "again")
    assert (tmp_path / "again" / CSV_NAME).read_bytes() == (tmp_path / "loose" / CSV_NAME).read_bytes()
    assert again.response.config == load_response(tmp_path / "loose").config
    # a rule that wants more than the record holds is capped where it ends
    fixed = reanalyse(tmp_path / "loose", criterion="fixed", settle_periods=5000, average_periods=50)
    assert set(fixed.record_ended) == set(FREQS)
    assert {p.status for p in fixed.response} == {"capped"}


@pytest.mark.slow
def test_a_simulated_bench_sweep_analysed_again_is_bit_identical(tmp_path: Path) -> None:
    sweep(on_bench(f"reanalyse-{uuid.uuid4().hex[:8]}"), tmp_path / "live")
    record = load_samples(samples_path(tmp_path / "live", FREQS[0]))
    assert record.source == "bench" and record.reference == "setpoint_echo" and record.y.shape[1] == 2
    assert record.t[0] <= record.t0 < record.t[1]  # the sample before the first period edge is kept
    done = cli("analyse", str(tmp_path / "live"), "--out", str(tmp_path / "again"))
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "again" / CSV_NAME).read_bytes() == (tmp_path / "live" / CSV_NAME).read_bytes()
    other = cli("analyse", str(tmp_path / "live"), "--criterion", "full", "--tolerance", "1")
    assert other.returncode == 0, other.stderr
    assert "criterion full, tolerance 1 %" in other.stdout
    # the bench's delays taken off: every phase turned forward by k w (h / 2 + d), the gain as measured
    delay = 0.0015
    done = cli("analyse", str(tmp_path / "live"), "--without-chain", "--delay", str(delay), "--delay-uncertainty",
               "1e-4", "--out", str(tmp_path / "unchained"), "--plots", "none")
    assert done.returncode == 0, done.stderr
    assert "taken off every phase" in done.stdout
    measured = {(p.frequency_hz, p.harmonic): p for p in load_response(tmp_path / "live").points}
    for p in load_response(tmp_path / "unchained").points:
        q = measured[(p.frequency_hz, p.harmonic)]
        turn = 360.0 * p.harmonic * p.frequency_hz * (0.5 / 1000.0 + delay)
        assert p.gain_db == pytest.approx(q.gain_db, abs=1e-12)
        assert (p.phase_deg - q.phase_deg - turn + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-9)
        assert p.uncertainty > q.uncertainty  # the delay's uncertainty widens it
    wrong = cli("analyse", str(tmp_path / "live"), "--delay", "0.001")
    assert wrong.returncode == 2 and len(wrong.stderr.splitlines()) == 1 and "--without-chain" in wrong.stderr


def test_bad_input_is_one_line(tmp_path: Path) -> None:
    sweep(offline(0.5), tmp_path / "live")
    done = cli("analyse", str(tmp_path / "live"), "--criterion", "nope")
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1
    assert "response.json: analysis.criterion: must be one of" in done.stderr
    with pytest.raises(ConfigError):
        reanalyse(tmp_path / "live", tolerance_percent=-1.0)
    samples_path(tmp_path / "live", FREQS[1]).unlink()
    with pytest.raises(SamplesError, match="no such samples file"):
        reanalyse(tmp_path / "live")
    done = cli("analyse", str(tmp_path / "live"))
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1 and "4.0Hz.npz" in done.stderr
    samples_path(tmp_path / "live", FREQS[0]).write_bytes(b"not a zip")
    with pytest.raises(SamplesError, match="not a samples file"):
        load_samples(samples_path(tmp_path / "live", FREQS[0]))
    done = cli("analyse", str(tmp_path / "live"), "--out", str(tmp_path / "live"))
    assert done.returncode == 2 and "results already here" in done.stderr
    sweep(offline(0.5), tmp_path / "none", keep_samples=False)
    assert not (tmp_path / "none" / "samples").exists()
    offline_sweep = cli("identify", str(tmp_path / "none"), "--without-chain", "--no-plot")
    assert offline_sweep.returncode == 2 and len(offline_sweep.stderr.splitlines()) == 1
    assert "not a bench sweep" in offline_sweep.stderr


def test_analyse_names_every_stored_point_that_its_samples_do_not_give_again(tmp_path: Path) -> None:
    """One row's p and q scaled by 1.1 (+0.83 dB) in response.csv: analyse names that point, with by how much, and
    counts the others identical."""
    import dataclasses


    sweep(offline(), tmp_path / "live")
    stored = load_response(tmp_path / "live")
    edited = stored.points[3]
    stored.points[3] = dataclasses.replace(edited, p=1.1 * edited.p, q=1.1 * edited.q,
                                           uncertainty=1.1 * edited.uncertainty,
                                           uncertainty_1d=1.1 * edited.uncertainty_1d)
    save_response(stored, tmp_path / "live")  # every column consistent: only the samples can tell
    target = (edited.frequency_hz, edited.harmonic)
    done = cli("analyse", str(tmp_path / "live"), "--quiet")
    assert done.returncode == 0, done.stderr
    assert f"{2 * len(FREQS) - 1} identical to the stored points, 1 not:" in done.stdout
    named = [line for line in done.stdout.splitlines() if line.startswith("  ")]
    assert len(named) == 1 and named[0].startswith(f"  {target[0]:g} Hz harmonic {target[1]} position:"), named
    change = float(named[0].rsplit("= ", 1)[1].rstrip(")"))
    assert change == pytest.approx(0.1 / 1.1, rel=1e-3)  # printed to 3 digits


def test_the_setpoint_ratios_are_kept_and_a_bad_one_is_named(tmp_path: Path) -> None:
    from bodebench.io.samples import PointSamples

    record = PointSamples(4.0, AMPLITUDE, ("position",), 0.25)
    record.add(np.linspace(0.2, 1.3, 12), np.arange(12.0))
    record.setpoint_ratios = np.array([1.002 - 0.003j, 1.0015 - 0.002j, 1.001 - 0.0025j])
    path = record.save(tmp_path)
    again = load_samples(path)
    assert again.setpoint_ratios.tolist() == record.setpoint_ratios.tolist()
    assert load_samples(PointSamples(4.0, AMPLITUDE, ("position",)).save(tmp_path / "none")).setpoint_ratios.size == 0
    with np.load(path) as data:
        arrays = {name: data[name] for name in data.files}
    np.savez(path, **{**arrays, "setpoint_ratios": np.ones((2, 2))})
    with pytest.raises(SamplesError, match=r"4\.0Hz\.npz: setpoint_ratios float64 \(2, 2\): not a complex vector"):
        load_samples(path)
