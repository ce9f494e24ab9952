"""``bodebench dbc``: the frame layout written as a DBC file that cantools, the other end's implementation, reads back
to the layout's own bit positions, and with which it decodes what bodebench's codec encodes (and the reverse)."""

from __future__ import annotations

import math
import random
from pathlib import Path

import cantools
import pytest

from bodebench.apps.cli import main
from bodebench.drivers.codec import Message
from bodebench.drivers.dbc import DbcMessage
from bodebench.drivers.layout import Layout
from bodebench.io.config import load_config

ROOT = Path(__file__).resolve().parents[1]

ODD = """
[excitation]
amplitude = 0.5
frequencies_hz = [2, 5]
[bench]
transport = "can"
rate_hz = 1000
clock = "realtime"
timebase = "timestamp"
[can]
interface = "socketcan"
channel = "can0"
[safety]
max_amplitude = 1.0
[frames.setpoint]
id = 0x18FF0010
extended = true
signals = [{ name = "setpoint", byte = 2, type = "int16", endian = "big", scale = 0.001, offset = -1.5 },
           { name = "counter", byte = 0, type = "uint8" }]
[[frames.feedback]]
id = 0x181
signals = [{ name = "position", byte = 0, type = "int32", endian = "big", scale = 1e-5 },
           { name = "counter", byte = 4, type = "uint8" },
           { name = "timestamp_us", byte = 5, type = "uint16", endian = "big" }]
[[frames.feedback]]
id = 0x182
signals = [{ name = "pressure", byte = 0, type = "uint16", scale = 0.01, offset = -20 },
           { name = "counter", byte = 2, type = "uint8" },
           { name = "current", byte = 3, type = "float32", endian = "big" }]
[frames.enable]
id = 0x10
data = [1]
"""
"""Big-endian and scaled signals with offsets, a 29-bit id, signals out of byte order."""


def written(config: Path, tmp_path: Path) -> tuple[Layout, cantools.database.can.Database]:
    out = tmp_path / "layout.dbc"
    assert main(["dbc", str(config), "--out", str(out)]) == 0
    layout = load_config(config).cases[0].layout
    assert layout is not None
    return layout, cantools.database.load_file(str(out), database_format="dbc")


def expected_bits(message: Message) -> dict[str, tuple[int, int, str, bool, bool, float, float]]:
    """Each signal's DBC position worked out from the codec's own fields: a little-endian signal starts at its
    first byte's bit 0, a big-endian one at its first byte's bit 7 (the DBC's most significant bit)."""
    out = {}
    for s in message.signals:
        start = 8 * s.byte + (0 if s.endian == "little" else 7)
        order = "little_endian" if s.endian == "little" else "big_endian"
        out[s.name] = (start, 8 * s.size, order, s.type.startswith(("int", "float")), s.type.startswith("float"),
                       s.scale, s.offset)
    return out


def values_for(message: Message | DbcMessage, rng: random.Random) -> dict[str, float]:
    """Random physical values that fit each signal, on its raw grid."""
    from bodebench.drivers.dbc import signal_specs

    values = {}
    for spec in signal_specs(message):
        if spec.is_float:
            values[spec.name] = rng.uniform(-1e3, 1e3)
        else:
            lo, hi = (-(1 << (spec.length - 1)), (1 << (spec.length - 1)) - 1) if spec.signed \
                else (0, (1 << spec.length) - 1)
            if isinstance(message, DbcMessage):  # within the DBC's own [minimum, maximum], where it gives them
                sig = message.dbc_signal(spec.name)
                if sig.minimum is not None:
                    lo = max(lo, math.ceil((sig.minimum - spec.offset) / spec.scale))
                if sig.maximum is not None:
                    hi = min(hi, math.floor((sig.maximum - spec.offset) / spec.scale))
            values[spec.name] = rng.randint(lo, hi) * spec.scale + spec.offset
    return values


@pytest.mark.parametrize("source", ["odd", "sim_can.toml", "sim_serial.toml", "real_can.toml"])
def test_the_written_dbc_is_the_layout(source: str, tmp_path: Path) -> None:
    if source == "odd":
        config = tmp_path / "odd.toml"
        config.write_text(ODD)
    else:
        config = tmp_path / source
        config.write_text((ROOT / "configs" / source).read_text())
        if source == "real_can.toml":
            (tmp_path / "real_can.dbc").write_text((ROOT / "configs" / "real_can.dbc").read_text())
    layout, db = written(config, tmp_path)
    ours = [layout.setpoint, *layout.feedback]
    assert [(m.frame_id, m.is_extended_frame, m.length) for m in db.messages] == \
        [(m.id, m.extended, m.length) for m in ours]
    rng = random.Random(7)
    for message in ours:
        theirs = db.get_message_by_frame_id(message.id)
        got = {s.name: (s.start, s.length, s.byte_order, s.is_signed or s.is_float, s.is_float, s.scale, s.offset)
               for s in theirs.signals}
        if isinstance(message, Message):
            assert got == expected_bits(message)
        else:  # a layout read from a DBC file: the positions that file gave, under bodebench's names
            source_db = cantools.database.load_file(str(tmp_path / "real_can.dbc"))
            original = {s.name: s for s in source_db.get_message_by_frame_id(message.id).signals}
            mapping = {"setpoint": "Setpoint", "counter": "SetpointCounter"} if message is layout.setpoint else \
                {"position": "ActualPosition", "setpoint_echo": "AppliedSetpoint", "counter": "SampleCounter"}
            assert set(got) == set(message.signal_names)
            for name, position in got.items():
                o = original[mapping[name]]
                assert position == (o.start, o.length, o.byte_order, o.is_signed or o.is_float, o.is_float, o.scale,
                                    o.offset)
        for _ in range(50):  # bodebench encodes, cantools decodes; cantools encodes, bodebench decodes
            values = values_for(message, rng)
            payload = message.encode(values)
            decoded = theirs.decode(payload, decode_choices=False)
            mine = message.decode(payload)
            assert set(decoded) == set(mine)
            for name, value in mine.items():
                assert math.isclose(decoded[name], value, rel_tol=1e-12, abs_tol=1e-12), (message.name, name)
            back = message.decode(bytes(theirs.encode(decoded, strict=False)))
            for name, value in mine.items():
                assert math.isclose(back[name], value, rel_tol=1e-12, abs_tol=1e-12), (message.name, name)


def test_dbc_refuses_an_offline_config_and_an_existing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                            ) -> None:
    assert main(["dbc", str(ROOT / "configs" / "paper2013.toml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "paper2013.toml: bench: missing" in err
    out = tmp_path / "mine.dbc"
    out.write_text("mine")
    assert main(["dbc", str(ROOT / "configs" / "sim_can.toml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a file is there already" in err and out.read_text() == "mine"


def test_the_fixed_frames_are_named_in_the_database_comment(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                            ) -> None:
    assert main(["dbc", str(ROOT / "configs" / "sim_can.toml")]) == 0
    text = capsys.readouterr().out
    db = cantools.database.load_string(text, database_format="dbc")
    comment = db.buses[0].comment if db.buses else text
    for role, frame in (("enable", "id 0x10 data 01"), ("disable", "id 0x10 data 00"),
                        ("heartbeat", "id 0x700 data 05 every 0.1 s")):
        assert f"{role} {frame}" in comment
