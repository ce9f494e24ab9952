"""Experiment configuration: one TOML file, validated on load against declarative table schemas.

Each top-level table is a frozen dataclass registered in :data:`TABLES`. Its fields carry validation metadata
(``field(metadata={...})``); one generic converter (:func:`build_table`) turns a TOML table into the dataclass.
Supported field types: ``float`` (integers accepted and converted, booleans rejected, must be finite), ``int``
(booleans rejected), ``str``, ``bool``, ``dict`` (a TOML table, checked by the table's own ``validate``),
``tuple[float, ...]``, ``tuple[int, ...]``, ``tuple[str, ...]`` (from TOML
arrays) and ``T | None`` of those (absent means ``None``).

Field metadata keys:

- ``doc``: description with units.
- ``min`` / ``max`` with ``min_exclusive`` / ``max_exclusive``: bounds (for arrays, on every element).
- ``nonzero``: the value (or every element) must differ from 0.
- ``choices``: the allowed values.
- ``non_empty`` / ``unique``: arrays only; at least one element / no element repeated.
- ``only_if``: ``(other_field, allowed_values)``; giving this key explicitly while ``other_field`` holds another
  value is an error (``plant.friction: not a parameter of model "lag"``).

A table class may define ``validate(self, where)`` for cross-field checks: it raises :class:`FieldError` naming the
field at fault, and ``where(name)`` gives the dotted key a field's value came from (for use in messages). A table
class with ``TABLE_OPTIONAL = True`` yields ``None`` when absent instead of being built from defaults.

Every error is a :class:`ConfigError` whose text is one line: ``<source>: <dotted key>: <problem>``.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import re
import tomllib
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from bodebench.core.rules import CRITERIA
from bodebench.io.bench_config import BENCH_TABLES, CaseCheckError, check_bench_case

__all__ = [
    "AnalysisConfig",
    "CaseConfig",
    "ConfigError",
    "ExcitationConfig",
    "ExperimentConfig",
    "FieldError",
    "PlantConfig",
    "TABLES",
    "build_table",
    "load_config",
    "parse_config",
]

T = TypeVar("T")

CASE_NAME_PATTERN = re.compile(r"[A-Za-z0-9_.-]+")
"""Allowed case names (they become directory names); "." and ".." are refused as well."""

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_META_KEYS = frozenset(
    {"doc", "min", "min_exclusive", "max", "max_exclusive", "nonzero", "choices", "non_empty", "unique", "only_if"}
)
_TOP_LEVEL_KEYS = ("title", "cases")


class ConfigError(ValueError):
    """A configuration problem. ``str(err)`` is one line naming the source and the dotted key at fault.

    ``key`` is the dotted key when the problem concerns one key, else ``None``.
    """

    def __init__(self, message: str, key: str | None = None) -> None:
        super().__init__(message)
        self.key = key


class FieldError(ValueError):
    """Raised by a table's ``validate`` hook: ``key`` is the field at fault, ``problem`` what is wrong with it."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"{key}: {problem}")
        self.key = key
        self.problem = problem


# --------------------------------------------------------------------------------------------------- the tables


_HYDRAULIC = ("model", ("hydraulic",))


