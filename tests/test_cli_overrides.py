"""``--set table.key=value`` and ``--port`` on the commands that read a configuration, and ``sim-controller
--write-config``: overrides validated as the file's own keys, recorded with the results, and a written bench
config that reaches the served drive over a real pseudo-terminal."""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bodebench.apps.cli import main
from bodebench.io.config import SIMULATED_DRIVE_EDS, load_config, parse_config
from bodebench.io.document import Override, apply_overrides, edited_copy, parse_override, toml_text
from bodebench.io.results import load_response
from bodebench.sim.plants import LinearOscillator

ROOT = Path(__file__).resolve().parents[1]

OFFLINE = """
title = "two dampings"
[plant]
model = "linear"
mass = 1e-3
stiffness = 1.0
[excitation]
amplitude = 0.5
frequencies_hz = [1.0, 5.0, 20.0]
[analysis]
harmonics = [1]
[cases.light.plant]
damping_ratio = 0.05
[cases.heavy.plant]
damping_ratio = 0.7
"""


def command() -> list[str]:
    exe = shutil.which("bodebench")
    return [exe] if exe else [sys.executable, "-m", "bodebench"]


# ------------------------------------------------------------------------------------------------ parsing


@pytest.mark.parametrize("text, parts, value", [
    ("analysis.tolerance_percent=0.1", ("analysis", "tolerance_percent"), 0.1),
    ('serial.port="/dev/pts/5"', ("serial", "port"), "/dev/pts/5"),
    ("serial.port=/dev/pts/5", ("serial", "port"), "/dev/pts/5"),  # a bare word is a string
    ("serial.port=", ("serial", "port"), ""),
    ("excitation.frequencies_hz=[1,2,5]", ("excitation", "frequencies_hz"), [1, 2, 5]),
    ("excitation.frequencies = {start_hz = 1, stop_hz = 10, per_decade = 2}", ("excitation", "frequencies"),
     {"start_hz": 1, "stop_hz": 10, "per_decade": 2}),
    ('cases."fbar_0.8".plant.friction=0.009', ("cases", "fbar_0.8", "plant", "friction"), 0.009),
    ("can.fd=true", ("can", "fd"), True),
    ("frames.setpoint.id=0x101", ("frames", "setpoint", "id"), 0x101),
    ("can.channel=vcan0", ("can", "channel"), "vcan0"),
])
def test_an_override_is_a_dotted_key_and_a_toml_value(text: str, parts: tuple[str, ...], value: Any) -> None:
    override = parse_override(text)
    assert override.parts == parts and override.value == value and type(override.value) is type(value)
    assert parse_override(str(override)) == override  # printed as it would be typed


@pytest.mark.parametrize("text, problem", [
    ("analysis.tolerance_percent", "expected KEY=VALUE"),
    ("=0.1", "empty key"),
    ("analysis..x=1", "not a TOML dotted key"),
    ('serial.port="/dev/pts/5', "not a TOML value"),
    ("excitation.frequencies_hz=[1, 2", "not a TOML value"),
])
def test_a_malformed_override_is_refused(text: str, problem: str) -> None:
    with pytest.raises(ValueError, match=re.escape(problem)):
        parse_override(text)


@pytest.mark.parametrize("argument", ["analysis.tolerance_percent", "=3", 'serial.port="x'])
def test_a_malformed_set_is_an_argument_error(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              argument: str) -> None:
    with pytest.raises(SystemExit) as stopped:
        main(["simulate", str(tmp_path / "x.toml"), "--out", str(tmp_path / "out"), "--set", argument])
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith("bodebench simulate: argument --set: ") and "Traceback" not in err


# --------------------------------------------------------------------------------------------- validation


