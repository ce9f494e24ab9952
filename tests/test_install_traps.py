"""A package left out of an install, on a documented path: one line naming the extra that installs it, never a
traceback; ``bodebench ports`` lists only the CAN interfaces that can open here and says why the others cannot.

Each check runs a fresh interpreter whose ``sitecustomize`` makes the package unimportable (``sys.modules[name] =
None``) before bodebench is imported, as on an install without it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def without(tmp_path: Path, *modules: str) -> dict[str, str]:
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text("import sys\n" + "".join(f"sys.modules[{m!r}] = None\n" for m in modules))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), env.get("PYTHONPATH", "")]))
    return env


def bodebench(env: dict[str, str] | None, *args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bodebench", *args], env=env, cwd=cwd, capture_output=True,
                          text=True, timeout=300)


def one_line(done: subprocess.CompletedProcess[str], *words: str) -> str:
    assert "Traceback" not in done.stderr and "ModuleNotFoundError" not in done.stderr, done.stderr
    assert done.stderr.count("\n") == 1, done.stderr
    for word in words:
        assert word in done.stderr, done.stderr
    return done.stderr


def test_the_blocking_itself_works(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-c", "import canopen"], env=without(tmp_path, "canopen"),
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1 and "import of canopen halted" in done.stderr


@pytest.mark.parametrize("command", [["check"], ["run", "--out", "OUT"], ["simulate", "--out", "OUT"],
                                     ["sim-controller", "--seconds", "1"], ["dbc"]])
def test_transport_canopen_without_canopen_names_the_extra(tmp_path: Path, command: list[str]) -> None:
    args = [a.replace("OUT", str(tmp_path / "out")) for a in command]
    done = bodebench(without(tmp_path, "canopen"), args[0], "configs/sim_canopen.toml", *args[1:])
    assert done.returncode == 2
    one_line(done, "sim_canopen.toml: bench.transport = \"canopen\" needs the canopen package",
             "pip install 'bodebench[canopen]'")
    assert not (tmp_path / "out").exists()


def test_the_api_raises_the_same_one_line(tmp_path: Path) -> None:
    code = ("import bodebench\n"
            "try:\n    bodebench.configure('configs/sim_canopen.toml')\n"
            "except bodebench.MissingDependency as exc:\n    print(exc)\n")
    done = subprocess.run([sys.executable, "-c", code], env=without(tmp_path, "canopen"), cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "'bodebench[canopen]'" in done.stdout and done.stdout.count("\n") == 1


def test_udp_multicast_without_msgpack_names_the_extra(tmp_path: Path) -> None:
    env = without(tmp_path, "msgpack")
    config = tmp_path / "udp.toml"
    text = (ROOT / "configs" / "sim_can.toml").read_text()
    config.write_text(text.replace('interface = "virtual"', 'interface = "udp_multicast"')
                      .replace('channel = "bodebench"', 'channel = "239.74.163.2"'))
    for args in (["check", str(config)], ["sim-controller", str(config), "--seconds", "1"],
                 ["run", str(config), "--out", str(tmp_path / "out")]):
        done = bodebench(env, *args)
        assert done.returncode == 2
        one_line(done, 'udp.toml: can.interface = "udp_multicast"', "needs the msgpack package",
                 "pip install 'bodebench[rehearse]'")
    # the port itself says so to a script that opens it
    code = ("from bodebench.drivers.ports import CanPort\nfrom bodebench.drivers.errors import DriverInitError\n"
            "try:\n    CanPort.open('udp_multicast', '239.74.163.2')\n"
            "except DriverInitError as exc:\n    print(exc)\n")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "'bodebench[rehearse]'" in done.stdout, done.stderr


def test_ports_leaves_out_udp_multicast_without_msgpack_and_says_why(tmp_path: Path) -> None:
    done = bodebench(without(tmp_path, "msgpack"), "ports", "--can", "udp_multicast", "--can", "virtual", "--json")
    assert done.returncode == 0, done.stderr
    listed = json.loads(done.stdout)
    assert {c["interface"] for c in listed["can"]} == {"virtual"}
    assert [u["interface"] for u in listed["can_unusable"]] == ["udp_multicast"]
    assert "pip install 'bodebench[rehearse]'" in listed["can_unusable"][0]["why"]
    done = bodebench(without(tmp_path, "msgpack"), "ports", "--no-can")
    assert done.returncode == 0 and "CAN" not in done.stdout
    done = bodebench(without(tmp_path, "msgpack"), "ports", "--can", "udp_multicast")
    assert done.returncode == 0 and done.stderr == ""
    assert "CAN configurations (python-can, udp_multicast): 0" in done.stdout
    assert "  udp_multicast: python-can's udp_multicast interface needs the msgpack package" in done.stdout


def test_ports_lists_udp_multicast_where_msgpack_is_installed() -> None:
    import msgpack  # noqa: F401 - a test extra: the install this test runs in has it
    done = bodebench(None, "ports", "--can", "udp_multicast", "--json")
    assert done.returncode == 0, done.stderr
    listed = json.loads(done.stdout)
    assert listed["can"] and {c["interface"] for c in listed["can"]} == {"udp_multicast"}
    assert listed["can_unusable"] == []


def test_an_interface_asked_for_that_finds_nothing_says_why() -> None:
    done = bodebench(None, "ports", "--can", "pcan", "--can", "slcan", "--json")
    assert done.returncode == 0, done.stderr
    listed = json.loads(done.stdout)
    reasons = {u["interface"]: u["why"] for u in listed["can_unusable"]}
    # pcan: channels where PCAN-Basic and an adapter are there, else the reason; never a silent 0
    assert any(c["interface"] == "pcan" for c in listed["can"]) or reasons.get("pcan")
    assert "cannot list its channels" in reasons["slcan"]  # python-can has no detection for slcan


def test_an_interface_python_can_does_not_know_is_one_line() -> None:
    done = bodebench(None, "ports", "--can", "pcna")
    assert done.returncode == 2
    one_line(done, "python-can knows no interface 'pcna'", "pcan")