@dataclass(frozen=True)
class PlantConfig:
    """The simulated plant (METHOD.md section 2); all quantities dimensionless unless stated."""

    model: str = field(
        metadata={
            "choices": ("coulomb", "linear", "lag", "hydraulic"),
            "doc": "plant model: coulomb, linear, lag or hydraulic (electrohydraulic position drive, SI units)",
        }
    )
    mass: float = field(
        default=1.0,
        metadata={"min": 0, "min_exclusive": True, "only_if": ("model", ("coulomb", "linear")), "doc": "mass m"},
    )
    stiffness: float = field(
        default=1.0,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": ("model", ("coulomb", "linear")),
            "doc": "position (spring) load K_p",
        },
    )
    friction: float = field(
        default=0.0,
        metadata={"min": 0, "only_if": ("model", ("coulomb",)), "doc": "dry-friction force F_ct"},
    )
    damping_ratio: float = field(
        default=0.0,
        metadata={
            "min": 0,
            "only_if": ("model", ("coulomb", "linear")),
            "doc": "viscous damping ratio zeta (dimensionless)",
        },
    )
    time_constant: float = field(
        default=1.0,
        metadata={"min": 0, "min_exclusive": True, "only_if": ("model", ("lag",)), "doc": "lag time constant, s"},
    )
    gain: float = field(
        default=1.0,
        metadata={"nonzero": True, "only_if": ("model", ("lag",)), "doc": "lag static gain (dimensionless)"},
    )

    # The electrohydraulic position drive (sim/hydraulic.py); defaults: a ~10 kN industrial cylinder.
    supply_pressure: float = field(
        default=210e5,
        metadata={"min": 0, "min_exclusive": True, "only_if": _HYDRAULIC, "doc": "supply pressure P_s, Pa"},
    )
    valve_gain: float = field(
        default=1.8e-7,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": _HYDRAULIC,
            "doc": "valve flow gain K_q in Q_L = K_q x_v sqrt((P_s - sign(x_v) P_L)/2), m^3/(s*Pa^0.5)",
        },
    )
    valve_natural_frequency_hz: float = field(
        default=150.0,
        metadata={"min": 0, "min_exclusive": True, "only_if": _HYDRAULIC, "doc": "servo valve natural frequency, Hz"},
    )
    valve_damping_ratio: float = field(
        default=0.7,
        metadata={"min": 0, "only_if": _HYDRAULIC, "doc": "servo valve damping ratio (dimensionless)"},
    )
    piston_area: float = field(
        default=5e-4,
        metadata={"min": 0, "min_exclusive": True, "only_if": _HYDRAULIC, "doc": "piston area A_p, m^2"},
    )
    total_volume: float = field(
        default=1.5e-4,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": _HYDRAULIC,
            "doc": "total oil volume V_t of both chambers and lines, m^3",
        },
    )
    bulk_modulus: float = field(
        default=1.4e9,
        metadata={"min": 0, "min_exclusive": True, "only_if": _HYDRAULIC, "doc": "effective bulk modulus, Pa"},
    )
    leakage: float = field(
        default=2e-12,
        metadata={"min": 0, "only_if": _HYDRAULIC, "doc": "cross-port leakage coefficient C_l, m^3/(s*Pa)"},
    )
    piston_mass: float = field(
        default=40.0,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": _HYDRAULIC,
            "doc": "moving mass (piston, rod, load), kg",
        },
    )
    load_stiffness: float = field(
        default=0.0,
        metadata={"min": 0, "only_if": _HYDRAULIC, "doc": "load spring stiffness K_load, N/m"},
    )
    viscous_damping: float = field(
        default=2000.0,
        metadata={"min": 0, "only_if": _HYDRAULIC, "doc": "viscous damping b, N*s/m"},
    )
    coulomb_friction: float = field(
        default=150.0,
        metadata={"min": 0, "only_if": _HYDRAULIC, "doc": "Coulomb (stick-slip) friction force F_c, N"},
    )
    loop_gain: float = field(
        default=60.0,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": _HYDRAULIC,
            "doc": "position-loop gain K_loop: normalised valve current per metre of position error, 1/m",
        },
    )


@dataclass(frozen=True)
class ExcitationConfig:
    """The sine input: amplitude and the frequencies to measure at."""

    amplitude: float = field(
        metadata={"min": 0, "min_exclusive": True, "doc": "input amplitude A_i (A_F for the friction link)"}
    )
    frequencies_hz: tuple[float, ...] = field(
        metadata={
            "min": 0,
            "min_exclusive": True,
            "non_empty": True,
            "unique": True,
            "doc": "measurement frequencies, Hz",
        }
    )


