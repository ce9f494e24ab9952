"""Tests of the configuration loader (instrument/io/config.py)."""

from __future__ import annotations

import copy
import errno
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bodebench.core.rules import CRITERIA
from bodebench.io import config as cfg
from bodebench.io.config import (
    AnalysisConfig,
    CaseConfig,
    ConfigError,
    ExcitationConfig,
    ExperimentConfig,
    PlantConfig,
    build_table,
    load_config,
    parse_config,
)

SRC = "configs/x.toml"

# Which plant parameters each model uses (from the specification, not from the code's metadata).
MODEL_PARAMS: dict[str, set[str]] = {
    "coulomb": {"mass", "stiffness", "friction", "damping_ratio"},
    "linear": {"mass", "stiffness", "damping_ratio"},
    "lag": {"time_constant", "gain"},
}
ALL_PARAMS = {"mass", "stiffness", "friction", "damping_ratio", "time_constant", "gain"}

DEFAULT_ANALYSIS = AnalysisConfig(
    harmonics=(1,),
    tolerance_percent=0.01,
    skip_periods=1,
    criterion="adaptive",
    window=5,
    max_periods=20000,
    steps_per_period=200,
    settle_periods=50,
    average_periods=50,
)


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def minimal() -> dict[str, Any]:
    return {
        "plant": {"model": "coulomb", "mass": 2.533e-4, "friction": 0.008},
        "excitation": {"amplitude": 0.01, "frequencies_hz": [1.0, 10.0, 100.0]},
    }


def error_of(data: Any, source: str = SRC) -> str:
    with pytest.raises(ConfigError) as info:
        parse_config(data, source)
    message = str(info.value)
    assert "\n" not in message
    return message


# --------------------------------------------------------------------------------------------- valid files


PAPER_TOML = """\
title = "Coulomb link, 2013 experiment"

[plant]
model = "coulomb"
mass = 2.533e-4
stiffness = 1          # integer accepted for a float
friction = 0.008
damping_ratio = 0.0

[excitation]
amplitude = 0.01
frequencies_hz = [1, 1.3, 10.03, 100]

[analysis]
harmonics = [1, 2]
tolerance_percent = 0.01
skip_periods = 2
criterion = "full"
window = 7
max_periods = 5000
steps_per_period = 400
"""


def test_valid_file_round_trips_with_defaults(tmp_path: Path) -> None:
    path = write(tmp_path, "paper.toml", PAPER_TOML)
    exp = load_config(path)
    plant = PlantConfig(
        model="coulomb", mass=2.533e-4, stiffness=1.0, friction=0.008, damping_ratio=0.0,
        time_constant=1.0, gain=1.0,
    )
    excitation = ExcitationConfig(amplitude=0.01, frequencies_hz=(1.0, 1.3, 10.03, 100.0))
    analysis = AnalysisConfig(
        harmonics=(1, 2), tolerance_percent=0.01, skip_periods=2, criterion="full", window=7,
        max_periods=5000, steps_per_period=400, settle_periods=50, average_periods=50,
    )
    raw = {
        "plant": {"model": "coulomb", "mass": 2.533e-4, "stiffness": 1.0, "friction": 0.008, "damping_ratio": 0.0},
        "excitation": {"amplitude": 0.01, "frequencies_hz": [1.0, 1.3, 10.03, 100.0]},
        "analysis": {
            "harmonics": [1, 2], "tolerance_percent": 0.01, "skip_periods": 2, "criterion": "full", "window": 7,
            "max_periods": 5000, "steps_per_period": 400, "settle_periods": 50, "average_periods": 50,
            "max_gap_cycles": 0.25, "max_discarded_percent": 50.0, "fold_decay": 2.0,
        },
    }
    expected = ExperimentConfig(
        path=path,
        title="Coulomb link, 2013 experiment",
        cases=(CaseConfig(name="paper", source=path, plant=plant, excitation=excitation, analysis=analysis,
                          raw=raw),),
        has_cases=False,
    )
    assert exp == expected
    case = exp.cases[0]
    assert case.raw == raw
    assert json.loads(json.dumps(case.raw)) == raw
    assert type(case.plant.stiffness) is float
    assert all(type(f) is float for f in case.excitation.frequencies_hz)
    assert case.source == path


def test_defaults_filled_when_optional_tables_absent(tmp_path: Path) -> None:
    path = write(
        tmp_path, "lag run.toml",
        '[plant]\nmodel = "lag"\n[excitation]\namplitude = 2\nfrequencies_hz = [0.5]\n',
    )
    exp = load_config(path)
    case = exp.cases[0]
    assert case.plant == PlantConfig(model="lag")
    assert (case.plant.time_constant, case.plant.gain) == (1.0, 1.0)
    assert case.analysis == DEFAULT_ANALYSIS
    # Parameters that the lag model does not use stay out of the sidecar dict.
    assert case.raw["plant"] == {"model": "lag", "time_constant": 1.0, "gain": 1.0}
    assert case.raw["analysis"]["max_periods"] == 20000
    # The case is named after the file stem, made directory-safe; the title defaults to the stem.
    assert case.name == "lag_run"
    assert exp.title == "lag run"


