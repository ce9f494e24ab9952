"""The example configurations: every one in configs/ loads, ``bodebench example`` lists and writes them exactly, and
an installed wheel carries them (with py.typed)."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from bodebench.apps.cli import main
from bodebench.io.config import SIMULATED_DRIVE_EDS, SIMULATED_EDS, ConfigError, load_config
from bodebench.io.document import parse_override

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
SHIPPED = sorted(p.name for p in CONFIGS.iterdir() if p.suffix in (".toml", ".dbc"))

EDS = parse_override(f"canopen.eds={SIMULATED_DRIVE_EDS}")
"""A real CiA 402 config names the user's own EDS; the simulated drive's holds the same standard objects."""


REAL_EDS = {"real_cia402.toml": EDS, "real_cia408.toml": parse_override(f"canopen.eds={SIMULATED_EDS['408']}")}
"""The real CANopen examples name the user's own EDS; the simulated device's of the same profile stands in."""


def overrides_for(name: str) -> list:  # type: ignore[type-arg]
    return [REAL_EDS[name]] if name in REAL_EDS else []


@pytest.mark.parametrize("name", [n for n in SHIPPED if n.endswith(".toml")])
def test_every_shipped_config_loads(name: str) -> None:
    config = load_config(CONFIGS / name, overrides_for(name))
    for case in config.cases:
        assert case.excitation.frequencies_hz
        if name.startswith("real_"):  # a real bench: nothing simulated, the drive reached by the user's values
            assert case.plant is None and case.simulator is None
            assert case.bench is not None and case.bench.clock == "realtime"
            assert (case.serial.port if case.serial else case.can.channel if case.can else "")  # type: ignore[union-attr]


def test_the_real_cia402_example_needs_the_drives_own_eds() -> None:
    with pytest.raises(ConfigError, match=r"real_cia402.toml: canopen.eds: cannot read the EDS .*my_drive.eds"):
        load_config(CONFIGS / "real_cia402.toml")


def test_the_real_cia402_example_uses_standard_objects_only() -> None:
    case = load_config(CONFIGS / "real_cia402.toml", [EDS]).cases[0]
    assert case.canopen_setup is not None
    assert case.canopen_setup.setpoint.index == 0x607A
    assert [(name, ref.index) for name, ref, _ in case.canopen_setup.actual] == [("position", 0x6064)]
    assert case.bench is not None and case.bench.timebase == "sync"  # dated by the SYNC, no counter needed


def test_example_lists_every_shipped_file_with_its_title(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["example"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(SHIPPED)
    listed = {line.split()[0]: line.split(None, 1)[1] for line in lines}
    for file in SHIPPED:
        text = (CONFIGS / file).read_text()
        if file.endswith(".toml"):
            assert listed[file.removesuffix(".toml")] == tomllib.loads(text)["title"]
        else:
            assert f'CM_ "{listed[file]}";' in text


@pytest.mark.parametrize("name", SHIPPED)
def test_example_writes_the_shipped_file_unchanged(name: str, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "copy"
    assert main(["example", name.removesuffix(".toml"), "--out", str(out)]) == 0
    assert out.read_bytes() == (CONFIGS / name).read_bytes()
    assert main(["example", name.removesuffix(".toml")]) == 0  # standard output
    assert capsys.readouterr().out == (CONFIGS / name).read_text()


def test_example_never_overwrites_and_names_what_there_is(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "mine.toml"
    out.write_text("my own bench\n")
    assert main(["example", "sim_can", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "mine.toml: a file is there already" in err
    assert out.read_text() == "my own bench\n"
    assert main(["example", "no_such"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no example 'no_such'" in err and "sim_can" in err


def test_an_example_written_next_to_its_dbc_loads_from_there(tmp_path: Path) -> None:
    for name in ("real_can", "real_can.dbc"):
        assert main(["example", name, "--out", str(tmp_path / (name if "." in name else name + ".toml"))]) == 0
    case = load_config(tmp_path / "real_can.toml").cases[0]
    assert case.layout is not None and case.layout.channels == ("position", "setpoint_echo")


@pytest.mark.slow
def test_a_wheel_carries_the_examples_and_py_typed(tmp_path: Path) -> None:
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(ROOT)],
                           capture_output=True, text=True, timeout=600)
    assert built.returncode == 0, built.stderr
    (wheel,) = tmp_path.glob("bodebench-*.whl")
    unpacked = tmp_path / "site"
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        archive.extractall(unpacked)
    assert "bodebench/py.typed" in names
    assert {n.removeprefix("bodebench/configs/") for n in names if n.startswith("bodebench/configs/")} == set(SHIPPED)
    env = {**os.environ, "PYTHONPATH": str(unpacked)}
    code = ("import bodebench, sys; from bodebench.apps.cli import main\n"
            f"assert bodebench.__file__.startswith({str(unpacked)!r}), bodebench.__file__\n"
            "sys.exit(main(['example', 'sim_can']))\n")
    done = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout == (CONFIGS / "sim_can.toml").read_text()
    # from the wheel alone: a CiA 408 example written out and swept (its simulated device's EDS is package data)
    assert {"bodebench/data/cia408_sim.eds", "bodebench/apps/commands/run.py"} <= names
    code = ("import sys; from bodebench.apps.cli import main\n"
            "assert main(['example', 'sim_cia408_valve', '--out', 'valve.toml']) == 0\n"
            "sys.exit(main(['run', 'valve.toml', '--out', 'valve', '--quiet', '--plots', 'none', '--set', "
            "'excitation.frequencies_hz=[5, 45]']))\n")
    swept = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True,
                           timeout=300)
    assert swept.returncode == 0, swept.stderr
    rows = [line for line in (tmp_path / "valve" / "response.csv").read_text().splitlines()[1:] if line]
    assert len(rows) == 2 and all(",true,converged," in row for row in rows)