@pytest.mark.parametrize("setting, expected", [
    ("serial.prt=3", "configs/sim_serial.toml: --set serial.prt: unknown key"),
    ("seral.port=3", "configs/sim_serial.toml: --set seral: unknown key"),
    ("analysis.tolerance_percent=abc", 'configs/sim_serial.toml: --set analysis.tolerance_percent: expected a '
                                       'number, got string "abc"'),
    ("analysis.tolerance_percent=-1", "configs/sim_serial.toml: --set analysis.tolerance_percent: must be > 0, "
                                      "got -1.0"),
    ("excitation.frequencies_hz=[4, 500]", "configs/sim_serial.toml: --set excitation.frequencies_hz[1]: 500 Hz: "
                                           "harmonic 3 needs at least 8 samples a period at bench.rate_hz = 2000"),
    ("serial.baudrate.x=1", "configs/sim_serial.toml: --set serial.baudrate: holds 1000000, not a table"),
    ("frames.feedback.1.id=2", "configs/sim_serial.toml: --set frames.feedback.1: an array of 1 tables"),
])
def test_an_override_is_validated_as_the_files_keys_are(monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                                         setting: str, expected: str) -> None:
    monkeypatch.chdir(ROOT)
    status = main(["run", "configs/sim_serial.toml", "--out", str(tmp_path / "out"), "--set", setting])
    err = capsys.readouterr().err.strip()
    assert status == 2 and len(err.splitlines()) == 1
    assert err.startswith(f"bodebench: {expected}"), err
    assert not (tmp_path / "out").exists()


def test_overrides_reach_nested_tables_cases_and_arrays_of_tables() -> None:
    paper = ROOT / "configs" / "paper2013.toml"
    config = load_config(paper, [parse_override('cases."fbar_0.8".plant.friction=0.009'),
                                 parse_override("analysis.tolerance_percent=0.1")])
    assert [(c.name, c.plant.friction, c.analysis.tolerance_percent) for c in config.cases] == [
        ("fbar_0.1", 0.001, 0.1), ("fbar_0.8", 0.009, 0.1), ("fbar_0.95", 0.0095, 0.1)]
    assert config.cases[1].raw["plant"]["friction"] == 0.009  # what the results record
    with pytest.raises(ValueError, match=re.escape('--set cases.fbar_0.plant.friction: no case fbar_0 in the file '
                                                   '(its cases: "fbar_0.1", "fbar_0.8", "fbar_0.95"')):
        load_config(paper, [Override(("cases", "fbar_0", "plant", "friction"), 0.009)])
    serial = ROOT / "configs" / "sim_serial.toml"
    config = load_config(serial, [parse_override("frames.feedback.0.id=0x82"),
                                  parse_override("simulator.faults.drop=0.25")])
    assert config.cases[0].raw["frames"]["feedback"][0]["id"] == 0x82
    assert config.cases[0].simulator.faults.drop == 0.25
    # the document itself is not changed
    document = tomllib.loads(serial.read_text())
    changed, created = apply_overrides(document, [parse_override("simulator.faults.drop=0.25")])
    assert "faults" not in document["simulator"] and created == [("simulator", "faults")]
    assert changed["simulator"]["faults"] == {"drop": 0.25}