def test_parse_config_matches_load_config(tmp_path: Path) -> None:
    import tomllib

    path = write(tmp_path, "paper.toml", PAPER_TOML)
    from_file = load_config(path)
    from_dict = parse_config(tomllib.loads(PAPER_TOML), str(path))
    assert from_dict == from_file


# --------------------------------------------------------------------------------------------- reading errors


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "absent.toml"
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}: cannot read: {os.strerror(errno.ENOENT)}"


def test_directory_is_not_readable(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(tmp_path)
    assert str(info.value).startswith(f"{tmp_path}: cannot read: ")


def test_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_bytes(b'title = "\xff"\n')
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}: cannot read: not UTF-8 (byte 9)"


def test_toml_syntax_error_reports_line_and_column(tmp_path: Path) -> None:
    # The second "=" on line 3 sits in column 8 ("mass = " is 7 characters).
    path = write(tmp_path, "x.toml", '[plant]\nmodel = "lag"\nmass = = 1\n')
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}: line 3 column 8: Invalid value"


def test_toml_error_at_end_of_document(tmp_path: Path) -> None:
    # The file ends after the newline of line 2, i.e. at line 3 column 1.
    path = write(tmp_path, "x.toml", "[excitation]\nfrequencies_hz = [1,\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: line 3 column 1: ")
    assert "(at" not in message


