"""Crash safety: kill -9 mid-sweep, then ``bodebench run --resume``; results files are never half-written."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest

from bodebench.core.response import FrequencyResponse
from bodebench.io.results import load_response, save_response

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "sim_can.toml"


def command() -> list[str]:
    exe = shutil.which("bodebench")
    return [exe] if exe else [sys.executable, "-m", "bodebench"]


def small_config(tmp_path: Path) -> Path:
    text = CONFIG.read_text().replace("frequencies_hz = [2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 15, 20, 30, 50]",
                                      "frequencies_hz = [5, 6, 8, 10, 12, 15]")
    text = text.replace("harmonics = [1, 3]", "harmonics = [1]")
    # what is resumed does not hang on the rate: half the setpoints of the shipped config
    text = text.replace("rate_hz = 2000", "rate_hz = 1000")
    path = tmp_path / "bench.toml"
    path.write_text(text)
    return path


def measured_rows(directory: Path) -> list[str]:
    return [line for line in (directory / "response.csv").read_text().splitlines() if not line.startswith("#")][1:]


@pytest.mark.slow
def test_kill_9_then_resume_keeps_every_converged_point(tmp_path: Path) -> None:
    cfg = small_config(tmp_path)
    out = tmp_path / "out"
    run = subprocess.Popen(command() + ["run", str(cfg), "--out", str(out), "--quiet"], stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and run.poll() is None:
        if (out / "response.csv").exists() and len(measured_rows(out)) >= 3:
            break
        time.sleep(0.02)
    assert run.poll() is None, "the sweep ended before it could be killed"
    os.killpg(run.pid, signal.SIGKILL)
    run.wait(timeout=30)
    before = measured_rows(out)
    assert len(before) >= 3
    # the files on disk are whole: they load, every row parses, no temporary file is left as the results
    assert len(load_response(out).points) == len(before)

    refused = subprocess.run(command() + ["run", str(cfg), "--out", str(out)], capture_output=True, text=True,
                             timeout=120)
    assert refused.returncode == 2 and "--resume" in refused.stderr and "response.csv" in refused.stderr
    assert measured_rows(out) == before

    resumed = subprocess.run(command() + ["run", str(cfg), "--out", str(out), "--resume", "--quiet"],
                             capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    after = measured_rows(out)
    assert after[: len(before)] == before  # measured points kept unchanged, in place
    response = load_response(out)
    assert sorted(p.frequency_hz for p in response.points) == [5, 6, 8, 10, 12, 15]
    assert all(p.converged for p in response.points)


@pytest.mark.slow
def test_resume_refuses_results_of_another_configuration(tmp_path: Path) -> None:
    cfg = tmp_path / "fast.toml"  # results of three fast frequencies are results as much as any
    cfg.write_text(small_config(tmp_path).read_text().replace("frequencies_hz = [5, 6, 8, 10, 12, 15]",
                                                              "frequencies_hz = [10, 12, 15]"))
    out = tmp_path / "out"
    other = tmp_path / "other.toml"
    other.write_text(cfg.read_text().replace("friction = 0.008", "friction = 0.009"))
    first = subprocess.run(command() + ["run", str(other), "--out", str(out), "--quiet"], capture_output=True,
                           text=True, timeout=300)
    assert first.returncode == 0, first.stderr
    proc = subprocess.run(command() + ["run", str(cfg), "--out", str(out), "--resume"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    assert "response.json" in proc.stderr and "plant" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize("damage", ["truncate", "garbage", "sidecar"])
def test_corrupt_results_directory_gives_one_line(tmp_path: Path, damage: str) -> None:
    cfg = small_config(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    response = FrequencyResponse(config={}, case="x")
    save_response(response, out)
    csv = out / "response.csv"
    header = next(line for line in csv.read_text().splitlines() if not line.startswith("#"))
    if damage == "truncate":
        csv.write_text(header + "\n3.0,1,position,0.01,0.7")
    elif damage == "garbage":
        csv.write_bytes(b"\x00\xff not a csv \n")
    else:
        (out / "response.json").write_text("{ half")
    proc = subprocess.run(command() + ["run", str(cfg), "--out", str(out), "--resume"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert ("response.json" if damage == "sidecar" else "response.csv") in lines[0]


def offline_text() -> str:
    """An offline experiment: the plant, excitation and analysis of the serial bench, without the bench."""
    from test_cli_bench import SERIAL_BENCH

    return SERIAL_BENCH.split("[bench]")[0].format(freqs="[3, 5, 8, 12]")


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["offline", "bench"])
def test_simulate_refuses_to_overwrite_and_resumes(tmp_path: Path, kind: str) -> None:
    """``bodebench simulate`` of an offline experiment and of a bench config's drive: finished results are not
    overwritten; an interrupted sweep (here: the last points gone from its files) is continued with --resume."""
    if kind == "offline":
        cfg = tmp_path / "offline.toml"
        cfg.write_text(offline_text())
    else:
        cfg = small_config(tmp_path)
    out = tmp_path / "out"
    first = subprocess.run(command() + ["simulate", str(cfg), "--out", str(out), "--quiet", "--jobs", "1"],
                           capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr
    finished = measured_rows(out)
    again = subprocess.run(command() + ["simulate", str(cfg), "--out", str(out), "--quiet", "--jobs", "1"],
                           capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and "--resume" in again.stderr and "Traceback" not in again.stderr
    assert measured_rows(out) == finished
    whole = load_response(out)
    kept = sorted(whole.points, key=lambda p: p.frequency_hz)[:2]  # what an interrupted sweep had saved
    save_response(FrequencyResponse(kept, config=whole.config, case=whole.case), out)
    quiet = ["--quiet"] if kind == "offline" else []  # the bench's progress counts what was on disk
    resumed = subprocess.run(command() + ["simulate", str(cfg), "--out", str(out), *quiet, "--jobs", "1",
                                          "--resume"], capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    if kind == "bench":
        series = len({(p.channel, p.harmonic) for p in whole.points})
        on_disk = sum(1 for f in {p.frequency_hz for p in kept}
                      if sum(1 for p in kept if p.frequency_hz == f) == series)
        total = len({p.frequency_hz for p in whole.points})
        lines = resumed.stderr.splitlines()
        started = next(line for line in lines if f"{total} points on" in line)
        assert f"{on_disk} already measured" in started, started
        counts = [line.split()[1] for line in lines[1:] if " Hz converged in " in line]
        assert counts == [f"{n}/{total}" for n in range(on_disk + 1, total + 1)], lines
    response = load_response(out)
    assert sorted(p.frequency_hz for p in response.points) == sorted(p.frequency_hz for p in whole.points)
    assert [p for p in response.points if p.frequency_hz in {k.frequency_hz for k in kept}] == kept
    assert all(p.converged for p in response.points)


def test_a_sweep_resumes_on_another_port_or_channel_but_not_on_another_drive(tmp_path: Path) -> None:
    """How the drive is reached (the serial port, the CAN interface and channel) is not what is measured: results
    made on one port or bus channel resume on another; results made at another tolerance do not."""
    from bodebench.bench.procedure import previous_run
    from bodebench.io.config import parse_config
    from bodebench.io.results import ResultsError

    def case(source: str, **changes: dict) -> object:
        data = tomllib.loads((Path(__file__).parent.parent / source).read_text())
        for table, values in changes.items():
            data[table] = {**data.get(table, {}), **values}
        return parse_config(data, source).cases[0]

    for source, moved in (("configs/sim_serial.toml", {"serial": {"port": "/dev/pts/7"}}),
                          ("configs/sim_can.toml", {"can": {"channel": "another-bus", "interface": "socketcan"}})):
        made = case(source)
        out = tmp_path / Path(source).stem
        out.mkdir()
        save_response(FrequencyResponse(config=made.raw, case=made.name), out)
        elsewhere = case(source, **moved)
        assert elsewhere.raw != made.raw
        assert previous_run(out, elsewhere, "resume") is not None
        with pytest.raises(ResultsError, match=r"another configuration \(analysis.tolerance_percent: [0-9.e-]+ in the "
                                               r"results, 0.02 now\); cannot resume"):
            previous_run(out, case(source, **moved, analysis={"tolerance_percent": 0.02}), "resume")


def test_a_resume_refuses_samples_files_gone_since_written_and_names_them(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """samples/ deleted between the runs: the checksums the sidecar recorded say so; the resume is refused naming
    each file, and goes on with them named as warnings when told to (resume_changed, --accept-changes)."""
    import logging
    import shutil

    from bodebench.bench.procedure import SweepProcedure, previous_run
    from bodebench.io.config import parse_config as parse
    from bodebench.io.results import ResultsError

    data = {"plant": {"model": "lag", "time_constant": 0.05, "gain": 1.0},
            "excitation": {"amplitude": 1.0, "frequencies_hz": [1.0, 3.0]},
            "analysis": {"tolerance_percent": 0.1}}
    case = parse(data, "x.toml").cases[0]
    SweepProcedure(parse(data, "x.toml"), tmp_path, keep_samples=True).run()
    shutil.rmtree(tmp_path / "samples")
    with pytest.raises(ResultsError) as refused:
        previous_run(tmp_path, case, existing="resume")
    assert "samples/1.0Hz.npz: gone since it was written; samples/3.0Hz.npz: gone since it was written" \
        in str(refused.value) and "--accept-changes" in str(refused.value)
    with caplog.at_level(logging.WARNING, logger="bodebench.sweep"):
        previous = previous_run(tmp_path, case, existing="resume_changed")
    assert previous is not None and len(previous) == 2
    assert sum("gone since it was written" in r.getMessage() for r in caplog.records) == 2
