"""``bodebench check``: every shipped configuration checks, its printed plan is the configuration's, a broken one is
one line naming the key, and the frames it says go to the drive are those a real session on the virtual bus sends."""

from __future__ import annotations

import json
import re
import uuid
from pathlib import Path

import can
import pytest

from bodebench.apps.cli import main
from bodebench.bench.procedure import SweepProcedure
from bodebench.io.config import SIMULATED_DRIVE_EDS, SIMULATED_EDS, load_config, parse_config
from bodebench.io.document import parse_override

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))
HEX = r"[0-9a-f]{2}(?: [0-9a-f]{2})*"
"""Bytes as check prints them."""
EDS = f"canopen.eds={SIMULATED_DRIVE_EDS}"  # a real CiA 402 config names the user's own EDS
REAL_EDS = {"real_cia402.toml": EDS, "real_cia408.toml": f"canopen.eds={SIMULATED_EDS['408']}"}
"""The real CANopen examples name the user's own EDS; the simulated device's of the same profile stands in."""


def checked(path: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> str:
    sets = ["--set", REAL_EDS[path.name]] if path.name in REAL_EDS else []
    assert main(["check", str(path), *sets, *extra]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    return captured.out


def plan_rows(out: str) -> list[list[tuple[float, float]]]:
    """The (frequency, amplitude) rows of every case's plan table."""
    cases: list[list[tuple[float, float]]] = []
    rows: list[tuple[float, float]] | None = None
    for line in out.splitlines():
        if line.strip().startswith("f Hz"):
            rows = []
            cases.append(rows)
        elif rows is not None and line.strip().startswith("sweep:"):
            rows = None
        elif rows is not None:
            f, amplitude = line.split()[:2]
            rows.append((float(f), float(amplitude)))
    return cases


@pytest.mark.parametrize("path", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_check_prints_each_shipped_configs_own_plan(path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = checked(path, capsys)
    config = load_config(path, [parse_override(REAL_EDS[path.name])] if path.name in REAL_EDS else [])
    expected = [[(f, case.excitation.amplitude_at(f)) for f in case.excitation.frequencies_hz]
                for case in config.cases]
    assert plan_rows(out) == expected
    if config.on_bench:  # what is sent on start and on every way out, and the limits
        assert "sent to the drive, on start:" in out and "sent to the drive on every way out" in out
        safety = config.cases[0].on_bench.safety
        assert f"max_amplitude {safety.max_amplitude:g}:" in out
        analysis = config.cases[0].analysis
        assert f"folds: {analysis.fold_policy}: " in out
        assert (f"and as 1/j^{analysis.fold_decay:g} in the tail" in out) == (analysis.fold_policy == "bound")
    else:
        assert "nothing is sent to any drive" in out and "sent to the drive" not in out


def test_check_takes_set_as_run_does(capsys: pytest.CaptureFixture[str]) -> None:
    out = checked(ROOT / "configs" / "sim_can.toml", capsys, "--set", "excitation.frequencies_hz=[3, 7]",
                  "--set", "excitation.amplitude=0.005")
    assert plan_rows(out) == [[(3.0, 0.005), (7.0, 0.005)]]


def test_the_fewest_periods_are_where_the_rule_stops_on_a_steady_sine(capsys: pytest.CaptureFixture[str]) -> None:
    # the fixed scheme stops after exactly settle + average periods: the fewest is that, whatever the plan
    out = checked(ROOT / "configs" / "sim_can.toml", capsys, "--set", 'analysis.criterion="fixed"',
                  "--set", "analysis.settle_periods=7", "--set", "analysis.average_periods=11")
    assert "periods: at least 18 " in out
    # 18 periods plus the ramp in (2) and out (1) at 2 Hz: 10.5 s of drive time
    row = next(line for line in out.splitlines() if line.split()[:1] == ["2"])
    assert row.split()[5] == "18-1200" and "10.5 s" in row  # at most 600 s of periods at 2 Hz (max_point_s)


@pytest.mark.parametrize("edit, key", [
    ("max_amplitude = 0.02", "safety.max_amplitude"),
    ("channel = \"bodebench\"", "can.chanel"),
])
def test_a_broken_config_is_one_line_naming_the_key(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    edit: str, key: str) -> None:
    text = (ROOT / "configs" / "sim_can.toml").read_text()
    broken = text.replace(edit, "max_amplitude = -1" if key.startswith("safety") else "chanel = \"bodebench\"")
    assert broken != text
    path = tmp_path / "broken.toml"
    path.write_text(broken)
    assert main(["check", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1 and f"broken.toml: {key}" in captured.err
    assert "Traceback" not in captured.err


def test_check_opens_no_bus(capsys: pytest.CaptureFixture[str]) -> None:
    # python-can's virtual bus: a check of a config on it adds no bus to those the interface holds
    from can.interfaces.virtual import channels

    before = dict(channels)
    out = checked(ROOT / "configs" / "sim_can.toml", capsys, "--set", f"can.channel=check-{uuid.uuid4().hex[:8]}")
    assert "python-can virtual channel check-" in out
    assert dict(channels) == before


@pytest.mark.slow
def test_the_frames_check_lists_are_those_a_session_sends(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = ROOT / "configs" / "sim_can.toml"
    channel = f"checked-{uuid.uuid4().hex[:8]}"
    out = checked(config, capsys, "--set", f"can.channel={channel}")
    said = {name: bytes.fromhex(data) for name, data in
            re.findall(rf"(enable|disable|heartbeat): id 0x[0-9A-F]+ data ({HEX})", out)}
    found = re.search(rf"(\d+) x setpoint 0: id 0x([0-9A-F]+) data ({HEX})", out)
    assert found is not None
    zeros, zero_id, zero_data = found.groups()
    data = json.loads(json.dumps(load_config(config).cases[0].raw))
    data["can"] = {"interface": "virtual", "channel": channel}
    data["excitation"]["frequencies_hz"] = [20.0]
    data["analysis"].update(harmonics=[1], tolerance_percent=0.1)
    log = tmp_path / "bus.asc"
    SweepProcedure(parse_config(data, "sim_can.toml"), tmp_path / "out", log_bus=log).run()
    sent = [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(log) if not m.is_rx]
    layout = load_config(config).cases[0].on_bench.layout
    assert layout.heartbeat is not None and layout.enable is not None and layout.disable is not None
    beats = [frame for frame in sent if frame[0] == layout.heartbeat.id]
    assert beats and all(data == said["heartbeat"] for _, data in beats)
    rest = [frame for frame in sent if frame[0] != layout.heartbeat.id]
    assert rest[0] == (layout.enable.id, said["enable"])  # the first frame: the enable check printed
    assert rest[-1] == (layout.disable.id, said["disable"])  # the last: the disable check printed
    tail = rest[-1 - int(zeros):-1]  # before it, that many zero setpoints (the counter bytes aside)
    assert [(frame_id, payload[:4]) for frame_id, payload in tail] == \
        [(int(zero_id, 16), bytes.fromhex(zero_data)[:4])] * int(zeros)


def sdo_writes(frames: list[tuple[int, bytes]], node: int) -> list[tuple[int, int, int]]:
    """(index, subindex, value) of each expedited SDO download the host sent to ``node``, in order, PDO
    communication and mapping objects (0x1400 to 0x1BFF) left out."""
    writes = []
    for frame_id, data in frames:
        if frame_id == 0x600 + node and len(data) == 8 and data[0] & 0xE3 == 0x23:  # ccs 1, expedited, size given
            index, sub = data[1] | data[2] << 8, data[3]
            if not 0x1400 <= index <= 0x1BFF:
                writes.append((index, sub, int.from_bytes(data[4:8 - (data[0] >> 2 & 3)], "little")))
    return writes


@pytest.mark.slow
def test_the_canopen_sequence_check_lists_is_what_a_session_sends(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    config = ROOT / "configs" / "sim_canopen.toml"
    channel = f"checked-{uuid.uuid4().hex[:8]}"
    out = checked(config, capsys, "--set", f"can.channel={channel}")
    start, _, leave = out.partition("sent to the drive on every way out")
    said_writes = [[(int(i, 16), int(s, 16) if s else None, int(v, 0))
                    for i, s, v in re.findall(r"SDO write 0x([0-9A-F]{4})(?::([0-9A-F]{2}))? = (\S+) ", part)]
                   for part in (start, leave)]
    said_nmt = [bytes.fromhex(d) for d in re.findall(rf"NMT [a-z-]+: id 0x000 data ({HEX})", out)]
    back = re.search(r"SDO write back 0x([0-9A-F]{4}) and 0x([0-9A-F]{4})", leave)
    assert back is not None
    data = json.loads(json.dumps(load_config(config).cases[0].raw))
    data["can"] = {"interface": "virtual", "channel": channel}
    data["excitation"]["frequencies_hz"] = [20.0]
    data["analysis"].update(harmonics=[1], tolerance_percent=0.1)
    case = parse_config(data, str(config)).cases[0]
    log = tmp_path / "bus.asc"
    SweepProcedure(parse_config(data, str(config)), tmp_path / "out", log_bus=log).run()
    sent = [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(log) if not m.is_rx]
    assert case.canopen is not None
    node = case.canopen.node_id
    writes = sdo_writes(sent, node)
    first_stop = next(i for i, w in enumerate(writes) if w[0] == 0x6040 and w[2] == 0x0002)  # quick stop
    on_start, on_exit = writes[:first_stop], writes[first_stop:]

    def same(said: list[tuple[int, int | None, int]], done: list[tuple[int, int, int]]) -> bool:
        return len(said) == len(done) and all(
            i == j and (s is None or s == t) and v == w for (i, s, v), (j, t, w) in zip(said, done, strict=True))

    assert same(said_writes[0], on_start), (said_writes[0], on_start)
    assert same(said_writes[1], on_exit[:len(said_writes[1])]), (said_writes[1], on_exit)
    assert [w[0] for w in on_exit[len(said_writes[1]):]] == [int(back[1], 16), int(back[2], 16)]
    assert [d for i, d in sent if i == 0x000] == said_nmt