def test_toml_duplicate_table_error(tmp_path: Path) -> None:
    path = write(tmp_path, "x.toml", "[plant]\nmodel = 'lag'\n[plant]\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value).startswith(f"{path}: line 3 column ")


# --------------------------------------------------------------------------------------------- value errors


def with_value(table: str, key: str, value: Any, model: str = "coulomb") -> dict[str, Any]:
    data = minimal()
    data["plant"] = {"model": model}
    data.setdefault(table, {})[key] = value
    return data


VALUE_ERRORS = [
    # (table, key, value, model, expected message after the source)
    ("plant", "mass", -1.0, "coulomb", "plant.mass: must be > 0, got -1.0"),
    ("plant", "mass", -1, "linear", "plant.mass: must be > 0, got -1.0"),
    ("plant", "mass", 0, "coulomb", "plant.mass: must be > 0, got 0.0"),
    ("plant", "stiffness", -2.5, "coulomb", "plant.stiffness: must be > 0, got -2.5"),
    ("plant", "friction", -0.1, "coulomb", "plant.friction: must be >= 0, got -0.1"),
    ("plant", "damping_ratio", -0.05, "linear", "plant.damping_ratio: must be >= 0, got -0.05"),
    ("plant", "time_constant", 0.0, "lag", "plant.time_constant: must be > 0, got 0.0"),
    ("plant", "gain", 0, "lag", "plant.gain: must be != 0, got 0.0"),
    ("plant", "model", "spring", "coulomb",
     'plant.model: must be one of "coulomb", "linear", "lag", "hydraulic", "valve", got "spring"'),
    ("excitation", "amplitude", 0.0, "coulomb", "excitation.amplitude: must be > 0, got 0.0"),
    ("excitation", "frequencies_hz", [], "coulomb", "excitation.frequencies_hz: must not be empty"),
    ("excitation", "frequencies_hz", [1, 2, 3, -4], "coulomb",
     "excitation.frequencies_hz[3]: must be > 0, got -4.0"),
    ("excitation", "frequencies_hz", [1, 2, 3, 0], "coulomb",
     "excitation.frequencies_hz[3]: must be > 0, got 0.0"),
    ("excitation", "frequencies_hz", [5, 10, 5.0], "coulomb",
     "excitation.frequencies_hz[2]: duplicate of excitation.frequencies_hz[0] (5.0)"),
    ("analysis", "harmonics", [], "coulomb", "analysis.harmonics: must not be empty"),
    ("analysis", "harmonics", [1, 0], "coulomb", "analysis.harmonics[1]: must be >= 1, got 0"),
    ("analysis", "harmonics", [2, 1, 2], "coulomb",
     "analysis.harmonics[2]: duplicate of analysis.harmonics[0] (2)"),
    ("analysis", "tolerance_percent", 0, "coulomb", "analysis.tolerance_percent: must be > 0, got 0.0"),
    ("analysis", "skip_periods", -1, "coulomb", "analysis.skip_periods: must be >= 0, got -1"),
    ("analysis", "window", 1, "coulomb", "analysis.window: must be >= 2, got 1"),
    ("analysis", "max_periods", 0, "coulomb", "analysis.max_periods: must be >= 1, got 0"),
    ("analysis", "steps_per_period", 7, "coulomb", "analysis.steps_per_period: must be >= 8, got 7"),
    ("analysis", "settle_periods", -3, "coulomb", "analysis.settle_periods: must be >= 0, got -3"),
    ("analysis", "average_periods", 0, "coulomb", "analysis.average_periods: must be >= 1, got 0"),
    ("analysis", "criterion", "sometimes", "coulomb",
     "analysis.criterion: must be one of " + ", ".join(f'"{c}"' for c in CRITERIA) + ', got "sometimes"'),
    # Wrong types.
    ("excitation", "amplitude", "abc", "coulomb", 'excitation.amplitude: expected a number, got string "abc"'),
    ("excitation", "amplitude", True, "coulomb", "excitation.amplitude: expected a number, got boolean true"),
    ("excitation", "amplitude", [1.0], "coulomb", "excitation.amplitude: expected a number, got array of 1"),
    ("excitation", "amplitude", {"a": 1}, "coulomb", "excitation.amplitude: expected a number, got table"),
    ("excitation", "amplitude", math.nan, "coulomb", "excitation.amplitude: must be a finite number, got nan"),
    ("excitation", "amplitude", math.inf, "coulomb", "excitation.amplitude: must be a finite number, got inf"),
    ("excitation", "frequencies_hz", 10.0, "coulomb",
     "excitation.frequencies_hz: expected an array, got float 10.0"),
    ("excitation", "frequencies_hz", [1, "2", 3], "coulomb",
     'excitation.frequencies_hz[1]: expected a number, got string "2"'),
    ("excitation", "frequencies_hz", [1, 2, False], "coulomb",
     "excitation.frequencies_hz[2]: expected a number, got boolean false"),
    ("analysis", "skip_periods", 1.5, "coulomb", "analysis.skip_periods: expected an integer, got float 1.5"),
    ("analysis", "skip_periods", 2.0, "coulomb", "analysis.skip_periods: expected an integer, got float 2.0"),
    ("analysis", "window", True, "coulomb", "analysis.window: expected an integer, got boolean true"),
    ("analysis", "window", "5", "coulomb", 'analysis.window: expected an integer, got string "5"'),
    ("analysis", "harmonics", [1, 2.0], "coulomb",
     "analysis.harmonics[1]: expected an integer, got float 2.0"),
    ("analysis", "criterion", 3, "coulomb", "analysis.criterion: expected a string, got integer 3"),
    ("plant", "model", False, "coulomb", "plant.model: expected a string, got boolean false"),
]


@pytest.mark.parametrize(("table", "key", "value", "model", "expected"), VALUE_ERRORS)
def test_value_errors(table: str, key: str, value: Any, model: str, expected: str) -> None:
    assert error_of(with_value(table, key, value, model)) == f"{SRC}: {expected}"


def test_error_from_file_names_file_and_key(tmp_path: Path) -> None:
    text = '[plant]\nmodel = "linear"\nmass = -1\n[excitation]\namplitude = 1\nfrequencies_hz = [1]\n'
    path = write(tmp_path, "x.toml", text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}: plant.mass: must be > 0, got -1.0"
    assert info.value.key == "plant.mass"
    assert isinstance(info.value, ValueError)


def test_cross_field_max_periods_must_exceed_skip_periods() -> None:
    data = minimal()
    data["analysis"] = {"skip_periods": 3, "max_periods": 3}
    assert error_of(data) == f"{SRC}: analysis.max_periods: must be > analysis.skip_periods (3)"
    data["analysis"] = {"skip_periods": 3, "max_periods": 4}
    assert parse_config(data).cases[0].analysis.max_periods == 4
    # Against the default max_periods of 20000.
    data["analysis"] = {"skip_periods": 20000}
    assert error_of(data) == f"{SRC}: analysis.max_periods: must be > analysis.skip_periods (20000)"


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ({"excitation": {"amplitude": 1, "frequencies_hz": [1]}},
         "plant: missing: an offline experiment needs a [plant] table (only a real drive needs none)"),
        ({"plant": {"mass": 1.0}, "excitation": {"amplitude": 1, "frequencies_hz": [1]}}, "plant.model: missing"),
        ({"plant": {"model": "lag"}},
         "excitation.frequencies_hz: missing (give frequencies_hz = [...] or frequencies = {start_hz, stop_hz, "
         "per_decade})"),
        ({"plant": {"model": "lag"}, "excitation": {"amplitude": 1}},
         "excitation.frequencies_hz: missing (give frequencies_hz = [...] or frequencies = {start_hz, stop_hz, "
         "per_decade})"),
        ({"plant": {"model": "lag"}, "excitation": {"frequencies_hz": [1]}},
         "excitation.amplitude: missing (give amplitude, amplitudes = [...] (one per frequency) or "
         "amplitude_profile = {frequencies_hz, amplitudes})"),
    ],
)
def test_missing_required_keys(data: dict[str, Any], expected: str) -> None:
    assert error_of(data) == f"{SRC}: {expected}"


def test_title_must_be_a_string() -> None:
    data = minimal()
    data["title"] = 42
    assert error_of(data) == f"{SRC}: title: expected a string, got integer 42"


