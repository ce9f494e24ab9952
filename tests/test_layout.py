"""Tests of drivers.layout (signals, messages, layouts, configuration tables) and the DBC adapter."""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodebench.drivers import Layout, LayoutError, Message, Signal, default_layout
from bodebench.drivers.dbc import DbcMessage

# independent description of the types: struct code and raw limits
TYPES = {
    "int8": ("b", -128, 127),
    "uint8": ("B", 0, 255),
    "int16": ("h", -32768, 32767),
    "uint16": ("H", 0, 65535),
    "int32": ("i", -(2**31), 2**31 - 1),
    "uint32": ("I", 0, 2**32 - 1),
    "float32": ("f", None, None),
    "float64": ("d", None, None),
}


def one_signal(type_: str, endian: str = "little", byte: int = 1, scale: float = 1.0, offset: float = 0.0) -> Message:
    return Message("m", 0x100, signals=(Signal("x", byte, type_, endian, scale, offset),))


@pytest.mark.parametrize("endian", ["little", "big"])
@pytest.mark.parametrize("type_", list(TYPES))
def test_round_trip_against_struct(type_: str, endian: str) -> None:
    code, lo, hi = TYPES[type_]
    fmt = ("<" if endian == "little" else ">") + code
    values = [lo, hi, 0, 1, lo // 3 if lo is not None else -7] if lo is not None else [0.0, -1.5, 3.25e5, 1e-3, -7.0]
    msg = one_signal(type_, endian, byte=1)
    for value in values:
        expected = b"\x00" + struct.pack(fmt, value)
        payload = msg.encode({"x": value})
        assert payload == expected
        decoded = msg.decode(payload)["x"]
        assert decoded == struct.unpack(fmt, expected[1:])[0]


def test_scale_and_offset_against_struct() -> None:
    msg = one_signal("int16", "big", byte=0, scale=0.01, offset=5.0)
    # (7.344 - 5) / 0.01 = 234.4 -> 234
    assert msg.encode({"x": 7.344}) == struct.pack(">h", 234)
    assert msg.decode(struct.pack(">h", -100))["x"] == pytest.approx(-100 * 0.01 + 5.0)
    msg = one_signal("float32", "little", byte=0, scale=2.0, offset=-1.0)
    assert msg.encode({"x": 9.0}) == struct.pack("<f", 5.0)


def test_unused_bytes_are_zero_and_length_covers_signals() -> None:
    msg = Message("m", 1, signals=(Signal("a", 0, "uint8"), Signal("b", 4, "uint16", "big")))
    assert msg.length == 6
    assert msg.encode({"a": 0xFF, "b": 0x1234}) == bytes([0xFF, 0, 0, 0, 0x12, 0x34])


@pytest.mark.parametrize(
    ("type_", "value"),
    [("uint8", 256), ("uint8", -1), ("int8", 128), ("int16", -32769), ("uint32", 2.0**32), ("int32", 2.0**31)],
)
def test_out_of_range_names_message_and_signal(type_: str, value: float) -> None:
    msg = Message("speed_cmd", 5, signals=(Signal("rpm", 0, type_),))
    with pytest.raises(LayoutError, match=r"speed_cmd.*rpm"):
        msg.encode({"rpm": value})


def test_rounding_to_the_limit_is_accepted_but_beyond_is_not() -> None:
    msg = Message("m", 5, signals=(Signal("v", 0, "uint8", scale=0.5),))
    assert msg.encode({"v": 127.6}) == bytes([255])  # raw 255.2 rounds to 255
    with pytest.raises(LayoutError):
        msg.encode({"v": 127.8})  # raw 255.6 rounds to 256


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("type_", ["int8", "uint16", "int32", "uint32"])
def test_non_finite_refused_for_integers(type_: str, value: float) -> None:
    msg = Message("cmd", 5, signals=(Signal("pos", 0, type_),))
    with pytest.raises(LayoutError, match=r"cmd.*pos"):
        msg.encode({"pos": value})


def test_non_finite_allowed_for_floats_and_float32_overflow_refused() -> None:
    msg = one_signal("float32", byte=0)
    assert math.isnan(msg.decode(msg.encode({"x": math.nan}))["x"])
    assert msg.decode(msg.encode({"x": math.inf}))["x"] == math.inf
    with pytest.raises(LayoutError, match=r"\"m\".*\"x\""):
        msg.encode({"x": 1e39})


def test_missing_value_and_short_payload() -> None:
    msg = Message("fb", 0x181, signals=(Signal("a", 0, "float32"), Signal("b", 4, "uint16")))
    with pytest.raises(LayoutError, match=r"fb.*\"b\""):
        msg.encode({"a": 1.0})
    with pytest.raises(LayoutError, match=r"fb.*0x181.*5 bytes"):
        msg.decode(bytes(5))
    assert msg.decode(bytes(8)) == {"a": 0.0, "b": 0.0}  # extra bytes are ignored


@settings(max_examples=200, deadline=None)
@given(
    type_=st.sampled_from(["int8", "uint8", "int16", "uint16", "int32", "uint32"]),
    endian=st.sampled_from(["little", "big"]),
    scale=st.floats(1e-4, 1e3) | st.floats(-1e3, -1e-4),
    offset=st.floats(-1e4, 1e4),
    fraction=st.floats(0.0, 1.0),
)
def test_integer_round_trip_within_half_scale(
    type_: str, endian: str, scale: float, offset: float, fraction: float
) -> None:
    _, lo, hi = TYPES[type_]
    raw_lo, raw_hi = lo + 0.5, hi - 0.5  # stay clear of the rounding edges of the range
    physical_ends = sorted((raw_lo * scale + offset, raw_hi * scale + offset))
    value = physical_ends[0] + fraction * (physical_ends[1] - physical_ends[0])
    msg = one_signal(type_, endian, byte=2, scale=scale, offset=offset)
    decoded = msg.decode(msg.encode({"x": value}))["x"]
    # half a raw step, plus double-precision rounding of the arithmetic on numbers of this magnitude
    assert abs(decoded - value) <= abs(scale) / 2 + 8 * 2.0**-52 * (abs(value) + abs(offset))


@settings(max_examples=200, deadline=None)
@given(value=st.floats(-3e38, 3e38), endian=st.sampled_from(["little", "big"]))
def test_float32_round_trip_matches_struct(value: float, endian: str) -> None:
    fmt = "<f" if endian == "little" else ">f"
    msg = one_signal("float32", endian, byte=0)
    assert msg.decode(msg.encode({"x": value}))["x"] == struct.unpack(fmt, struct.pack(fmt, value))[0]


@settings(max_examples=100, deadline=None)
@given(value=st.floats(allow_nan=False), endian=st.sampled_from(["little", "big"]))
def test_float64_round_trip_is_exact(value: float, endian: str) -> None:
    msg = one_signal("float64", endian, byte=3)
    assert msg.decode(msg.encode({"x": value}))["x"] == value


# --------------------------------------------------------------------------------------------------------------
# message and signal construction
def test_signal_field_errors_name_the_field() -> None:
    with pytest.raises(LayoutError, match=r"signal \"s\": type: one of int8"):
        Signal("s", 0, "int12")
    with pytest.raises(LayoutError, match=r"endian"):
        Signal("s", 0, "int8", "middle")
    with pytest.raises(LayoutError, match=r"scale"):
        Signal("s", 0, "int8", scale=0.0)
    with pytest.raises(LayoutError, match=r"byte"):
        Signal("s", -1, "int8")


def test_message_rules() -> None:
    with pytest.raises(LayoutError, match=r"overlap"):
        Message("m", 1, signals=(Signal("a", 0, "float32"), Signal("b", 3, "uint8")))
    with pytest.raises(LayoutError, match=r"appears twice"):
        Message("m", 1, signals=(Signal("a", 0, "uint8"), Signal("a", 1, "uint8")))
    with pytest.raises(LayoutError, match=r"both"):
        Message("m", 1, signals=(Signal("a", 0, "uint8"),), data=b"\x01")
    with pytest.raises(LayoutError, match=r"id"):
        Message("m", 0x800, signals=(Signal("a", 0, "uint8"),))
    assert Message("m", 0x800, extended=True, data=b"").length == 0
    fixed = Message("en", 0x10, data=bytes([1, 2]))
    assert fixed.encode({}) == b"\x01\x02" and fixed.length == 2


# --------------------------------------------------------------------------------------------------------------
# layouts
DEFAULT_TOML_TABLE: dict[str, Any] = {
    "setpoint": {
        "id": 0x201,
        "extended": False,
        "signals": [
            {"name": "setpoint", "byte": 0, "type": "float32"},
            {"name": "counter", "byte": 4, "type": "uint16"},
        ],
    },
    "feedback": [
        {"id": 0x181, "signals": [{"name": "position", "byte": 0, "type": "float32"},
                                  {"name": "counter", "byte": 4, "type": "uint16"}]},
        {"id": 0x182, "signals": [{"name": "setpoint_echo", "byte": 0, "type": "float32"},
                                  {"name": "counter", "byte": 4, "type": "uint16"}]},
    ],
    "enable": {"id": 0x010, "data": [1]},
    "disable": {"id": 0x010, "data": [0]},
}


def test_default_layout_is_the_documented_example() -> None:
    layout = default_layout()
    assert layout == Layout.from_mapping(DEFAULT_TOML_TABLE, "x.toml")
    assert layout.setpoint.id == 0x201 and not layout.setpoint.extended
    assert [m.id for m in layout.feedback] == [0x181, 0x182]
    assert layout.channels == ("position", "setpoint_echo")
    assert layout.has_counter and layout.has_setpoint_counter and not layout.has_timestamp
    assert layout.counter_modulus == 2**16
    assert layout.enable is not None and layout.enable.encode({}) == b"\x01"
    assert layout.disable is not None and layout.disable.encode({}) == b"\x00"
    assert layout.setpoint.encode({"setpoint": 1.5, "counter": 258}) == struct.pack("<fH", 1.5, 258)
    layout.validate("can")
    layout.validate("serial-ascii")
    with pytest.raises(LayoutError, match=r"0x201 exceeds 0xFF"):
        layout.validate("serial-binary")


def test_whole_config_with_frames_key_is_accepted() -> None:
    assert Layout.from_mapping({"frames": DEFAULT_TOML_TABLE}, "x.toml") == default_layout()


def _with(path: list[Any], value: Any) -> dict[str, Any]:
    """Deep copy of the default table with one entry replaced (value None deletes it)."""
    import copy

    table = copy.deepcopy(DEFAULT_TOML_TABLE)
    node: Any = table
    for key in path[:-1]:
        node = node[key]
    if value is None:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return table


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        (["feedback", 1, "signals", 0, "type"], "int12",
         'bench.toml: frames.feedback[1].signals[0].type: one of int8, uint8, int16, uint16, int32, uint32, '
         'float32, float64, got "int12"'),
        (["feedback", 0, "signals", 0, "colour"], "red", "frames.feedback[0].signals[0]: unknown key(s) colour"),
        (["setpoint", "bitrate"], 5, "frames.setpoint: unknown key(s) bitrate"),
        (["feedback", 0, "id"], "0x181", "frames.feedback[0].id: a non-negative integer"),
        (["feedback", 0, "signals", 1, "byte"], None, "frames.feedback[0].signals[1].byte: missing"),
        (["enable", "data"], [1, 300], "frames.enable.data[1]: a byte 0..255, got 300"),
        (["setpoint", "extended"], "no", "frames.setpoint.extended: true or false"),
        (["setpoint", "signals", 0, "scale"], 0, "frames.setpoint.signals[0].scale: a finite non-zero number"),
        (["setpoint"], None, "frames.setpoint: missing"),
        (["mystery"], 1, "frames: unknown key(s) mystery"),
    ],
)
def test_config_errors_name_the_key_path(path: list[Any], value: Any, expected: str) -> None:
    with pytest.raises(LayoutError) as info:
        Layout.from_mapping(_with(path, value), "bench.toml")
    assert expected in str(info.value)


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        (["setpoint", "signals", 0, "name"], "target", 'needs a signal named "setpoint"'),
        (["feedback", 1, "signals"], [{"name": "setpoint_echo", "byte": 0, "type": "float32"}],
         'needs a "counter" signal'),
        (["feedback", 1, "signals", 0, "name"], "position", 'channel "position" appears in feedback messages'),
        (["feedback", 1, "id"], 0x181, "share id 0x181"),
        (["enable", "id"], 0x201, "share id 0x201"),
        (["feedback", 1, "signals", 1, "type"], "uint8", "same width"),
        (["feedback", 0, "signals", 1, "type"], "int16", '"counter": must be uint8 or uint16'),
        (["feedback", 0, "signals", 1, "byte"], 2, "overlap"),
    ],
)
def test_layout_rules(path: list[Any], value: Any, expected: str) -> None:
    with pytest.raises(LayoutError) as info:
        Layout.from_mapping(_with(path, value), "bench.toml")
    assert expected in str(info.value)
    assert str(info.value).startswith("bench.toml: frames")