@dataclass(frozen=True)
class AnalysisConfig:
    """Harmonic analysis and stopping rule (METHOD.md section 1)."""

    harmonics: tuple[int, ...] = field(
        default=(1,),
        metadata={"min": 1, "non_empty": True, "unique": True, "doc": "harmonic numbers k to measure"},
    )
    tolerance_percent: float = field(
        default=0.01,
        metadata={"min": 0, "min_exclusive": True, "doc": "stopping tolerance eps, percent"},
    )
    skip_periods: int = field(default=1, metadata={"min": 0, "doc": "periods n_k not analysed"})
    criterion: str = field(default="adaptive", metadata={"choices": CRITERIA, "doc": "stopping rule"})
    window: int = field(default=5, metadata={"min": 2, "doc": "window length l, periods"})
    max_periods: int = field(default=20000, metadata={"min": 1, "doc": "period limit per frequency"})
    steps_per_period: int = field(default=200, metadata={"min": 8, "doc": "integration steps per period K_f"})
    settle_periods: int = field(
        default=50, metadata={"min": 0, "doc": 'periods discarded (criterion "fixed" only)'}
    )
    average_periods: int = field(
        default=50, metadata={"min": 1, "doc": 'periods averaged (criterion "fixed" only)'}
    )

    def validate(self, where: Callable[[str], str]) -> None:
        """Cross-field checks; raises :class:`FieldError`."""
        if self.max_periods <= self.skip_periods:
            raise FieldError("max_periods", f"must be > {where('skip_periods')} ({self.skip_periods})")


TABLES: dict[str, type] = {
    "plant": PlantConfig,
    "excitation": ExcitationConfig,
    "analysis": AnalysisConfig,
    **BENCH_TABLES,
}
"""Registered top-level tables, by TOML name. Every registered table may also appear inside ``[cases.NAME]``."""


@dataclass(frozen=True)
class CaseConfig:
    """One validated case: base tables merged with the case's overrides.

    ``raw`` is the merged, validated configuration as a JSON-serialisable dict (defaults filled in; plant keys that
    the model does not use left out). ``tables`` holds every registered table's object by name (``None`` for an
    absent optional table).
    """

    name: str
    plant: PlantConfig
    excitation: ExcitationConfig
    analysis: AnalysisConfig
    raw: dict = field(hash=False)
    tables: dict = field(default_factory=dict, compare=False, repr=False)


@dataclass(frozen=True)
class ExperimentConfig:
    """A loaded configuration file. ``has_cases`` is False when the file had no ``[cases]`` table (then there is
    one case, named after the file stem)."""

    path: Path
    title: str
    cases: tuple[CaseConfig, ...]
    has_cases: bool


# --------------------------------------------------------------------------------------------------- formatting


def _quote(text: str) -> str:
    """A string as a one-line TOML basic string."""
    return json.dumps(text, ensure_ascii=False)