# --------------------------------------------------------------------------------------------- unknown keys


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (lambda d: d.update(plan={"model": "lag"}), "plan: unknown key"),
        (lambda d: d.update(tolerance=0.1), "tolerance: unknown key"),
        (lambda d: d.update({"odd key": 1}), '"odd key": unknown key'),
        (lambda d: d["plant"].update(mas=1.0), "plant.mas: unknown key"),
        (lambda d: d["excitation"].update(frequency=[1.0]), "excitation.frequency: unknown key"),
        (lambda d: d.update(analysis={"eps": 0.01}), "analysis.eps: unknown key"),
        (lambda d: d.update(cases={"a": {"plantt": {}}}), "cases.a.plantt: unknown key"),
        (lambda d: d.update(cases={"a": {"title": "x"}}), "cases.a.title: unknown key"),
        (lambda d: d.update(cases={"a": {"plant": {"mas": 1.0}}}), "cases.a.plant.mas: unknown key"),
        (lambda d: d.update(cases={"a": {"analysis": {"eps": 1.0}}}), "cases.a.analysis.eps: unknown key"),
    ],
)
def test_unknown_keys_at_every_level(mutate: Any, expected: str) -> None:
    data = minimal()
    mutate(data)
    assert error_of(data) == f"{SRC}: {expected}"


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (lambda d: d.update(plant=3), "plant: expected a table, got integer 3"),
        (lambda d: d.update(analysis=[1]), "analysis: expected a table, got array of 1"),
        (lambda d: d.update(cases="a"), 'cases: expected a table, got string "a"'),
        (lambda d: d.update(cases={}), "cases: must contain at least one case"),
        (lambda d: d.update(cases={"a": 1.5}), "cases.a: expected a table, got float 1.5"),
        (lambda d: d.update(cases={"a": {"plant": "lag"}}), 'cases.a.plant: expected a table, got string "lag"'),
    ],
)
def test_tables_must_be_tables(mutate: Any, expected: str) -> None:
    data = minimal()
    mutate(data)
    assert error_of(data) == f"{SRC}: {expected}"


@pytest.mark.parametrize("name", ["a b", "..", ".", "", "x/y", "é"])
def test_bad_case_names(name: str) -> None:
    data = minimal()
    data["cases"] = {name: {}}
    message = error_of(data)
    assert message == (
        f'{SRC}: cases.{json.dumps(name, ensure_ascii=False)}: case name must match [A-Za-z0-9_.-]+ '
        'and not be "." or ".."'
    )


def test_case_names_differing_only_in_letter_case_are_refused() -> None:
    data = minimal()
    data["cases"] = {"Run1": {}, "run1": {}}
    assert error_of(data) == f"{SRC}: cases.run1: same directory name as cases.Run1 on case-insensitive file systems"


# --------------------------------------------------------------------------------------------- model parameters


IRRELEVANT = sorted((model, key) for model, used in MODEL_PARAMS.items() for key in ALL_PARAMS - used)


@pytest.mark.parametrize(("model", "key"), IRRELEVANT)
def test_parameter_not_used_by_model_is_an_error(model: str, key: str) -> None:
    data = with_value("plant", key, 0.5, model)
    assert error_of(data) == f'{SRC}: plant.{key}: not a parameter of model "{model}"'


@pytest.mark.parametrize("model", sorted(MODEL_PARAMS))
def test_parameters_used_by_model_are_accepted(model: str) -> None:
    data = minimal()
    data["plant"] = {"model": model, **{key: 0.5 for key in MODEL_PARAMS[model]}}
    case = parse_config(data).cases[0]
    assert all(getattr(case.plant, key) == 0.5 for key in MODEL_PARAMS[model])
    assert set(case.raw["plant"]) == {"model"} | MODEL_PARAMS[model]


# --------------------------------------------------------------------------------------------- cases


CASES_TOML = """\
title = "friction sweep"

[plant]
model = "coulomb"
mass = 2.533e-4

[excitation]
amplitude = 0.01
frequencies_hz = [1, 10, 100]

[analysis]
harmonics = [1, 2]
max_periods = 9000

[cases.fbar_0_1]
plant.friction = 0.001

[cases."fbar_0.8"]
plant.friction = 0.008
analysis.harmonics = [1]

[cases.lin.plant]
model = "linear"
friction = 0.0095
"""


def test_case_overrides_merge_key_by_key(tmp_path: Path) -> None:
    path = write(tmp_path, "paper.toml", CASES_TOML.replace("friction = 0.0095\n", "damping_ratio = 0.05\n"))
    # Base keys a case's model does not use are errors, so friction is set per Coulomb case, not in the base.
    exp = load_config(path)
    assert exp.has_cases is True
    assert exp.title == "friction sweep"
    assert [c.name for c in exp.cases] == ["fbar_0_1", "fbar_0.8", "lin"]
    first, second, third = exp.cases
    assert first.plant == PlantConfig(model="coulomb", mass=2.533e-4, friction=0.001)
    assert first.analysis.harmonics == (1, 2)
    assert first.analysis.max_periods == 9000
    assert second.plant == PlantConfig(model="coulomb", mass=2.533e-4, friction=0.008)
    assert second.analysis.harmonics == (1,)
    assert second.analysis.max_periods == 9000  # untouched base key survives the override of another key
    assert second.excitation == ExcitationConfig(amplitude=0.01, frequencies_hz=(1.0, 10.0, 100.0))
    assert third.plant.model == "linear"
    assert third.plant.damping_ratio == 0.05
    assert third.raw["plant"] == {"model": "linear", "mass": 2.533e-4, "stiffness": 1.0, "damping_ratio": 0.05}
    assert second.raw["analysis"]["harmonics"] == [1]
    assert second.raw["analysis"]["tolerance_percent"] == 0.01
    for case in exp.cases:
        assert json.loads(json.dumps(case.raw)) == case.raw


