"""Seeded mutants of the shipped configurations, for the loader's fuzzing test and benchmark.

A mutant is a shipped config with one to three edits: a value replaced by one of ``HOSTILE_VALUES`` (wrong types,
extremes, NaN, huge strings, TOML dates), a key deleted, an unknown key added, a scalar wrapped in a list or a list
or table flattened to a scalar. ``check_mutant`` loads it and says what went wrong, if anything: the loader must
either accept it or refuse it with one line (a ``ConfigError``) that names the source; anything else (another
exception, a message over several lines) is a defect.
"""

from __future__ import annotations

import copy
import datetime
import math
import random
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bodebench.io.config import ConfigError, parse_config

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"

HOSTILE_VALUES: tuple[Any, ...] = (
    0, -1, 1, 0.5, 127, 128, 255, 256, 65535, 65536, 2**31, 2**63 - 1, -(2**63), 1e300, -1e300, 5e-324, 1e-300,
    math.nan, math.inf, -math.inf, True, False, "", "x", "x" * 5000, "0x7FFFFFFF", "0xZZ", "nan", "-1", "\x00", "../..",
    "/dev/null", [], [0], [-1], [math.nan], [1e300], ["a"], [[]], {}, {"a": 1}, {"": {}},
    datetime.datetime(2026, 12, 5, 1, 2, 3), datetime.date(2026, 12, 5), datetime.time(1, 2, 3),
)
"""Values a hurried or hostile edit may leave in a config."""


@dataclass(frozen=True)
class Mutant:
    """A mutated config: its ``source`` (the shipped file's name), the edits made, and the document."""

    source: str
    edits: tuple[str, ...]
    data: dict[str, Any]


def shipped_configs() -> dict[str, dict[str, Any]]:
    """The shipped configs by file name, parsed as TOML."""
    return {path.name: tomllib.loads(path.read_text(encoding="utf-8")) for path in sorted(CONFIG_DIR.glob("*.toml"))}


def _places(data: Any, path: tuple[str | int, ...] = ()) -> Iterator[tuple[tuple[str | int, ...], Any]]:
    """Every (path, value) below ``data``: tables, lists and their entries."""
    if isinstance(data, dict):
        for key, value in data.items():
            yield (*path, key), value
            yield from _places(value, (*path, key))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            yield (*path, i), value
            yield from _places(value, (*path, i))


def _parent(data: Any, path: tuple[str | int, ...]) -> Any:
    for part in path[:-1]:
        data = data[part]
    return data


def _edit(data: dict[str, Any], rng: random.Random) -> str:
    """One random edit of ``data`` in place; returns it in words."""
    places = list(_places(data))
    path, value = places[rng.randrange(len(places))]
    parent, last = _parent(data, path), path[-1]
    where = ".".join(str(p) for p in path)
    kind = rng.random()
    if kind < 0.55:
        new = rng.choice(HOSTILE_VALUES)
        parent[last] = copy.deepcopy(new)
        return f"{where} = {new!r:.40}"
    if kind < 0.7:
        del parent[last]
        return f"{where} deleted"
    if kind < 0.8 and isinstance(value, dict):
        value[rng.choice(("unknown", "Amplitude", "frequencies_hz ", ""))] = rng.choice(HOSTILE_VALUES)
        return f"{where}: an unknown key added"
    if kind < 0.9 and not isinstance(value, (dict, list)):
        parent[last] = [value]
        return f"{where} wrapped in a list"
    if isinstance(value, (dict, list)):
        parent[last] = rng.choice((0, "x", 1.0))
        return f"{where}: a table or list replaced by a scalar"
    parent[last] = str(value)
    return f"{where} as a string"


def mutants(seed: int, count: int) -> Iterator[Mutant]:
    """``count`` mutants, the same for the same ``seed``: each a shipped config with one to three edits."""
    rng = random.Random(seed)
    configs = shipped_configs()
    names = sorted(configs)
    for _ in range(count):
        source = rng.choice(names)
        data = copy.deepcopy(configs[source])
        edits = tuple(_edit(data, rng) for _ in range(rng.choice((1, 1, 2, 3))))
        yield Mutant(source, edits, data)


