"""The bench commands as a user runs them: ``bodebench run`` and ``bodebench sim-controller`` in real processes."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bodebench.core.response import FrequencyResponse
from bodebench.io.results import load_response, save_response
from bodebench.status import PointStatus

SERIAL_BENCH = """
title = "lockstep serial drive"
[plant]
model = "coulomb"
mass = 2.533e-4
stiffness = 1.0
friction = 0.008
[excitation]
amplitude = 0.01
frequencies_hz = {freqs}
[analysis]
harmonics = [1]
tolerance_percent = 0.01
[bench]
transport = "serial"
rate_hz = 1000
clock = "lockstep"
[serial]
port = "{port}"
framing = "binary"
[frames.setpoint]
id = 1
signals = [{{ name = "setpoint", byte = 0, type = "float32" }}, {{ name = "counter", byte = 4, type = "uint16" }}]
[[frames.feedback]]
id = 0x81
signals = [{{ name = "position", byte = 0, type = "float32" }}, {{ name = "counter", byte = 4, type = "uint16" }}]
[frames.enable]
id = 0x10
data = [1]
[frames.disable]
id = 0x10
data = [0]
[safety]
max_amplitude = 0.02
watchdog_s = 2.0
{simulator}
"""


def command() -> list[str]:
    exe = shutil.which("bodebench")
    return [exe] if exe else [sys.executable, "-m", "bodebench"]


@pytest.mark.slow
def test_run_command_sweeps_the_simulated_can_bench(tmp_path: Path) -> None:
    cfg = Path(__file__).resolve().parents[1] / "configs" / "sim_can.toml"
    text = cfg.read_text().replace("frequencies_hz = [2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 15, 20, 30, 50]",
                                   "frequencies_hz = [4, 12]")
    small = tmp_path / "sim_can_small.toml"
    small.write_text(text)
    proc = subprocess.run(command() + ["run", str(small), "--out", str(tmp_path / "out")], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    # the case's line (its summary figures follow it) says how the drive was left
    assert [line for line in proc.stdout.splitlines() if line.endswith("drive left at setpoint 0, disabled")]
    response = load_response(tmp_path / "out")
    assert sorted({p.frequency_hz for p in response.points}) == [4.0, 12.0]
    assert all(p.converged for p in response.points)
    # the offline run of the same bench config gives the same numbers
    proc = subprocess.run(command() + ["simulate", str(small), "--out", str(tmp_path / "offline")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    offline = load_response(tmp_path / "offline")
    a, b = response.select(harmonic=1), offline.select(harmonic=1)
    assert np.allclose(a.gain_db, b.gain_db, atol=0.05) and np.allclose(a.phase_deg, b.phase_deg, atol=0.2)


def test_run_refuses_an_offline_config(tmp_path: Path) -> None:
    cfg = Path(__file__).resolve().parents[1] / "configs" / "paper2013.toml"
    proc = subprocess.run(command() + ["run", str(cfg), "--out", str(tmp_path)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2
    assert "paper2013.toml" in proc.stderr and "bench" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.slow
@pytest.mark.parametrize("signum, group", [(signal.SIGINT, True), (signal.SIGTERM, False), (signal.SIGTERM, True),
                                           (signal.SIGHUP, True)],
                         ids=["ctrl-c", "sigterm-to-the-process", "sigterm-to-the-group", "sighup"])
def test_a_stop_signal_mid_sweep_keeps_points_and_leaves_the_drive_at_zero(tmp_path: Path, signum: int,
                                                                           group: bool) -> None:
    """A standalone simulated drive on a pty; ``bodebench run`` against it gets a stop signal mid-sweep: Ctrl-C
    (SIGINT to the foreground group), SIGTERM to the process alone (``timeout``, ``kill``) or to its group
    (systemd, ``docker stop``), SIGHUP (a closed terminal). The drive reports what it received."""
    sim_cfg = tmp_path / "drive.toml"
    sim_cfg.write_text(SERIAL_BENCH.format(freqs="[3]", port="", simulator="[simulator]"))
    drive = subprocess.Popen(command() + ["sim-controller", str(sim_cfg)], stdout=subprocess.PIPE, text=True,
                             start_new_session=True)
    try:
        line = drive.stdout.readline()
        port = re.search(r'port = "([^"]+)"', line).group(1)
        run_cfg = tmp_path / "run.toml"
        run_cfg.write_text(SERIAL_BENCH.format(freqs="[15, 12, 3, 4, 5, 6, 7, 8]", port=port, simulator=""))
        out = tmp_path / "out"
        run = subprocess.Popen(command() + ["run", str(run_cfg), "--out", str(out)], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and run.poll() is None:
            csv = out / "response.csv"
            rows = [line for line in csv.read_text().splitlines() if not line.startswith("#")] if csv.exists() else []
            if len(rows) >= 3:  # the column names and two points measured
                break
            time.sleep(0.05)
        assert run.poll() is None, run.stderr.read()
        (os.killpg if group else os.kill)(run.pid, signum)
        _, err = run.communicate(timeout=60)
        assert run.returncode == 128 + signum, err
        assert "Traceback" not in err
        last = err.strip().splitlines()[-1]
        assert f"interrupted ({signal.Signals(signum).name})" in last
        assert last.endswith("drive left at setpoint 0, disabled"), last
        kept = load_response(out)
        assert len(kept.points) >= 2 and all(p.converged for p in kept.points)
    finally:
        os.killpg(drive.pid, signal.SIGINT)
        tail, _ = drive.communicate(timeout=30)
    assert "last setpoint 0, disabled" in tail
    # what the drive saw: enabled, each point's setpoint back to zero, and last the disable frame
    events = [line.split(" s  drive ", 1)[1] for line in tail.splitlines() if " s  drive " in line]
    assert events[0] == "enabled (enable frame)" and events[-1] == "disabled (disable frame)", events
    assert events[-2].startswith("setpoint zeroed")


def test_a_port_that_does_not_exist_is_one_line_that_claims_nothing(tmp_path: Path) -> None:
    cfg = tmp_path / "run.toml"
    cfg.write_text(SERIAL_BENCH.format(freqs="[3]", port=str(tmp_path / "no-such-tty"), simulator=""))
    proc = subprocess.run(command() + ["run", str(cfg), "--out", str(tmp_path / "out")], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and proc.stderr.count("cannot open serial port") == 1, proc.stderr
    assert lines[0].endswith("no point measured; nothing was sent to the drive")
    assert not (tmp_path / "out").exists()


def test_a_canopen_drive_that_falls_silent_is_one_line(tmp_path: Path) -> None:
    """The drive stops answering mid-sweep: the host's SDO requests during the shutdown time out. The run's one line
    says what failed and what was not confirmed; canopen's own log of the transfers it aborted stays out of it."""
    cfg = Path(__file__).resolve().parents[1] / "configs" / "sim_canopen.toml"
    proc = subprocess.run(command() + ["run", str(cfg), "--out", str(tmp_path / "out"), "--plots", "none",
                                       "--set", "simulator.canopen.silent_at_s=0.5",
                                       "--set", "canopen.state_timeout_s=0.3",
                                       "--set", "canopen.heartbeat_timeout_s=0.4",
                                       "--set", "excitation.frequencies_hz=[5]"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    errors = [line for line in proc.stderr.strip().splitlines() if not line.startswith("sim_canopen: ")]
    assert len(errors) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "no heartbeat" in errors[0] and "NOT seen disabled" in errors[0]
    assert "no SDO answer writing controlword (0x6040:00): No SDO response received" in errors[0]
    assert (tmp_path / "out" / "response.json").exists()


def test_a_run_whose_every_point_is_refused_ends_in_its_lines_with_its_record_and_no_plot(tmp_path: Path) -> None:
    """The drive stalls 10 ms in every 100 ms: each period of the 10 Hz point has a gap, the point is refused once
    its discarded periods exceed half of the 30 it may span (16), and the run ends without a plot to draw: exit
    status 1, no traceback, the record on disk."""
    cfg = Path(__file__).resolve().parents[1] / "configs" / "sim_can.toml"
    out = tmp_path / "out"
    proc = subprocess.run(command() + ["run", str(cfg), "--out", str(out), "--set", "excitation.frequencies_hz=[10]",
                                       "--set", "simulator.faults.stall_every_s=0.1",
                                       "--set", "simulator.faults.stall_s=0.01", "--set", "analysis.max_periods=30"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "10 Hz REFUSED, not written: 10 Hz: 16 of 16 periods discarded" in proc.stderr
    assert "0 points, 0 not converged, 1 frequencies refused" in proc.stdout + proc.stderr
    record = json.loads((out / "response.json").read_text())["runs"][-1]
    assert record["refused"][0]["frequency_hz"] == 10.0
    assert not list(out.glob("bode*")) and not list(out.glob("periods*"))


def test_results_that_cannot_be_written_are_found_before_the_first_setpoint(tmp_path: Path) -> None:
    cfg = Path(__file__).resolve().parents[1] / "configs" / "sim_can.toml"
    (tmp_path / "a-file").write_text("")
    proc = subprocess.run(command() + ["run", str(cfg), "--out", str(tmp_path / "a-file" / "out")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"bodebench: sim_can: not started: {tmp_path / 'a-file' / 'out'}: cannot create the results directory: "
        "Not a directory; nothing was sent to the drive"]


@pytest.mark.slow
def test_a_write_failure_mid_sweep_stops_safely_and_keeps_every_point_on_disk(tmp_path: Path) -> None:
    """Files may not grow past a limit (RLIMIT_FSIZE, as a full disk would refuse them): response.csv hits it
    mid-sweep. One line says so; every point saved before is on disk, whole; the drive was zeroed and disabled."""
    import resource

    from bodebench.io.config import load_config

    cfg = Path(__file__).resolve().parents[1] / "configs" / "sim_can.toml"
    case = load_config(cfg).cases[0]
    save_response(FrequencyResponse(config=case.raw, case=case.name), tmp_path / "probe")
    # the sidecar as it starts (the configuration, the run's record) fits; response.csv (a row of about 300 bytes per
    # point) or the sidecar with its growing checksums outgrows it within a few frequencies; the raw samples, bigger
    # still, are not kept here
    limit = max((tmp_path / "probe" / name).stat().st_size for name in ("response.json",
                                                                        "response.csv-metadata.json")) + 500

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    out = tmp_path / "out"
    freqs = [12, 15, 20, 30, 50, 9, 10]  # the config's fastest first: the limit is met within a few points
    proc = subprocess.run(command() + ["run", str(cfg), "--out", str(out), "--quiet", "--no-samples",
                                       "--set", f"excitation.frequencies_hz={freqs}"],
                          capture_output=True, text=True, timeout=300, preexec_fn=limited)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    kept = load_response(out)
    assert 0 < len(kept.points) <= 2 * len(freqs)
    assert all(p.converged or p.status == PointStatus.ALIAS_LIMITED for p in kept.points)  # 50 Hz: 40 samples
    # the limit meets the rows (refused whole), or after them the sidecar's checksums (the rows kept), or at the end
    # the run's record and summary: each said in one line, every point on disk counted
    assert re.search(rf"^bodebench: sim_can: stopped: output: {re.escape(str(out))}: cannot write (the point at "
                     rf"[0-9.]+ Hz|the run's record or summary|the plots): File too large( \(the rows are on disk; "
                     rf"their checksums could not be recorded in the sidecar\))?; {len(kept.points)} points kept in "
                     rf"{re.escape(str(out))}; drive left at setpoint 0, disabled$", lines[0]), lines[0]
