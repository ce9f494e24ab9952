"""Results that cannot be edited without notice: every row of response.csv and every samples file has its SHA-256 in
the sidecar, recorded as it was written. Each kind of edit is named by ``--resume`` (which refuses it unless told)
and by ``analyse``."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bodebench.bench.procedure import SweepProcedure, previous_run
from bodebench.io.config import parse_config
from bodebench.io.results import CHECKSUMS, CSV_NAME, SIDECAR_NAME, ResultsError, load_response, verify_results
from bodebench.io.samples import load_samples, samples_path

DATA = {"plant": {"model": "lag", "time_constant": 0.05, "gain": 1.0},
        "excitation": {"amplitude": 1.0, "frequencies_hz": [1.0, 3.0, 9.0]},
        "analysis": {"tolerance_percent": 0.1, "harmonics": [1, 2]}}


@pytest.fixture()
def measured(tmp_path: Path) -> Path:
    SweepProcedure(parse_config(DATA, "x.toml"), tmp_path / "out", keep_samples=True).run()
    return tmp_path / "out"


def rows(directory: Path) -> tuple[list[str], int]:
    lines = (directory / CSV_NAME).read_text().splitlines(keepends=True)
    return lines, next(i for i, line in enumerate(lines) if not line.startswith("#"))


def scale_row(directory: Path, index: int, factor: float) -> None:
    """Row ``index`` rewritten with p, q and their intervals scaled, every column consistent with them (the edit a
    careful hand makes: the loader's own checks cannot see it)."""
    from bodebench.io.results import _point_row, style_of_config

    response = load_response(directory)
    p = response.points[index]
    edited = dataclasses.replace(p, p=factor * p.p, q=factor * p.q, uncertainty=factor * p.uncertainty,
                                 uncertainty_1d=factor * p.uncertainty_1d)
    lines, header = rows(directory)
    lines[header + 1 + index] = _point_row(edited, style_of_config(response.config)) + "\n"
    (directory / CSV_NAME).write_text("".join(lines))


def problems(directory: Path) -> list[str]:
    checked, found = verify_results(directory)
    assert checked
    return found


def test_an_untouched_directory_verifies_and_resumes(measured: Path) -> None:
    assert problems(measured) == []
    assert previous_run(measured, parse_config(DATA, "x.toml").cases[0], "resume") is not None


@pytest.mark.parametrize("edit, expected", [
    (lambda d: scale_row(d, 2, 1.1), ["response.csv line {h3} (3.0 1 position): changed since it was written"]),
    (lambda d: (lambda lines, h: (d / CSV_NAME).write_text("".join(lines[:h + 2] + lines[h + 3:])))(*rows(d)),
     "deleted"),
    (lambda d: (lambda lines, h: (d / CSV_NAME).write_text("".join(lines[:h + 2] + [lines[h + 1]] + lines[h + 2:])))(
        *rows(d)), "added"),
])
def test_an_edited_row_is_named_and_the_resume_refused_unless_told(measured: Path, edit, expected) -> None:  # type: ignore[no-untyped-def]
    case = parse_config(DATA, "x.toml").cases[0]
    _, header = rows(measured)
    edit(measured)
    found = problems(measured)
    assert found, "the edit went unnoticed"
    if isinstance(expected, list):
        assert found == [e.format(h3=header + 4) for e in expected]
    else:
        assert any(expected in line or "changed since" in line for line in found), found
    with pytest.raises(ResultsError) as refused:
        previous_run(measured, case, "resume")
    assert "changed since it was written" in str(refused.value) and "--accept-changes" in str(refused.value)
    assert previous_run(measured, case, "resume_changed") is not None


@pytest.mark.parametrize("how", ["scaled", "truncated", "deleted"])
def test_an_edited_samples_file_is_named(measured: Path, how: str) -> None:
    path = samples_path(measured, 3.0)
    if how == "scaled":
        record = load_samples(path)
        record.batches = [(t, 2 * y) for t, y in record.batches]
        record.save(measured)
    elif how == "truncated":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    else:
        path.unlink()
    word = "gone" if how == "deleted" else "changed"
    assert problems(measured) == [f"samples/3.0Hz.npz: {word} since it was written"]


def test_a_directory_without_checksums_loads_and_resumes_unverified(measured: Path) -> None:
    sidecar = json.loads((measured / SIDECAR_NAME).read_text())
    del sidecar[CHECKSUMS]
    (measured / SIDECAR_NAME).write_text(json.dumps(sidecar))
    assert verify_results(measured) == (False, [])
    assert len(load_response(measured)) == 6
    assert previous_run(measured, parse_config(DATA, "x.toml").cases[0], "resume") is not None


def test_rows_a_stopped_run_wrote_after_its_last_checksum_are_no_problem(measured: Path) -> None:
    """The writer appends a frequency's rows, then records their checksums: a stop between the two leaves that one
    frequency's rows unrecorded at the end, which is what resume exists for."""
    sidecar = json.loads((measured / SIDECAR_NAME).read_text())
    sidecar[CHECKSUMS]["rows"] = sidecar[CHECKSUMS]["rows"][:4]  # the last frequency's two rows unrecorded
    (measured / SIDECAR_NAME).write_text(json.dumps(sidecar))
    assert problems(measured) == []


def test_analyse_names_what_changed(measured: Path) -> None:
    scale_row(measured, 2, 1.1)
    record = load_samples(samples_path(measured, 9.0))
    record.batches = [(t, y + np.float64(1e-3)) for t, y in record.batches]
    record.save(measured)
    done = subprocess.run([sys.executable, "-m", "bodebench", "analyse", str(measured), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "(3.0 1 position): changed since it was written" in done.stdout
    assert "samples/9.0Hz.npz: changed since it was written" in done.stdout
    assert "  3 Hz harmonic 1 position: stored" in done.stdout  # and the point its samples do not give again