def judge_mutant(mutant: Mutant) -> tuple[bool, str | None]:
    """(whether the loader accepted the mutant, the defect or None): refused with one line naming its source is no
    defect."""
    try:
        parse_config(mutant.data, mutant.source)
    except ConfigError as exc:
        message = str(exc)
        if "\n" in message or not message.startswith(mutant.source):
            return False, f"{mutant.source} {list(mutant.edits)}: refused with a message that is not one line " \
                          f"naming the file: {message!r:.300}"
        return False, None
    except Exception as exc:  # noqa: BLE001 - any other exception is the defect looked for
        return False, f"{mutant.source} {list(mutant.edits)}: {type(exc).__name__}: {exc!s:.300}"
    return True, None


def check_mutant(mutant: Mutant) -> str | None:
    """None when the loader accepted the mutant or refused it with one line naming its source; else the defect."""
    return judge_mutant(mutant)[1]


NONSENSE: tuple[tuple[str, Any], ...] = (
    ("excitation.frequencies_hz", [5e-324]), ("excitation.frequencies_hz", [1e300]),
    ("excitation.frequencies_hz", [math.nan]), ("excitation.frequencies_hz", [math.inf]),
    ("excitation.frequencies_hz", [-1.0]), ("excitation.frequencies_hz", [0.0]), ("excitation.frequencies_hz", []),
    ("analysis.tolerance_percent", 65536), ("analysis.tolerance_percent", 100), ("analysis.tolerance_percent", 0),
    ("analysis.tolerance_percent", -1), ("analysis.tolerance_percent", math.nan),
    ("analysis.tolerance_percent", math.inf),
    ("bench.rate_hz", 9.2e18), ("bench.rate_hz", 0), ("bench.rate_hz", -1), ("bench.rate_hz", math.nan),
    ("excitation.amplitude", 0), ("excitation.amplitude", -0.01), ("excitation.amplitude", math.nan),
    ("excitation.amplitude", math.inf),
    ("analysis.harmonics", [0]), ("analysis.harmonics", [-1]), ("analysis.harmonics", []),
    ("analysis.harmonics", [1.5]), ("analysis.harmonics", [10**6]),
    ("safety.watchdog_s", 0), ("safety.watchdog_s", -1), ("safety.watchdog_s", math.nan),
    ("safety.watchdog_s", math.inf), ("safety.max_amplitude", -1), ("safety.max_amplitude", math.nan),
    ("safety.max_rate", -1), ("safety.max_rate", math.nan),
    ("simulator.jitter", -0.1), ("simulator.jitter", math.nan), ("simulator.hum", -1), ("simulator.hum", math.nan),
    ("plant.mass", -1), ("plant.mass", 0), ("plant.mass", math.nan), ("plant.stiffness", math.inf),
    ("canopen.node_id", 0), ("canopen.node_id", 128), ("canopen.heartbeat_ms", -1), ("canopen.host_node_id", 0),
    ("canopen.setpoint_scale", 0), ("canopen.setpoint_scale", math.nan),
)
"""(dotted key, value) edits that no instrument may accept: each is refused by the loader, naming the key."""


def nonsense_mutants() -> Iterator[tuple[str, Mutant]]:
    """(key, mutant) for every edit of ``NONSENSE`` whose table the shipped config has, of the shipped configs that
    load as they are (a real drive's example names files the user brings, such as its EDS)."""
    for source, config in shipped_configs().items():
        try:
            parse_config(config, source)
        except ConfigError:
            continue
        for key, value in NONSENSE:
            table, name = key.split(".")
            if table not in config:
                continue
            data = copy.deepcopy(config)
            data[table][name] = copy.deepcopy(value)
            yield key, Mutant(source, (f"{key} = {value!r}",), data)
