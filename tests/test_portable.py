"""bodebench on a platform without termios, fcntl, tty and pty (Windows): the command line, the CAN and serial
drivers and the in-process simulated drive import and run; the pseudo-terminal simulators say they need POSIX.

Each check runs a fresh interpreter whose ``sitecustomize`` makes those modules unimportable (``sys.modules[name] =
None``) before bodebench is imported, and so do the processes it starts. pyserial is loaded first: its POSIX backend
needs fcntl and termios here, where on Windows it loads its win32 backend instead.
"""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLOCKED = ("termios", "fcntl", "tty", "pty")


@pytest.fixture()
def no_posix_tty(tmp_path: Path) -> dict[str, str]:
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(
        "import sys\nimport serial\nimport serial.tools.list_ports\n"
        + "".join(f"sys.modules[{name!r}] = None\n" for name in BLOCKED))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), env.get("PYTHONPATH", "")]))
    return env


def python(env: dict[str, str], *args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=600)


def test_the_blocking_itself_works(no_posix_tty: dict[str, str]) -> None:
    done = python(no_posix_tty, "-c", "import termios")
    assert done.returncode == 1 and "ModuleNotFoundError: import of termios halted" in done.stderr


def test_the_command_line_and_the_drivers_import(no_posix_tty: dict[str, str]) -> None:
    done = python(no_posix_tty, "-m", "bodebench", "--help")
    assert done.returncode == 0, done.stderr
    assert "simulate" in done.stdout and "run" in done.stdout
    code = ("import sys\n"
            "import bodebench.drivers.ports as ports, bodebench.apps.cli, bodebench.bench.connection\n"
            "from bodebench.io.config import load_config\n"
            f"assert all(sys.modules.get(m) is None for m in {BLOCKED!r})\n"
            "layout = load_config('configs/sim_serial.toml').cases[0].layout\n"
            "line = ports.SerialPort.open('loop://', 115200, 'binary', layout)\n"
            "line.send(ports.Frame(0x10, bytes([1])))\n"
            "got = line.recv(1.0)\n"
            "assert [(f.id, f.data) for f in got] == [(0x10, bytes([1]))], got\n"
            "line.close()\n"
            "print('serial ok')\n")
    done = python(no_posix_tty, "-c", code)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "serial ok"


@pytest.mark.slow
def test_a_can_sweep_runs_and_a_pty_simulator_says_it_needs_posix(no_posix_tty: dict[str, str],
                                                                     tmp_path: Path) -> None:
    config = tmp_path / "lag.toml"
    config.write_text(
        '[plant]\nmodel = "lag"\ntime_constant = 0.01\n'
        '[excitation]\namplitude = 0.01\nfrequencies_hz = [5.0, 20.0]\n'
        '[analysis]\ntolerance_percent = 0.1\n'
        '[bench]\ntransport = "can"\nrate_hz = 1000\nclock = "lockstep"\n'
        f'[can]\ninterface = "virtual"\nchannel = "portable-{uuid.uuid4().hex[:8]}"\n'
        '[safety]\nmax_amplitude = 0.02\n[simulator]\n')
    done = python(no_posix_tty, "-m", "bodebench", "run", str(config), "--out", str(tmp_path / "out"), "--quiet")
    assert done.returncode == 0, done.stderr
    rows = [line for line in (tmp_path / "out" / "response.csv").read_text().splitlines() if not line.startswith("#")]
    assert len(rows) == 3  # the column names and two points
    serial = ROOT / "configs" / "sim_serial.toml"
    for command in (["run", str(serial), "--out", str(tmp_path / "serial")], ["sim-controller", str(serial)]):
        done = python(no_posix_tty, "-m", "bodebench", *command)
        assert done.returncode == 1, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and "need a POSIX system" in lines[0], done.stderr
        assert "Traceback" not in done.stderr


def test_results_are_saved_where_os_has_no_fchmod(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Windows has os.fchmod only from Python 3.13: the atomic writes of the results files do without it."""
    from bodebench.core.response import FrequencyResponse, ResponsePoint
    from bodebench.io.results import load_response, save_response, verify_results

    monkeypatch.delattr(os, "fchmod", raising=False)
    assert not hasattr(os, "fchmod")
    points = [ResponsePoint(f, 1, "position", 0.01, 0.004 * f, -0.003, 12, True, "converged", 1e-7, 5e-8, True)
              for f in (2.0, 5.0, 10.0)]
    save_response(FrequencyResponse(points, config={"note": "no fchmod"}, case="nofchmod"), tmp_path)
    loaded = load_response(tmp_path)
    assert loaded.points == points and loaded.case == "nofchmod" and loaded.config["note"] == "no fchmod"
    assert verify_results(tmp_path) == (True, [])  # the checksums recorded match what is on disk
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary file left behind
    if os.name == "posix":  # what an ordinary open() would have given, not mkstemp's 0600
        mask = os.umask(0)
        os.umask(mask)
        for name in ("response.csv", "response.json"):
            assert (tmp_path / name).stat().st_mode & 0o777 == 0o666 & ~mask