def test_transport_limits() -> None:
    table = _with(["feedback", 0, "signals"], [
        {"name": "position", "byte": 0, "type": "float64"},
        {"name": "counter", "byte": 8, "type": "uint16"},
    ])
    layout = Layout.from_mapping(table, "")
    with pytest.raises(LayoutError, match=r"10 bytes exceeds 8 for can"):
        layout.validate("can")
    layout.validate("serial-ascii")
    with pytest.raises(LayoutError, match=r"transport"):
        layout.validate("usb")


def test_heartbeat_and_timestamp() -> None:
    table = _with(["heartbeat"], {"id": 0x700, "data": [5], "period_s": 0.1})
    table["feedback"][0]["signals"].append({"name": "timestamp_us", "byte": 6, "type": "uint32", "endian": "big"})
    with pytest.raises(LayoutError, match=r"10 bytes exceeds 8"):
        Layout.from_mapping(table, "").validate("can")
    table["feedback"][0]["signals"][2]["byte"] = 6
    table["feedback"][0]["signals"][2]["type"] = "uint16"
    layout = Layout.from_mapping(table, "")
    assert layout.heartbeat is not None and layout.heartbeat_period_s == 0.1
    assert layout.has_timestamp and layout.timestamp_modulus == 2**16
    assert layout.channels == ("position", "setpoint_echo")
    with pytest.raises(LayoutError, match=r"period_s"):
        Layout.from_mapping(_with(["heartbeat"], {"id": 0x700, "data": [5]}), "")
    bad = _with(["heartbeat"], {"id": 0x700, "data": [5], "period_s": 0.1})
    bad["feedback"][1]["signals"].append({"name": "timestamp_us", "byte": 6, "type": "int16"})
    with pytest.raises(LayoutError, match=r"timestamp_us"):
        Layout.from_mapping(bad, "")