def test_base_value_irrelevant_to_case_model_names_base_key(tmp_path: Path) -> None:
    # The linear case inherits the base friction: the error names the base key.
    data = {
        "plant": {"model": "coulomb", "friction": 0.001},
        "excitation": {"amplitude": 0.01, "frequencies_hz": [1]},
        "cases": {"ok": {}, "lin": {"plant": {"model": "linear"}}},
    }
    assert error_of(data, "paper.toml") == 'paper.toml: plant.friction: not a parameter of model "linear"'


def test_case_value_irrelevant_to_model_names_case_key(tmp_path: Path) -> None:
    path = write(tmp_path, "paper.toml", CASES_TOML)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f'{path}: cases.lin.plant.friction: not a parameter of model "linear"'


def test_case_error_names_case_key_path() -> None:
    data = minimal()
    data["cases"] = {"fbar_0_8": {"plant": {"friction": -0.1}}}
    assert error_of(data, "paper.toml") == "paper.toml: cases.fbar_0_8.plant.friction: must be >= 0, got -0.1"
    data["cases"] = {"a": {"excitation": {"frequencies_hz": [1, "x"]}}}
    assert error_of(data, "paper.toml") == (
        'paper.toml: cases.a.excitation.frequencies_hz[1]: expected a number, got string "x"'
    )
    data["cases"] = {"fbar.0.8": {"analysis": {"window": 1}}}
    assert error_of(data, "paper.toml") == 'paper.toml: cases."fbar.0.8".analysis.window: must be >= 2, got 1'


def test_bad_base_value_is_reported_even_if_every_case_overrides_it() -> None:
    data = minimal()
    data["plant"]["mass"] = -5.0
    data["cases"] = {"a": {"plant": {"mass": 1.0}}, "b": {"plant": {"mass": 2.0}}}
    assert error_of(data) == f"{SRC}: plant.mass: must be > 0, got -5.0"
    data["plant"]["mass"] = 3.0
    assert [c.plant.mass for c in parse_config(data).cases] == [1.0, 2.0]


def test_cross_field_error_in_case_names_where_values_came_from() -> None:
    data = minimal()
    data["analysis"] = {"max_periods": 100}
    data["cases"] = {"a": {"analysis": {"skip_periods": 100}}}
    assert error_of(data) == f"{SRC}: analysis.max_periods: must be > cases.a.analysis.skip_periods (100)"
    data["analysis"] = {"skip_periods": 10}
    data["cases"] = {"a": {"analysis": {"max_periods": 10}}}
    assert error_of(data) == f"{SRC}: cases.a.analysis.max_periods: must be > analysis.skip_periods (10)"


def test_required_key_missing_in_a_case() -> None:
    data = {
        "excitation": {"amplitude": 1, "frequencies_hz": [1]},
        "cases": {"a": {"plant": {"model": "lag"}}, "b": {"plant": {"gain": 2.0}}},
    }
    assert error_of(data) == f"{SRC}: cases.b.plant.model: missing"
    data["plant"] = {"model": "lag"}
    assert [c.plant.gain for c in parse_config(data).cases] == [1.0, 2.0]


def test_cases_do_not_modify_input_dict() -> None:
    data = minimal()
    data["cases"] = {"a": {"plant": {"friction": 0.002}}}
    before = copy.deepcopy(data)
    parse_config(data)
    assert data == before


# --------------------------------------------------------------------------------------------- extensibility


@dataclass(frozen=True)
class _PortConfig:
    channel: str = field(metadata={"doc": "bus channel"})
    bitrate: int = field(default=500000, metadata={"min": 10000, "max": 1000000, "doc": "bit/s"})
    fd: bool = field(default=False, metadata={"doc": "CAN FD"})
    node: int | None = field(default=None, metadata={"min": 1, "max": 127, "max_exclusive": False})
    names: tuple[str, ...] = field(default=("a",), metadata={"choices": ("a", "b", "c"), "unique": True})

    TABLE_OPTIONAL = True


def test_build_table_generic_types() -> None:
    port = build_table(_PortConfig, {"channel": "can0", "fd": True, "node": 5, "names": ["b", "c"]}, "can", "x")
    assert port == _PortConfig(channel="can0", bitrate=500000, fd=True, node=5, names=("b", "c"))
    assert build_table(_PortConfig, {"channel": "can0"}, "can").node is None
    cases = [
        ({"channel": "can0", "bitrate": 2_000_000}, "x: can.bitrate: must be <= 1000000, got 2000000"),
        ({"channel": "can0", "fd": 1}, "x: can.fd: expected a boolean, got integer 1"),
        ({"channel": "can0", "node": 0}, "x: can.node: must be >= 1, got 0"),
        ({"channel": "can0", "names": ["a", "d"]}, 'x: can.names[1]: must be one of "a", "b", "c", got "d"'),
        ({"channel": 0}, "x: can.channel: expected a string, got integer 0"),
        ({}, "x: can.channel: missing"),
    ]
    for data, expected in cases:
        with pytest.raises(ConfigError) as info:
            build_table(_PortConfig, data, "can", "x")
        assert str(info.value) == expected


