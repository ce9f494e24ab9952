"""The configuration schema: frozen dataclasses whose fields carry their own validation.

One generic converter (:func:`build_table`) turns a TOML table into a table dataclass. Supported field types:
``float`` (integers accepted and converted, booleans rejected, must be finite), ``int`` (booleans rejected),
``str``, ``bool``, ``dict`` (a TOML table, checked by the table's own ``validate``), another table dataclass
(a nested TOML table, converted by the same rules; its keys are reported as ``outer.inner.key``),
``tuple[float, ...]``, ``tuple[int, ...]``, ``tuple[str, ...]`` (from TOML arrays) and ``T | None`` of those
(absent means ``None``).

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
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

__all__ = ["ConfigError", "FieldError", "KeyDoc", "build_table", "check_value", "describe_table"]

T = TypeVar("T")

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_META_KEYS = frozenset(
    {"doc", "min", "min_exclusive", "max", "max_exclusive", "nonzero", "choices", "non_empty", "unique", "only_if"}
)

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
        if tp not in _EXPECTED and not (dataclasses.is_dataclass(tp) and isinstance(tp, type) and not array):
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


@dataclass(frozen=True)
class KeyDoc:
    """One configuration key as its field declares it: ``key`` (dotted, within its table), ``type`` (as TOML
    writes it), ``default`` (as TOML writes it; "required" or "none"), ``rule`` (its bounds, choices and array
    rules in words, empty for none), ``doc`` and ``only_if`` (the models or modes it belongs to, in words)."""

    key: str
    type: str
    default: str
    rule: str
    doc: str
    only_if: str


_TOML_TYPES = {float: "number", int: "integer", str: "string", bool: "boolean", dict: "table"}


def _rule(meta: Mapping[str, Any], array: bool) -> str:
    """The bounds, choices and array rules of a field's metadata, in words (as the loader enforces them)."""
    parts = []
    lo, hi = meta.get("min"), meta.get("max")
    lo_op = ">" if meta.get("min_exclusive", False) else ">="
    hi_op = "<" if meta.get("max_exclusive", False) else "<="
    if lo is not None and hi is not None:
        parts.append(f"{lo_op} {_show(lo)} and {hi_op} {_show(hi)}")
    elif lo is not None:
        parts.append(f"{lo_op} {_show(lo)}")
    elif hi is not None:
        parts.append(f"{hi_op} {_show(hi)}")
    if meta.get("nonzero", False):
        parts.append("!= 0")
    if meta.get("choices") is not None:
        parts.append("one of " + ", ".join(_show(c) for c in meta["choices"]))
    if array and meta.get("non_empty", False):
        parts.append("at least one element")
    if array and meta.get("unique", False):
        parts.append("no element twice")
    if array and parts:
        parts[0] = "each " + parts[0] if not parts[0].startswith(("at least", "no element")) else parts[0]
    return "; ".join(parts)


def describe_table(cls: type, prefix: str = "") -> list[KeyDoc]:
    """Every key of table dataclass ``cls`` (nested tables' keys as ``inner.key``), from the same field
    declarations :func:`build_table` enforces."""
    out: list[KeyDoc] = []
    for spec in _schema(cls):
        key = f"{prefix}{spec.name}"
        if dataclasses.is_dataclass(spec.base):
            out.append(KeyDoc(key, "table", "none" if spec.optional else "{}", "", str(spec.meta.get("doc", "")), ""))
            out.extend(describe_table(spec.base, f"{key}."))
            continue
        kind = _TOML_TYPES[spec.base]
        kind = f"array of {kind}s" if spec.array else kind
        if spec.required:
            default = "required"
        elif spec.default is None:
            default = "none"
        elif spec.array:
            default = "[" + ", ".join(_show(v) for v in spec.default) + "]"
        elif isinstance(spec.default, dict):
            default = "{}" if not spec.default else json.dumps(spec.default)
        else:
            default = _show(spec.default)
        only_if = ""
        if "only_if" in spec.meta:
            other, allowed = spec.meta["only_if"]
            only_if = f"{other} = " + " or ".join(_show(a) for a in allowed)
        out.append(KeyDoc(key, kind, default, _rule(spec.meta, spec.array), str(spec.meta.get("doc", "")), only_if))
    return out


def check_value(cls: type, name: str, value: Any) -> str | None:
    """What is wrong with ``value`` for key ``name`` of table dataclass ``cls`` by its declaration (type, bounds,
    choices), in words; None when the loader would take it. For an editor of one value (the terminal UI)."""
    spec = next((s for s in _schema(cls) if s.name == name), None)
    if spec is None:
        raise KeyError(f"{cls.__name__} has no key {name!r}")
    try:
        _convert(spec, value, name)
    except _Fault as fault:
        return fault.problem
    return None


class _Fault(Exception):
    """A problem at a dotted key; turned into a :class:`ConfigError` with the source prepended."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"{key}: {problem}")
        self.key = key
        self.problem = problem


def _convert_scalar(base: type, value: Any, meta: Mapping[str, Any], key: str) -> Any:
    """Type-check and range-check one scalar (or build one nested table); raises :class:`_Fault` naming ``key``."""
    if dataclasses.is_dataclass(base):
        if not isinstance(value, Mapping):
            raise _Fault(key, f"expected a table, got {_describe(value)}")
        return _build(base, value, lambda k: f"{key}.{_key_path(k)}", lambda k: f"{key}.{_key_path(k)}")
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
    missing: Callable[[str], str],
    default_key: Callable[[str], str] | None = None,
) -> T:
    """Build table ``cls`` from the merged keys ``given``.

    ``origin(key)`` is the dotted key a given value came from, ``missing(key)`` the dotted key a missing required
    key is reported at, ``default_key(key)`` the dotted key of a key left at its default (default: ``missing``).
    """
    default_key = default_key or missing
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
            raise _Fault(missing(spec.name), "missing")
        else:
            values[spec.name] = spec.default

    def where(name: str) -> str:
        return origin(name) if name in given else default_key(name)

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
        if dataclasses.is_dataclass(spec.base):
            out[spec.name] = _to_raw(value)
        else:
            out[spec.name] = list(value) if spec.array else value
    return out


def build_table(cls: type[T], data: Mapping[str, Any], table: str, source: str = "<config>") -> T:
    """Convert one TOML table ``data`` to table dataclass ``cls``; errors name ``source`` and ``table.key``."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: {_key_path(table)}: expected a table, got {_describe(data)}", table)
    try:
        return _build(cls, data, lambda k: _key_path(table, k), lambda k: _key_path(table, k))
    except _Fault as fault:
        raise _error(source, fault) from None


def _error(source: str, fault: _Fault) -> ConfigError:
    return ConfigError(f"{source}: {fault.key}: {fault.problem}", fault.key)


def _expect_table(value: Any, *parts: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise _Fault(_key_path(*parts), f"expected a table, got {_describe(value)}")
    return value
