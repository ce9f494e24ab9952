"""The ``bodebench simulate`` command, end to end through the installed entry point."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bodebench.apps.cli import main
from bodebench.io.results import load_response
from bodebench.sim.plants import LinearOscillator

CONFIG = """
title = "two dampings"
[plant]
model = "linear"
mass = 1e-3
stiffness = 1.0
[excitation]
amplitude = 0.5
frequencies_hz = [1.0, 5.0, 20.0]
[analysis]
harmonics = [1, 3]
[cases.light.plant]
damping_ratio = 0.05
[cases.heavy.plant]
damping_ratio = 0.7
"""


def bodebench(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("bodebench")
    cmd = [exe] if exe else [sys.executable, "-m", "bodebench"]
    return subprocess.run(cmd + list(args), cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_simulate_writes_one_directory_per_case(tmp_path: Path) -> None:
    cfg = tmp_path / "cases.toml"
    cfg.write_text(CONFIG)
    proc = bodebench("simulate", str(cfg), "--out", str(tmp_path / "out"), "--jobs", "2", "--plots", "png,svg",
                     cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    for case, zeta in (("light", 0.05), ("heavy", 0.7)):
        d = tmp_path / "out" / case
        with open(d / "response.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        assert {"frequency_hz", "harmonic", "gain", "gain_db", "phase_deg", "periods", "converged"} <= set(rows[0])
        assert len(rows) == 6
        sidecar = json.loads((d / "response.json").read_text())
        assert sidecar["config"]["plant"]["damping_ratio"] == zeta
        for stem in ("bode", "periods"):
            assert (d / f"{stem}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
            assert "<svg" in (d / f"{stem}.svg").read_text()
        response = load_response(d)
        first = response.select(harmonic=1)
        exact = LinearOscillator(1e-3, 1.0, zeta).frequency_response(first.frequency_hz)[:, 0]
        assert np.allclose(first.gain, np.abs(exact), rtol=2e-4)
        # a linear plant has no third harmonic: below resolution, no phase
        third = response.select(harmonic=3)
        assert all(p.status == "below_resolution" for p in third.points)
        assert np.all(np.isnan(third.phase_deg))


@pytest.mark.parametrize("edit, bad, key", [
    ("mass = 1e-3", "mass = -1.0", "plant.mass"),
    ("amplitude = 0.5", 'amplitude = "big"', "excitation.amplitude"),
    ("harmonics = [1, 3]", "harmonics = [1, 0]", "analysis.harmonics"),
])
def test_bad_config_gives_one_line_naming_file_and_key(tmp_path: Path, capsys, edit: str, bad: str,
                                                       key: str) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text(CONFIG.replace(edit, bad))
    status = main(["simulate", str(cfg), "--out", str(tmp_path / "out"), "--jobs", "1"])
    err = capsys.readouterr().err.strip()
    assert status == 2
    assert len(err.splitlines()) == 1
    assert "bad.toml" in err and key in err
    assert not (tmp_path / "out").exists()


def test_unknown_key_is_an_error(tmp_path: Path, capsys) -> None:
    cfg = tmp_path / "typo.toml"
    cfg.write_text(CONFIG.replace("[analysis]", "[analysis]\ntolerance = 0.1"))
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "typo.toml" in err and "analysis.tolerance" in err and "Traceback" not in err


def test_missing_config_file(tmp_path: Path, capsys) -> None:
    assert main(["simulate", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "nope.toml" in capsys.readouterr().err