def test_an_optional_table_is_loaded_and_overridable_per_case() -> None:
    data = minimal()
    data["bench"] = {"transport": "can", "rate_hz": 1000.0}
    data["safety"] = {"max_amplitude": 1.0}
    data["simulator"] = {}
    data["excitation"]["frequencies_hz"] = [1.0]
    data["can"] = {"interface": "virtual", "bitrate": 500000}
    data["cases"] = {"a": {}, "b": {"can": {"bitrate": 250000}}}
    exp = parse_config(data)
    assert exp.cases[0].can == cfg.CanConfig(interface="virtual", bitrate=500000)
    assert exp.cases[1].can is not None and exp.cases[1].can.bitrate == 250000
    assert exp.cases[1].raw["can"] == {"interface": "virtual", "channel": "", "bitrate": 250000, "fd": False,
                                       "context": "", "options": {}}
    # An optional table that is absent yields None.
    del data["cases"]
    del data["simulator"]
    assert parse_config({**minimal(), "plant": data["plant"]}).cases[0].can is None
    data["can"]["channel"] = "can0"
    assert parse_config(data).cases[0].simulator is None


# --------------------------------------------------------------------------------------------- property test


FLOAT_BOUNDS: dict[tuple[str, str], str] = {
    ("plant", "mass"): "pos",
    ("plant", "stiffness"): "pos",
    ("plant", "friction"): "nonneg",
    ("plant", "damping_ratio"): "nonneg",
    ("plant", "time_constant"): "pos",
    ("plant", "gain"): "nonzero",
    ("excitation", "amplitude"): "pos",
    ("analysis", "tolerance_percent"): "pos",
}
INT_MIN: dict[str, int] = {
    "skip_periods": 0, "window": 2, "max_periods": 1, "steps_per_period": 8,
    "settle_periods": 0, "average_periods": 1,
}

positive = st.floats(min_value=1e-6, max_value=1e6)


@st.composite
def valid_tables(draw: st.DrawFn, model: str | None = None) -> dict[str, Any]:
    if model is None:
        model = draw(st.sampled_from(sorted(MODEL_PARAMS)))
    plant: dict[str, Any] = {"model": model}
    for key in sorted(MODEL_PARAMS[model]):
        if draw(st.booleans()):
            kind = FLOAT_BOUNDS[("plant", key)]
            if kind == "nonzero":
                plant[key] = draw(st.one_of(positive, positive.map(lambda x: -x)))
            elif kind == "nonneg":
                plant[key] = draw(st.one_of(st.just(0.0), positive, st.integers(0, 10)))
            else:
                plant[key] = draw(st.one_of(positive, st.integers(1, 10)))
    excitation = {
        "amplitude": draw(positive),
        "frequencies_hz": draw(st.lists(st.floats(min_value=1e-3, max_value=1e6), min_size=1, max_size=5,
                                        unique=True)),
    }
    analysis: dict[str, Any] = {}
    if draw(st.booleans()):
        analysis["harmonics"] = draw(st.lists(st.integers(1, 9), min_size=1, max_size=4, unique=True))
    if draw(st.booleans()):
        analysis["tolerance_percent"] = draw(st.floats(min_value=1e-6, max_value=99.0))
    if draw(st.booleans()):
        analysis["criterion"] = draw(st.sampled_from(CRITERIA))
    if draw(st.booleans()):
        analysis["skip_periods"] = draw(st.integers(0, 100))
    if draw(st.booleans()):
        analysis["max_periods"] = draw(st.integers(101, 30000))
    for key in ("window", "steps_per_period", "settle_periods", "average_periods"):
        if draw(st.booleans()):
            least = 8 * 9 if key == "steps_per_period" else INT_MIN[key]  # 8 steps a period of harmonic 9
            analysis[key] = draw(st.integers(least, least + 500))
    return {"plant": plant, "excitation": excitation, "analysis": analysis}


@st.composite
def valid_configs(draw: st.DrawFn) -> dict[str, Any]:
    data = draw(valid_tables())
    if draw(st.booleans()):
        data["title"] = draw(st.text(max_size=10))
    if draw(st.booleans()):
        names = draw(st.lists(st.from_regex(r"[a-z0-9_]{1,6}", fullmatch=True), min_size=1, max_size=3, unique=True))
        cases: dict[str, Any] = {}
        for name in names:
            # A case overrides a random subset of the (valid) base keys with other valid values of the same model.
            other = draw(valid_tables(data["plant"]["model"]))
            body: dict[str, Any] = {}
            for table in ("plant", "excitation", "analysis"):
                keys = [k for k in other[table] if k != "model" and draw(st.booleans())]
                if table == "analysis":
                    keys = [k for k in keys if k not in ("skip_periods", "max_periods")]
                if keys:
                    body[table] = {k: other[table][k] for k in keys}
            cases[name] = body
        data["cases"] = cases
    return data


def leaves(data: dict[str, Any]) -> list[tuple[tuple[str, ...], str]]:
    """Paths to every value of the schema tables (base and cases), with the key name."""
    out: list[tuple[tuple[str, ...], str]] = []
    for table in ("plant", "excitation", "analysis"):
        out += [((table, key), key) for key in data.get(table, {})]
    for name, body in data.get("cases", {}).items():
        for table, keys in body.items():
            out += [(("cases", name, table, key), key) for key in keys]
    return out