# --------------------------------------------------------------------------------------------------------------
# DBC
DBC_TEXT = """VERSION ""

NS_ :

BS_:

BU_: CTRL INST

BO_ 513 SETPOINT: 8 INST
 SG_ SetpointPos : 0|32@1- (0.001,0) [-100000|100000] "mm" CTRL
 SG_ SeqCnt : 32|16@1+ (1,0) [0|65535] "" CTRL
 SG_ Mode : 48|8@1+ (1,0) [0|255] "" CTRL

BO_ 385 FEEDBACK1: 6 CTRL
 SG_ ActPos : 0|32@1- (0.001,0) [-2000000|2000000] "mm" INST
 SG_ SeqCnt : 32|16@1+ (1,0) [0|65535] "" INST

BO_ 2147484034 FEEDBACK2: 8 CTRL
 SG_ Current : 0|16@1- (0.01,0) [-300|300] "A" INST
 SG_ SeqCnt : 16|16@1+ (1,0) [0|65535] "" INST
 SG_ TimeUs : 32|32@1+ (1,0) [0|4294967295] "us" INST

BO_ 16 CONTROL: 1 INST
 SG_ Enable : 0|1@1+ (1,0) [0|1] "" CTRL
"""

DBC_FRAMES: dict[str, Any] = {
    "setpoint": {"message": "SETPOINT", "signals": {"setpoint": "SetpointPos", "counter": "SeqCnt"}},
    "feedback": [
        {"message": "FEEDBACK1", "signals": {"position": "ActPos", "counter": "SeqCnt"}},
        {"message": "FEEDBACK2", "signals": {"current": "Current", "counter": "SeqCnt", "timestamp_us": "TimeUs"}},
    ],
    "enable": {"message": "CONTROL", "values": {"Enable": 1}},
    "disable": {"message": "CONTROL", "values": {"Enable": 0}},
}