def _clip(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _key_path(*parts: object) -> str:
    """Join key parts into a TOML dotted key, quoting parts that are not bare keys."""
    out: list[str] = []
    for part in parts:
        text = str(part)
        out.append(text if _BARE_KEY.fullmatch(text) else _quote(text))
    return ".".join(out)


def _show_number(value: int | float) -> str:
    if isinstance(value, int) and not isinstance(value, bool):
        if value.bit_length() > 96:
            return f"({value.bit_length()}-bit integer)"
        return str(value)
    return repr(float(value))


def _show(value: Any) -> str:
    if isinstance(value, str):
        return _clip(_quote(value))
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return _show_number(value)
    return _clip(repr(value))


def _describe(value: Any) -> str:
    """A value's TOML type and, for scalars, the value itself (one line)."""
    if isinstance(value, bool):
        return f"boolean {_show(value)}"
    if isinstance(value, int):
        return f"integer {_show(value)}"
    if isinstance(value, float):
        return f"float {_show(value)}"
    if isinstance(value, str):
        return f"string {_show(value)}"
    if isinstance(value, Mapping):
        return "table"
    if isinstance(value, (list, tuple)):
        return f"array of {len(value)}"
    if isinstance(value, datetime.datetime):
        return f"date-time {value.isoformat()}"
    if isinstance(value, datetime.date):
        return f"date {value.isoformat()}"
    if isinstance(value, datetime.time):
        return f"time {value.isoformat()}"
    if value is None:
        return "nothing (None)"
    return f"{type(value).__name__} {_show(value)}"


# --------------------------------------------------------------------------------------------------- the schema


@dataclass(frozen=True)
class _Field:
    name: str
    base: type  # float, int, str or bool
    array: bool
    optional: bool
    required: bool
    default: Any
    meta: Mapping[str, Any]


_SCHEMAS: dict[type, tuple[_Field, ...]] = {}
_EXPECTED = {float: "a number", int: "an integer", str: "a string", bool: "a boolean", dict: "a table"}


def _schema(cls: type) -> tuple[_Field, ...]:
    """The field descriptions of table dataclass ``cls`` (checked once, then cached)."""
    cached = _SCHEMAS.get(cls)
    if cached is not None:
        return cached
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints = typing.get_type_hints(cls)
    out: list[_Field] = []
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        optional = False
        origin = typing.get_origin(tp)
        if origin in (typing.Union, types.UnionType):
            members = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(members) != 1 or len(typing.get_args(tp)) != 2:
                raise TypeError(f"{cls.__name__}.{f.name}: only 'T | None' unions are supported")
            tp, optional = members[0], True
            origin = typing.get_origin(tp)
        array = False
        if origin is tuple:
            args = typing.get_args(tp)
            if len(args) != 2 or args[1] is not Ellipsis:
                raise TypeError(f"{cls.__name__}.{f.name}: only tuple[X, ...] arrays are supported")
            tp, array = args[0], True
        if tp not in _EXPECTED:
            raise TypeError(f"{cls.__name__}.{f.name}: unsupported field type {tp!r}")
        unknown = set(f.metadata) - _META_KEYS
        if unknown:
            raise TypeError(f"{cls.__name__}.{f.name}: unknown metadata keys {sorted(unknown)}")
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if required and optional:
            default: Any = None
            required = False
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = f.default
        out.append(_Field(f.name, tp, array, optional, required, default, f.metadata))
    result = tuple(out)
    _SCHEMAS[cls] = result
    return result


class _Fault(Exception):
    """A problem at a dotted key; turned into a :class:`ConfigError` with the source prepended."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"{key}: {problem}")
        self.key = key
        self.problem = problem


def _convert_scalar(base: type, value: Any, meta: Mapping[str, Any], key: str) -> Any:
    """Type-check and range-check one scalar; raises :class:`_Fault` naming ``key``."""
    if base is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _Fault(key, f"expected a number, got {_describe(value)}")
        try:
            converted: Any = float(value)
        except OverflowError:
            converted = math.inf
        if not math.isfinite(converted):
            raise _Fault(key, f"must be a finite number, got {_show(value)}")
    elif base is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _Fault(key, f"expected an integer, got {_describe(value)}")
        converted = int(value)
    elif base is str:
        if not isinstance(value, str):
            raise _Fault(key, f"expected a string, got {_describe(value)}")
        converted = value
    elif base is dict:
        if not isinstance(value, Mapping):
            raise _Fault(key, f"expected a table, got {_describe(value)}")
        return dict(value)
    else:
        if not isinstance(value, bool):
            raise _Fault(key, f"expected a boolean, got {_describe(value)}")
        converted = value

    shown = _show(converted)
    if "min" in meta:
        lo = meta["min"]
        if meta.get("min_exclusive", False):
            if not converted > lo:
                raise _Fault(key, f"must be > {_show(lo)}, got {shown}")
        elif not converted >= lo:
            raise _Fault(key, f"must be >= {_show(lo)}, got {shown}")
    if "max" in meta:
        hi = meta["max"]
        if meta.get("max_exclusive", False):
            if not converted < hi:
                raise _Fault(key, f"must be < {_show(hi)}, got {shown}")
        elif not converted <= hi:
            raise _Fault(key, f"must be <= {_show(hi)}, got {shown}")
    if meta.get("nonzero", False) and converted == 0:
        raise _Fault(key, f"must be != 0, got {shown}")
    choices = meta.get("choices")
    if choices is not None and converted not in choices:
        allowed = ", ".join(_show(c) for c in choices)
        raise _Fault(key, f"must be one of {allowed}, got {shown}")
    return converted


def _convert(spec: _Field, value: Any, key: str) -> Any:
    """Convert one given value of field ``spec``; ``key`` is the dotted key it came from."""
    if not spec.array:
        return _convert_scalar(spec.base, value, spec.meta, key)
    if not isinstance(value, (list, tuple)):
        raise _Fault(key, f"expected an array, got {_describe(value)}")
    items = tuple(_convert_scalar(spec.base, item, spec.meta, f"{key}[{i}]") for i, item in enumerate(value))
    if spec.meta.get("non_empty", False) and not items:
        raise _Fault(key, "must not be empty")
    if spec.meta.get("unique", False):
        first: dict[Any, int] = {}
        for i, item in enumerate(items):
            if item in first:
                raise _Fault(f"{key}[{i}]", f"duplicate of {key}[{first[item]}] ({_show(item)})")
            first[item] = i
    return items


def _build(
    cls: type[T],
    given: Mapping[str, Any],
    origin: Callable[[str], str],
    missing_at: tuple[str, ...],
    table: str,
) -> T:
    """Build table ``cls`` from the merged keys ``given``.

    ``origin(key)`` is the dotted key a given value came from, ``missing_at`` the key parts of the table under which
    missing required keys are reported, ``table`` the table's own name (for keys left at their defaults).
    """
    specs = _schema(cls)
    by_name = {s.name: s for s in specs}
    for key in given:
        if key not in by_name:
            raise _Fault(origin(key), "unknown key")
    values: dict[str, Any] = {}
    for spec in specs:
        if spec.name in given:
            values[spec.name] = _convert(spec, given[spec.name], origin(spec.name))
        elif spec.required:
            raise _Fault(_key_path(*missing_at, spec.name), "missing")
        else:
            values[spec.name] = spec.default

    def where(name: str) -> str:
        return origin(name) if name in given else _key_path(table, name)

    for spec in specs:
        condition = spec.meta.get("only_if")
        if condition is None or spec.name not in given:
            continue
        other, allowed = condition
        if values[other] not in allowed:
            raise _Fault(where(spec.name), f"not a parameter of {other} {_show(values[other])}")
    obj = cls(**values)
    hook = getattr(obj, "validate", None)
    if hook is not None:
        try:
            hook(where)
        except FieldError as err:
            raise _Fault(where(err.key), err.problem) from None
    return obj


def _applies(spec: _Field, obj: Any) -> bool:
    condition = spec.meta.get("only_if")
    if condition is None:
        return True
    other, allowed = condition
    return getattr(obj, other) in allowed


def _to_raw(obj: Any) -> dict[str, Any]:
    """A built table as a JSON-serialisable dict (arrays as lists; inapplicable and ``None`` fields left out)."""
    out: dict[str, Any] = {}
    for spec in _schema(type(obj)):
        value = getattr(obj, spec.name)
        if value is None or not _applies(spec, obj):
            continue
        out[spec.name] = list(value) if spec.array else value
    return out


def build_table(cls: type[T], data: Mapping[str, Any], table: str, source: str = "<config>") -> T:
    """Convert one TOML table ``data`` to table dataclass ``cls``; errors name ``source`` and ``table.key``."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: {_key_path(table)}: expected a table, got {_describe(data)}", table)
    try:
        return _build(cls, data, lambda k: _key_path(table, k), (table,), table)
    except _Fault as fault:
        raise _error(source, fault) from None