bad_values = st.one_of(
    st.text(max_size=5),
    st.booleans(),
    st.none(),
    st.just([]),
    st.lists(st.one_of(st.integers(), st.floats(), st.text(max_size=3)), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.integers(min_value=-3, max_value=0),
    st.floats(min_value=-10.0, max_value=0.0),
    st.just(10**400),
)


@pytest.mark.slow
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=valid_configs(), pick=st.integers(min_value=0), bad=bad_values, element=st.booleans())
def test_mutated_config_fails_cleanly_naming_the_key(data: dict[str, Any], pick: int, bad: Any, element: bool) -> None:
    exp = parse_config(copy.deepcopy(data), "prop.toml")  # the unmutated config is valid
    assert len(exp.cases) == max(1, len(data.get("cases", {})))

    paths = leaves(data)
    path, key = paths[pick % len(paths)]
    target: Any = data
    for part in path[:-1]:
        target = target[part]
    if element and isinstance(target[path[-1]], list) and target[path[-1]]:
        target[path[-1]][pick % len(target[path[-1]])] = bad
    else:
        target[path[-1]] = bad
    try:
        result = parse_config(data, "prop.toml")
    except ConfigError as err:
        message = str(err)
        assert "\n" not in message
        assert message.startswith("prop.toml: ")
        assert key in message
    else:
        for case in result.cases:
            assert json.loads(json.dumps(case.raw)) == case.raw


# ------------------------------------------------------------------------------ property test: frame layouts, DBC

BENCH: dict[str, Any] = {
    "plant": {"model": "coulomb", "mass": 2.533e-4, "stiffness": 1.0, "friction": 0.008},
    "excitation": {"amplitude": 0.01, "frequencies_hz": [2.0, 20.0]},
    "analysis": {"harmonics": [1]},
    "bench": {"transport": "can", "rate_hz": 1000, "timebase": "counter"},
    "can": {"interface": "virtual", "channel": "x"},
    "safety": {"max_amplitude": 0.02},
}
INT_TYPES = ("int8", "uint8", "int16", "uint16", "int32", "uint32")


@st.composite
def valid_frames(draw: st.DrawFn) -> dict[str, Any]:
    """A [frames] table that loads: a setpoint, one to three feedback messages joined by a counter (with a CRC
    byte at times), enable/disable told apart by their data, at times a heartbeat and a drive watchdog."""
    counter = draw(st.sampled_from(["uint8", "uint16"]))
    csize = 1 if counter == "uint8" else 2
    setpoint = {"id": 0x201, "signals": [{"name": "setpoint", "byte": 0, "type": "float32",
                                          "endian": draw(st.sampled_from(["little", "big"]))},
                                         {"name": "counter", "byte": 4, "type": counter}]}
    feedback = []
    for i, name in enumerate(["position", "setpoint_echo", "current"][:draw(st.integers(1, 3))]):
        kind = draw(st.sampled_from(["float32", "int16", "int32"]))
        sig: dict[str, Any] = {"name": name, "byte": 0, "type": kind}
        if kind != "float32":
            sig["scale"] = draw(st.floats(1e-6, 1e3).map(lambda x: float(f"{x:.6g}")))
            sig["offset"] = draw(st.floats(-10, 10).map(lambda x: float(f"{x:.6g}")))
        byte = 2 if kind == "int16" else 4
        signals = [sig, {"name": "counter", "byte": byte, "type": counter}]
        if draw(st.booleans()):
            signals.append({"name": "crc", "byte": byte + csize, "type": "uint8"})
        feedback.append({"id": 0x181 + i, "signals": signals})
    frames: dict[str, Any] = {"setpoint": setpoint, "feedback": feedback,
                              "enable": {"id": 0x10, "data": [1]}, "disable": {"id": 0x10, "data": [0]}}
    if draw(st.booleans()):
        frames["heartbeat"] = {"id": 0x700, "data": [5], "period_s": 0.1}
        frames["drive_watchdog_s"] = draw(st.sampled_from([0.0, 0.5, 1.0]))
    return frames


def frame_leaves(frames: dict[str, Any]) -> list[tuple[tuple[Any, ...], str]]:
    """Paths to every scalar a user types in [frames], with its key name."""
    out: list[tuple[tuple[Any, ...], str]] = []

    def walk(node: Any, path: tuple[Any, ...], key: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, (*path, k), k)
        elif isinstance(node, list) and node and isinstance(node[0], dict):
            for i, v in enumerate(node):
                walk(v, (*path, i), key)
        else:
            out.append((path, key))

    walk(frames, (), "frames")
    return out


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(frames=valid_frames(), pick=st.integers(min_value=0), bad=bad_values)
def test_mutated_frame_layout_fails_cleanly_naming_the_key(frames: dict[str, Any], pick: int, bad: Any) -> None:
    data = copy.deepcopy(BENCH)
    data["frames"] = copy.deepcopy(frames)
    parse_config(copy.deepcopy(data), "prop.toml")  # the unmutated layout loads
    path, key = frame_leaves(data["frames"])[pick % len(frame_leaves(data["frames"]))]
    target: Any = data["frames"]
    for part in path[:-1]:
        target = target[part]
    target[path[-1]] = bad
    try:
        parse_config(data, "prop.toml")
    except ConfigError as err:
        message = str(err)
        # rooted in [frames], or in the key that needs what the mutation took away (a measured channel)
        assert "\n" not in message and message.startswith(("prop.toml: frames", "prop.toml: bench.")), message
        assert key in message or f"{path[-1]}" in message or "share id" in message or "overlap" in message \
            or "same frame" in message or "exceeds" in message or "counter" in message \
            or "is not a feedback channel" in message, message  # a renamed measured channel


