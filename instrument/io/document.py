"""The TOML document of a configuration before validation: overrides from the command line (``--set
table.key=value``, ``--port``) and edited copies of the file (``sim-controller --write-config``).

Only the standard library: the command line parses ``--set`` before it imports anything else.
"""

from __future__ import annotations

import copy
import datetime
import json
import math
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["Override", "OverrideError", "apply_overrides", "edited_copy", "parse_override", "serial_port_overrides",
           "toml_text"]

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_INDEX = re.compile(r"0|[1-9][0-9]*")
_TOML_OPENERS = ('"', "'", "[", "{")
_CAN_TRANSPORTS = ("can", "canopen")


def key_path(parts: Sequence[str]) -> str:
    """Key parts as a TOML dotted key, parts that are not bare keys quoted (as configuration errors name keys)."""
    return ".".join(p if _BARE_KEY.fullmatch(p) else json.dumps(p, ensure_ascii=False) for p in parts)


@dataclass(frozen=True)
class Override:
    """One value set in the document before validation: ``parts`` is the dotted key, ``value`` a TOML value,
    ``option`` the command-line option that set it (it names the key in errors)."""

    parts: tuple[str, ...]
    value: Any
    option: str = "--set"

    @property
    def key(self) -> str:
        return key_path(self.parts)

    def __str__(self) -> str:
        return f"{self.key}={toml_value(self.value)}"


class OverrideError(ValueError):
    """An override that cannot go into the document: ``key`` the dotted key at fault, ``problem`` why."""

    def __init__(self, option: str, key: str, problem: str) -> None:
        super().__init__(f"{option} {key}: {problem}")
        self.option = option
        self.key = key
        self.problem = problem


def _parse_key(text: str) -> tuple[str, ...]:
    """A TOML dotted key (bare or quoted parts); ValueError when it is not one."""
    if not text:
        raise ValueError("empty key before '='")
    if "\n" in text or "\r" in text:
        raise ValueError("a key is one line")
    try:
        node: Any = tomllib.loads(f"{text} = 0")
    except tomllib.TOMLDecodeError:
        raise ValueError("not a TOML dotted key (table.key; quote a part holding a dot: "
                         'cases."fbar_0.8".plant.friction)') from None
    parts: list[str] = []
    while isinstance(node, dict):
        [(part, node)] = node.items()
        parts.append(part)
    return tuple(parts)


def _parse_value(text: str) -> Any:
    """A TOML value; a bare word that is not one is a string (``/dev/ttyUSB0``)."""
    try:
        parsed = tomllib.loads(f"v = {text}")
    except tomllib.TOMLDecodeError as exc:
        if text.startswith(_TOML_OPENERS):  # meant as a TOML string, array or table, but not one
            message = " ".join(str(exc).split())
            raise ValueError(f"not a TOML value ({message})") from None
        return text
    if set(parsed) != {"v"}:
        raise ValueError("not one TOML value")
    return parsed["v"]


def parse_override(text: str) -> Override:
    """``table.key=value`` (``value`` a TOML value or a bare word); ValueError (one line) when malformed."""
    key, eq, value = text.partition("=")
    if not eq:
        raise ValueError(f"{text!r}: expected KEY=VALUE, for example analysis.tolerance_percent=0.1")
    try:
        return Override(_parse_key(key.strip()), _parse_value(value.strip()))
    except ValueError as exc:
        raise ValueError(f"{text!r}: {exc}") from None


def apply_overrides(data: Mapping[str, Any], overrides: Sequence[Override]
                    ) -> tuple[dict[str, Any], list[tuple[str, ...]]]:
    """A copy of the document ``data`` with each override set, in order (tables on the way created as needed;
    an array of tables is entered by index: ``frames.feedback.0.id``), and the keys of the tables so created.
    Raises :class:`OverrideError` when a part of the path holds a value that is not a table."""
    doc: dict[str, Any] = copy.deepcopy(dict(data))
    created: list[tuple[str, ...]] = []
    for override in overrides:
        node: Any = doc
        parts = override.parts
        for i, part in enumerate(parts[:-1]):
            here = parts[: i + 1]
            if isinstance(node, list):
                if not _INDEX.fullmatch(part) or int(part) >= len(node):
                    raise OverrideError(override.option, key_path(here),
                                        f"an array of {len(node)} tables: index it from 0 to {len(node) - 1}")
                node = node[int(part)]
                continue
            child = node.get(part)
            if child is None:
                child = node[part] = {}
                created.append(here)
            elif not isinstance(child, (dict, list)) or (isinstance(child, list)
                                                           and not all(isinstance(c, dict) for c in child)):
                raise OverrideError(override.option, key_path(here),
                                    f"holds {toml_value(child)}, not a table: {key_path(parts)} cannot be set")
            node = child
        last = parts[-1]
        if isinstance(node, list):
            raise OverrideError(override.option, key_path(parts), "is an element of an array of tables, not a key")
        node[last] = copy.deepcopy(override.value)
    return doc, created


def names_override(key: str, overrides: Sequence[Override], created: Sequence[tuple[str, ...]]) -> Override | None:
    """The override that put the value at dotted ``key`` (an error's key) into the document, or None."""
    for override in reversed(overrides):
        path = override.key
        if key == path or key.startswith((path + ".", path + "[", path + " ")):
            return override
    for table in created:
        if key == key_path(table):
            for override in overrides:
                if override.parts[: len(table)] == table:
                    return override
    return None