@pytest.fixture()
def dbc_file(tmp_path: Path) -> Path:
    path = tmp_path / "drive.dbc"
    path.write_text(DBC_TEXT)
    return path


def test_dbc_layout(dbc_file: Path) -> None:
    layout = Layout.from_dbc(dbc_file, DBC_FRAMES)
    config = dict(DBC_FRAMES, dbc="drive.dbc")
    assert Layout.from_mapping(config, str(dbc_file.parent / "bench.toml")).channels == layout.channels
    assert layout.channels == ("position", "current")
    assert layout.counter_modulus == 2**16 and layout.timestamp_modulus == 2**32
    assert layout.feedback[1].extended and layout.feedback[1].id == 0x182
    assert layout.enable is not None and layout.enable.data == b"\x01"
    assert layout.disable is not None and layout.disable.data == b"\x00"
    layout.validate("can")
    # setpoint payload, built independently: int32 raw in 0.001 mm, uint16 counter, unmapped Mode = 0
    assert layout.setpoint.encode({"setpoint": 12.345, "counter": 7}) == struct.pack("<iHB", 12345, 7, 0) + b"\x00"
    fb = layout.feedback[1].decode(struct.pack("<hHI", -250, 9, 4_000_000_000))
    assert fb == pytest.approx({"current": -2.5, "counter": 9.0, "timestamp_us": 4e9})
    with pytest.raises(LayoutError, match=r"SETPOINT.*setpoint"):
        layout.setpoint.encode({"setpoint": 3e6, "counter": 1})  # raw does not fit int32
    with pytest.raises(LayoutError, match=r"SETPOINT"):
        layout.setpoint.encode({"setpoint": 150_000.0, "counter": 1})  # beyond the DBC maximum
    with pytest.raises(LayoutError, match=r"SETPOINT.*setpoint"):
        layout.setpoint.encode({"setpoint": math.nan, "counter": 1})
    with pytest.raises(LayoutError, match=r"FEEDBACK1"):
        layout.feedback[0].decode(b"\x00\x01")