DBC_HEAD = 'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: CTRL INST\n\n'


@st.composite
def dbc_files(draw: st.DrawFn) -> tuple[str, bool]:
    """A DBC file with a setpoint and a feedback message, its position signal drawn at random (byte order and
    sign characters, scale among them), and whether the loader must refuse it."""
    order = draw(st.sampled_from(["0", "1", "1", "9", "2"]))
    sign = draw(st.sampled_from(["+", "-"]))
    scale = draw(st.sampled_from(["0", "0.001", "1", "-0.5", "2e-3"]))
    length = draw(st.sampled_from([16, 32]))
    start = 0 if order != "0" else 7  # big-endian signals start at the most significant bit of their first byte
    text = (DBC_HEAD + 'BO_ 513 SETPOINT: 6 INST\n SG_ SetpointPos : 0|32@1- (0.001,0) [-1000|1000] "mm" CTRL\n'
            ' SG_ SeqCnt : 32|16@1+ (1,0) [0|65535] "" CTRL\n\n'
            f'BO_ 385 FEEDBACK1: 6 CTRL\n SG_ ActPos : {start}|{length}@{order}{sign} ({scale},0) [0|0] "mm" INST\n'
            ' SG_ SeqCnt : 32|16@1+ (1,0) [0|65535] "" INST\n')
    return text, order not in "01" or scale == "0"


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                 HealthCheck.function_scoped_fixture])
@given(dbc=dbc_files())
def test_dbc_signals_load_or_fail_cleanly_naming_the_key(dbc: tuple[str, bool], tmp_path: Path) -> None:
    text, refused = dbc
    (tmp_path / "drive.dbc").write_text(text)
    data = copy.deepcopy(BENCH)
    data["frames"] = {"dbc": "drive.dbc",
                      "setpoint": {"message": "SETPOINT", "signals": {"setpoint": "SetpointPos", "counter": "SeqCnt"}},
                      "feedback": [{"message": "FEEDBACK1", "signals": {"position": "ActPos", "counter": "SeqCnt"}}]}
    try:
        parse_config(data, str(tmp_path / "prop.toml"))
    except ConfigError as err:
        message = str(err)
        assert "\n" not in message and message.startswith(f"{tmp_path / 'prop.toml'}: frames"), message
        assert refused or "ActPos" in message, message  # a good signal may still not fit (e.g. overlap), by name
    else:
        assert not refused, text


@pytest.mark.parametrize("table, key, value, message", [
    ("excitation", "frequencies_hz", [5e-324, 1.0], "excitation.frequencies_hz[0]: 4.94066e-324 Hz is below 0.001 Hz"),
    ("excitation", "frequencies_hz", [1.0, 1e300], "excitation.frequencies_hz[1]: 1e+300 Hz is above 1e+06 Hz"),
    ("analysis", "tolerance_percent", 65536, "analysis.tolerance_percent: must be < 100, got 65536.0"),
    ("analysis", "tolerance_percent", 100, "analysis.tolerance_percent: must be < 100, got 100.0"),
])
def test_nonsense_that_once_loaded_is_one_line_naming_the_key(table: str, key: str, value: Any, message: str) -> None:
    data = {"plant": {"model": "lag"}, "excitation": {"amplitude": 1.0, "frequencies_hz": [1.0]}, "analysis": {}}
    data[table][key] = value
    with pytest.raises(ConfigError) as info:
        parse_config(data, "nonsense.toml")
    assert str(info.value).startswith(f"nonsense.toml: {message}")


def test_a_bench_rate_beyond_any_bus_is_refused() -> None:
    from test_bench_config import error

    assert "bench.rate_hz: must be <= 100000.0, got 9.2e+18" in error(lambda d: d["bench"].update(rate_hz=9.2e18))


def test_a_real_drive_s_configuration_and_its_bench_session_import_no_simulator() -> None:
    """A real drive's configuration (configs/real_can.toml) loaded and the bench session imported, in a fresh
    interpreter: no plant, no numba and no scipy come with them, so a real drive's sweep starts without the
    simulator's import time. (A configuration with a [simulator] builds its plant to check the channels the
    simulated drive can send.)"""
    import subprocess
    import sys

    code = ("import sys, bodebench.io.config, bodebench.bench.session, bodebench.bench.procedure; "
            f"bodebench.io.config.load_config({str(Path(__file__).parent.parent / 'configs' / 'real_can.toml')!r}); "
            "print(' '.join(sorted(m for m in sys.modules if m.startswith('bodebench.sim.') "
            "or m.split('.')[0] in ('numba', 'scipy'))))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert set(loaded) <= {"bodebench.sim.faults", "bodebench.sim.loop_config"}, loaded