def _transports(data: Mapping[str, Any]) -> list[str]:
    """The bench.transport of every case of a document, as written (``""`` where none is)."""
    bench = data.get("bench")
    base = bench.get("transport", "") if isinstance(bench, Mapping) else ""
    cases = data.get("cases")
    if not isinstance(cases, Mapping) or not cases:
        return [str(base)]
    out = []
    for body in cases.values():
        own = body.get("bench") if isinstance(body, Mapping) else None
        out.append(str(own.get("transport", base) if isinstance(own, Mapping) else base))
    return out


def serial_port_overrides(data: Mapping[str, Any], port: str) -> list[Override]:
    """What ``--port PORT`` sets in ``data`` (the document with its ``--set`` overrides): serial.port, and the
    serial.port of each case that names its own. ValueError (one line) on a document that is not a serial bench."""
    transports = _transports(data)
    can = sorted({t for t in transports if t in _CAN_TRANSPORTS})
    if can:
        raise ValueError(f'bench.transport is "{can[0]}": --port names a serial port; set the CAN channel with '
                         "--set can.channel=...")
    if not any(transports):
        raise ValueError("the configuration has no bench.transport: --port is the serial port of a bench config")
    out = [Override(("serial", "port"), port, "--port")]
    cases = data.get("cases")
    if isinstance(cases, Mapping):
        for name, body in cases.items():
            own = body.get("serial") if isinstance(body, Mapping) else None
            if isinstance(own, Mapping) and "port" in own:
                out.append(Override(("cases", str(name), "serial", "port"), port, "--port"))
    return out


# ----------------------------------------------------------------------------------------- writing TOML


def toml_value(value: Any) -> str:
    """One TOML value on one line (tables inline)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, (datetime.datetime, datetime.date, datetime.time)):
        return value.isoformat()
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{key_path([str(k)])} = {toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {type(value).__name__}")


def toml_text(data: Mapping[str, Any], header: str = "") -> str:
    """A whole document as TOML: the keys of each table, then its sub-tables under their own headers; arrays
    (of tables too) inline. ``header``: comment lines put first."""
    lines = [f"# {line}" for line in header.splitlines()]

    def table(node: Mapping[str, Any], parts: tuple[str, ...]) -> None:
        scalars = [(k, v) for k, v in node.items() if not isinstance(v, Mapping)]
        tables = [(k, v) for k, v in node.items() if isinstance(v, Mapping)]
        if parts and (scalars or not tables):
            lines.extend(["", f"[{key_path(parts)}]"])
        lines.extend(f"{key_path([str(k)])} = {toml_value(v)}" for k, v in scalars)
        for k, v in tables:
            table(v, (*parts, str(k)))

    table(data, ())
    return "\n".join(lines).lstrip("\n") + "\n"


_HEADER = re.compile(r"\s*\[(?!\[)(.*)\]\s*(#.*)?$")
_ANY_HEADER = re.compile(r"\s*\[")


def _header_path(line: str) -> tuple[str, ...] | None:
    """The table a standard header line ``[a.b]`` opens (None: not such a line)."""
    if not _HEADER.match(line):
        return None
    try:
        node: Any = tomllib.loads(line.strip())
    except tomllib.TOMLDecodeError:
        return None
    parts: list[str] = []
    while isinstance(node, dict) and node:
        [(part, node)] = node.items()
        parts.append(part)
    return tuple(parts)


def _set_in_text(lines: list[str], parts: tuple[str, ...], value: Any) -> None:
    """Set ``parts`` = ``value`` in the lines of a TOML file: the key's one-line assignment under its table's
    header replaced, or a line added after the header, or the table added at the end."""
    table, key = parts[:-1], parts[-1]
    line = f"{key_path([key])} = {toml_value(value)}"
    if table:
        start = next((i for i, text in enumerate(lines) if _header_path(text) == table), None)
        if start is None:
            lines.extend(["", f"[{key_path(table)}]", line])
            return
    else:
        start = -1  # the top level: the lines before the first header
    end = next((i for i in range(start + 1, len(lines)) if _ANY_HEADER.match(lines[i])), len(lines))
    assignment = re.compile(rf"\s*({re.escape(key)}|\"{re.escape(key)}\"|'{re.escape(key)}')\s*=")
    for i in range(start + 1, end):
        if assignment.match(lines[i]):
            lines[i] = line + _comment_of(lines[i])
            return
    lines.insert(start + 1, line)


def _comment_of(line: str) -> str:
    """The comment that ends a one-line assignment, with the spaces before it ("" when none)."""
    for found in re.finditer("#", line):
        head = line[: found.start()]
        try:
            tomllib.loads(head)
        except tomllib.TOMLDecodeError:
            continue  # a "#" inside a string
        return line[len(head.rstrip()):]
    return ""


def edited_copy(text: str, overrides: Sequence[Override], remove: Sequence[str] = (), header: str = "") -> str:
    """The TOML file ``text`` with ``overrides`` set and the top-level tables ``remove`` left out, as a file:
    edited line by line where that gives exactly the intended document (the comments stay), else written whole
    by :func:`toml_text`. Raises :class:`OverrideError` as :func:`apply_overrides`, ValueError on a file that is
    not TOML."""
    data = tomllib.loads(text)
    wanted, _ = apply_overrides(data, overrides)
    for name in remove:
        wanted.pop(name, None)
    if not [name for name in remove if name in data]:
        lines = text.splitlines()
        try:
            for override in overrides:
                _set_in_text(lines, override.parts, override.value)
            edited = ("\n".join(f"# {line}" for line in header.splitlines()) + "\n" if header else "") + \
                "\n".join(lines) + "\n"
            if tomllib.loads(edited) == wanted:
                return edited
        except (tomllib.TOMLDecodeError, TypeError):
            pass
    whole = toml_text(wanted, header)
    if tomllib.loads(whole) != wanted:
        raise ValueError("the configuration cannot be written back as TOML")
    return whole