# --------------------------------------------------------------------------------------------------- the loader


def _error(source: str, fault: _Fault) -> ConfigError:
    return ConfigError(f"{source}: {fault.key}: {fault.problem}", fault.key)


def _expect_table(value: Any, *parts: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise _Fault(_key_path(*parts), f"expected a table, got {_describe(value)}")
    return value


def _default_case_name(source: str) -> str:
    stem = Path(source).stem
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", stem).strip("_.")
    return name or "config"


def _build_case(
    name: str,
    base: Mapping[str, Mapping[str, Any]],
    overrides: Mapping[str, Mapping[str, Any]],
    case_parts: tuple[str, ...],
    source: str,
) -> CaseConfig:
    """Merge ``overrides`` (the case's sub-tables, from ``case_parts``) over ``base`` and validate the result."""
    built: dict[str, Any] = {}
    raw: dict[str, Any] = {}
    for table, cls in TABLES.items():
        base_keys = base.get(table, {})
        case_keys = overrides.get(table, {})
        if table not in base and table not in overrides and getattr(cls, "TABLE_OPTIONAL", False):
            built[table] = None
            continue
        merged = {**base_keys, **case_keys}

        def origin(key: str, table: str = table, case_keys: Mapping[str, Any] = case_keys) -> str:
            if key in case_keys:
                return _key_path(*case_parts, table, key)
            return _key_path(table, key)

        obj = _build(cls, merged, origin, (*case_parts, table), table)
        built[table] = obj
        raw[table] = _to_raw(obj)
    case = CaseConfig(
        name=name,
        plant=built["plant"],
        excitation=built["excitation"],
        analysis=built["analysis"],
        raw=raw,
        tables=built,
    )

    def key(table: str, name: str) -> str:
        return _key_path(*case_parts, table, name) if name in overrides.get(table, {}) else _key_path(table, name)

    try:
        check_bench_case(case, key, source)
    except CaseCheckError as err:
        raise _Fault(err.key, err.problem) from None
    return case


def _parse(data: Mapping[str, Any], source: str) -> ExperimentConfig:
    if not isinstance(data, Mapping):
        raise _Fault("(top level)", f"expected a table, got {_describe(data)}")
    for key in data:
        if key not in _TOP_LEVEL_KEYS and key not in TABLES:
            raise _Fault(_key_path(key), "unknown key")

    title = Path(source).stem
    if "title" in data:
        title = _convert_scalar(str, data["title"], {}, "title")

    base: dict[str, Mapping[str, Any]] = {}
    for table in TABLES:
        if table in data:
            base[table] = _expect_table(data[table], table)

    if "cases" not in data:
        case = _build_case(_default_case_name(source), base, {}, (), source)
        return ExperimentConfig(path=Path(source), title=title, cases=(case,), has_cases=False)

    cases = _expect_table(data["cases"], "cases")
    if not cases:
        raise _Fault("cases", "must contain at least one case")
    folded: dict[str, str] = {}
    overrides: dict[str, dict[str, Mapping[str, Any]]] = {}
    for name, body in cases.items():
        label = _key_path("cases", name)
        if not isinstance(name, str) or not CASE_NAME_PATTERN.fullmatch(name) or name in (".", ".."):
            raise _Fault(label, 'case name must match [A-Za-z0-9_.-]+ and not be "." or ".."')
        if name.lower() in folded:
            raise _Fault(label, f"same directory name as {_key_path('cases', folded[name.lower()])} "
                                "on case-insensitive file systems")
        folded[name.lower()] = name
        body = _expect_table(body, "cases", name)
        for key in body:
            if key not in TABLES:
                raise _Fault(_key_path("cases", name, key), "unknown key")
        overrides[name] = {table: _expect_table(sub, "cases", name, table) for table, sub in body.items()}

    # Every value in the base tables is checked even if each case overrides it.
    for table, keys in base.items():
        by_name = {s.name: s for s in _schema(TABLES[table])}
        for key, value in keys.items():
            if key not in by_name:
                raise _Fault(_key_path(table, key), "unknown key")
            _convert(by_name[key], value, _key_path(table, key))

    built = tuple(_build_case(name, base, overrides[name], ("cases", name), source) for name in cases)
    return ExperimentConfig(path=Path(source), title=title, cases=built, has_cases=True)


def parse_config(data: Mapping[str, Any], source: str = "<config>") -> ExperimentConfig:
    """Validate an already parsed configuration (a dict shaped like the TOML file).

    ``source`` names the configuration in error messages; its stem names the single case of a file without
    ``[cases]`` and is the default title. Raises :class:`ConfigError`.
    """
    try:
        return _parse(data, source)
    except _Fault as fault:
        raise _error(source, fault) from None


_TOML_POSITION = re.compile(r"\s*\(at line (\d+), column (\d+)\)$")
_TOML_END = re.compile(r"\s*\(at end of document\)$")


def _toml_error(source: str, text: str, err: tomllib.TOMLDecodeError) -> ConfigError:
    message = " ".join(str(err).split())
    found = _TOML_POSITION.search(message)
    if found:
        line, column = int(found.group(1)), int(found.group(2))
        message = message[: found.start()]
    else:
        lines = text.split("\n")
        line, column = len(lines), len(lines[-1]) + 1
        message = _TOML_END.sub("", message)
    return ConfigError(f"{source}: line {line} column {column}: {message}")


def load_config(path: str | Path) -> ExperimentConfig:
    """Read and validate a TOML configuration file. Raises :class:`ConfigError` (one-line message)."""
    source = str(path)
    try:
        blob = Path(path).read_bytes()
    except OSError as err:
        raise ConfigError(f"{source}: cannot read: {err.strerror or err}") from None
    try:
        text = blob.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{source}: cannot read: not UTF-8 (byte {err.start})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise _toml_error(source, text, err) from None
    return parse_config(data, source)