def test_dbc_matches_cantools_directly(dbc_file: Path) -> None:
    db = cantools.database.load_file(str(dbc_file))
    msg = DbcMessage(db.get_message_by_name("FEEDBACK1"), {"position": "ActPos", "counter": "SeqCnt"})
    payload = msg.encode({"position": -1.5, "counter": 65535})
    assert db.decode_message("FEEDBACK1", payload) == pytest.approx({"ActPos": -1.5, "SeqCnt": 65535})
    assert msg.integer_modulus("counter") == 2**16 and msg.integer_modulus("position") is None


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        (["setpoint", "message"], "NOPE", "frames.setpoint.message: no message \"NOPE\""),
        (["feedback", 0, "signals", "position"], "Missing", "has no signal \"Missing\""),
        (["enable", "values", "Turbo"], 1, "frames.enable.values.Turbo: no signal"),
        (["feedback", 0, "id"], 5, "frames.feedback[0]: unknown key(s) id"),
    ],
)
def test_dbc_config_errors(dbc_file: Path, path: list[Any], value: Any, expected: str) -> None:
    import copy

    table: Any = copy.deepcopy(DBC_FRAMES)
    node = table
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(LayoutError) as info:
        Layout.from_dbc(dbc_file, table, "bench.toml")
    assert expected in str(info.value)


def test_missing_dbc_file(tmp_path: Path) -> None:
    with pytest.raises(LayoutError, match=r"frames.dbc: cannot load"):
        Layout.from_mapping(dict(DBC_FRAMES, dbc="absent.dbc"), str(tmp_path / "bench.toml"))