@pytest.mark.slow
def test_overrides_are_what_the_results_record_and_what_resume_compares(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "cases.toml"
    cfg.write_text(OFFLINE)
    out = tmp_path / "out"
    sets = ["--set", "analysis.tolerance_percent=0.1", "--set", "cases.heavy.plant.damping_ratio=0.5",
            "--set", "excitation.frequencies_hz=[2, 8]"]
    assert main(["simulate", str(cfg), "--out", str(out), "--jobs", "1", "--plots", "none", "-q", *sets]) == 0
    for case, zeta in (("light", 0.05), ("heavy", 0.5)):
        sidecar = json.loads((out / case / "response.json").read_text())
        assert sidecar["config"]["plant"]["damping_ratio"] == zeta
        assert sidecar["config"]["analysis"]["tolerance_percent"] == 0.1
        response = load_response(out / case)
        assert sorted(response.frequency_hz) == [2.0, 8.0]
        exact = LinearOscillator(1e-3, 1.0, zeta).frequency_response(response.frequency_hz)[:, 0]
        assert np.allclose(response.gain, np.abs(exact), rtol=2e-3)
    capsys.readouterr()
    # resuming without the overrides is resuming another configuration: refused
    assert main(["simulate", str(cfg), "--out", str(out), "--jobs", "1", "--resume", "-q"]) == 2
    err = capsys.readouterr().err
    assert ("made with another configuration (analysis.tolerance_percent: 0.1 in the results, 0.01 now; "
            "excitation.frequencies_hz: [2.0, 8.0] in the results, ") in err, err
    # with them it is the same one: nothing left to measure, nothing changed
    before = {case: (out / case / "response.csv").read_text() for case in ("light", "heavy")}
    assert main(["simulate", str(cfg), "--out", str(out), "--jobs", "1", "--resume", "-q", "--plots", "none",
                 *sets]) == 0
    assert {case: (out / case / "response.csv").read_text() for case in ("light", "heavy")} == before


# -------------------------------------------------------------------------------------------------- --port


def test_port_on_a_can_bench_is_an_argument_error(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    for cfg in ("sim_can.toml", "sim_canopen.toml"):
        status = main(["run", str(ROOT / "configs" / cfg), "--out", str(tmp_path / "out"), "--port", "/dev/pts/5"])
        err = capsys.readouterr().err.strip()
        assert status == 2 and len(err.splitlines()) == 1
        assert err.startswith("bodebench run: --port /dev/pts/5: bench.transport is ")
        assert err.endswith("set the CAN channel with --set can.channel=... (see --help)")
    status = main(["tui", str(ROOT / "configs" / "paper2013.toml"), "--port", "/dev/pts/5"])
    err = capsys.readouterr().err.strip()
    assert status == 2 and "no bench.transport" in err and len(err.splitlines()) == 1


def test_port_sets_the_serial_port_of_every_case(tmp_path: Path) -> None:
    """What --port sets is what the command opens: a port that does not exist is the one named in the error."""
    missing = tmp_path / "no-such-tty"
    proc = subprocess.run(command() + ["run", str(ROOT / "configs" / "sim_serial.toml"), "--out",
                                       str(tmp_path / "out"), "--port", str(missing)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and f"cannot open serial port '{missing}'" in lines[0], proc.stderr
    assert lines[0].endswith("no point measured; nothing was sent to the drive")
    from bodebench.io.document import serial_port_overrides

    two = tomllib.loads((ROOT / "configs" / "sim_serial.toml").read_text())
    two["cases"] = {"a": {}, "b": {"serial": {"port": "/dev/ttyS0"}}}
    overrides = serial_port_overrides(two, "/dev/pts/9")
    config = parse_config(two, "two.toml", overrides)
    assert [c.serial.port for c in config.cases] == ["/dev/pts/9", "/dev/pts/9"]


# ------------------------------------------------------------------------------------------- written copies


def test_a_copy_keeps_the_file_and_changes_only_the_keys_set() -> None:
    text = (ROOT / "configs" / "sim_serial.toml").read_text()
    port = Override(("serial", "port"), "/dev/pts/7")
    tolerance = Override(("analysis", "tolerance_percent"), 0.1)
    copy = edited_copy(text, [port, tolerance], header="a copy")
    wanted, _ = apply_overrides(tomllib.loads(text), [port, tolerance])
    assert tomllib.loads(copy) == wanted
    lines = copy.splitlines()
    assert lines[0] == "# a copy"
    removed = [line for line in text.splitlines() if line not in lines]
    assert removed == ["tolerance_percent = 0.01"]  # every other line stays, comments too
    assert 'port = "/dev/pts/7"' in lines and "tolerance_percent = 0.1" in lines
    friction = edited_copy(text, [Override(("plant", "friction"), 0.009)])
    assert "friction = 0.009     # F_ct: Fbar = F_ct / A_F = 0.8" in friction.splitlines()  # its comment kept
    parse_config(tomllib.loads(copy), "copy.toml")


@pytest.mark.parametrize("name, overrides, remove", [
    ("sim_can.toml", [Override(("can", "channel"), "bench-7")], ("simulator",)),
    ("sim_canopen.toml", [Override(("can", "channel"), "bench-8"), Override(("canopen", "eds"),
                                                                           str(SIMULATED_DRIVE_EDS))], ("simulator",)),
    ("sim_serial.toml", [Override(("safety", "feedback_limits", "position"), [-0.4, 0.4])], ()),  # an inline table
    ("sim_serial.toml", [Override(("excitation", "frequencies_hz"), [4, 12])], ()),  # a value over two lines
    ("sim_serial.toml", [Override(("title", ), "a rehearsal")], ()),  # a top-level key
    ("paper2013.toml", [Override(("cases", "fbar_0.8", "plant", "friction"), 0.0085),
                        Override(("excitation", "frequencies_hz"), [5, 10])], ()),
])
def test_a_copy_is_exactly_the_document_meant(name: str, overrides: list[Override], remove: tuple[str, ...]) -> None:
    """Edited in place where that gives the document meant, else written whole: the same document either way."""
    text = (ROOT / "configs" / name).read_text()
    wanted, _ = apply_overrides(tomllib.loads(text), overrides)
    for table in remove:
        wanted.pop(table)
    copy = edited_copy(text, overrides, remove, header="a copy")
    assert tomllib.loads(copy) == wanted and copy.startswith("# a copy\n")
    assert tomllib.loads(toml_text(wanted)) == wanted
    config = parse_config(tomllib.loads(copy), str(ROOT / "configs" / name))
    assert all(c.simulator is None for c in config.cases) or not remove


@pytest.mark.slow
def test_sim_controller_writes_the_bench_config_that_run_sweeps(tmp_path: Path) -> None:
    """The simulated drive on a real pty writes a copy of its config pointing at that pty; ``bodebench run`` on
    the copy sweeps the drive, and the points are the offline experiment's of the same config."""
    drive_cfg = tmp_path / "drive.toml"
    drive_cfg.write_text((ROOT / "configs" / "sim_serial.toml").read_text())
    bench_cfg = tmp_path / "bench.toml"
    drive = subprocess.Popen(command() + ["sim-controller", str(drive_cfg), "--write-config", str(bench_cfg),
                                          "--set", "excitation.frequencies_hz=[8, 20]"],
                             stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        line = drive.stdout.readline()
        port = re.search(r'port = "([^"]+)"', line).group(1)
        assert f"a bench config for it: {bench_cfg} (bodebench run {bench_cfg} --out DIR)" in line, line
        case = load_config(bench_cfg).cases[0]
        assert case.serial.port == port and case.excitation.frequencies_hz == (8.0, 20.0)
        out = tmp_path / "out"
        run = subprocess.run(command() + ["run", str(bench_cfg), "--out", str(out), "--plots", "none"],
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        assert f"serial {port}" in run.stderr  # swept over the pty the drive opened
        response = load_response(out)
        assert sorted({p.frequency_hz for p in response.points}) == [8.0, 20.0]
        assert all(p.converged for p in response.points)
        assert json.loads((out / "response.json").read_text())["config"]["serial"]["port"] == port
    finally:
        drive.send_signal(signal.SIGINT)
        tail, _ = drive.communicate(timeout=30)
    assert "last setpoint 0, disabled" in tail
    events = [line.split(" s  drive ", 1)[1] for line in tail.splitlines() if " s  drive " in line]
    assert events[0] == "enabled (enable frame)" and events[-1] == "disabled (disable frame)", events
    offline = subprocess.run(command() + ["simulate", str(bench_cfg), "--out", str(tmp_path / "offline"),
                                          "--plots", "none", "-q"], capture_output=True, text=True, timeout=300)
    assert offline.returncode == 0, offline.stderr
    a, b = response.select(harmonic=1), load_response(tmp_path / "offline").select(harmonic=1)
    assert np.allclose(a.gain_db, b.gain_db, atol=0.05) and np.allclose(a.phase_deg, b.phase_deg, atol=0.2)


def test_write_config_refuses_to_overwrite_the_configuration(capsys: pytest.CaptureFixture[str],
                                                             tmp_path: Path) -> None:
    cfg = tmp_path / "drive.toml"
    cfg.write_text((ROOT / "configs" / "sim_serial.toml").read_text())
    assert main(["sim-controller", str(cfg), "--write-config", str(cfg), "--seconds", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"bodebench sim-controller: --write-config {cfg}: is the configuration itself (write the copy " \
                  "elsewhere) (see --help)"
    assert main(["sim-controller", str(cfg), "--write-config", str(tmp_path / "nowhere" / "x.toml")]) == 2
    assert "no directory" in capsys.readouterr().err
