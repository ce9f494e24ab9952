"""One declaration per configuration key: the loader, the terminal UI's editor and the generated configuration
reference all read it, so a bound changed in one place is changed for all three."""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field

import pytest

from bodebench.io.config import TABLES, AnalysisConfig
from bodebench.io.reference import configuration_reference
from bodebench.io.schema import ConfigError, build_table, check_value, describe_table


def _table(low: float, high: float) -> type:
    """A table whose one key ``gain`` lies in [low, high)."""

    @dataclass(frozen=True)
    class Probe:
        gain: float = field(default=low, metadata={"min": low, "max": high, "max_exclusive": True,
                                                   "doc": "a gain, 1"})

    return Probe


@pytest.mark.parametrize(("low", "high"), [(1.0, 5.0), (2.0, 9.0)])
def test_a_bound_changed_in_its_declaration_moves_the_loader_the_editor_and_the_docs(low: float, high: float) -> None:
    probe = _table(low, high)
    with pytest.raises(ConfigError, match=rf"probe.gain: must be >= {low!r}"):
        build_table(probe, {"gain": low - 0.5}, "probe")
    assert build_table(probe, {"gain": low}, "probe").gain == low  # type: ignore[attr-defined]
    with pytest.raises(ConfigError, match=rf"probe.gain: must be < {high!r}"):
        build_table(probe, {"gain": high}, "probe")
    assert check_value(probe, "gain", low - 0.5) == f"must be >= {low!r}, got {low - 0.5!r}"
    assert check_value(probe, "gain", (low + high) / 2) is None
    [doc] = describe_table(probe)
    assert doc.rule == f">= {low!r} and < {high!r}" and doc.default == repr(low) and doc.doc == "a gain, 1"


def test_the_tolerance_editor_refuses_what_the_loader_refuses() -> None:
    """The terminal UI's tolerance dialog asks the declaration (0 < tolerance_percent < 100)."""
    for value in (0.0, -1.0, 100.0, 150.0, math.nan, math.inf, 1e-300, 0.01, 99.9):
        try:
            build_table(AnalysisConfig, {"tolerance_percent": value}, "analysis")
            loads = True
        except ConfigError:
            loads = False
        assert (check_value(AnalysisConfig, "tolerance_percent", value) is None) == loads, value


def test_the_reference_lists_every_key_with_its_declared_bounds() -> None:
    """Each key of each table (nested tables' keys as ``inner.key``) has a row in its table's section whose allowed
    values are its bounds and choices, read here from the dataclass fields themselves."""
    text = configuration_reference()

    def fields(cls: type, prefix: str = "") -> list[tuple[str, dataclasses.Field]]:  # type: ignore[type-arg]
        out = []
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            out.append((f"{prefix}{f.name}", f))
            inner = [t for t in (hints[f.name], *typing.get_args(hints[f.name])) if dataclasses.is_dataclass(t)]
            if inner:
                out += fields(inner[0], f"{prefix}{f.name}.")
        return out

    for name, cls in TABLES.items():
        section = text.split(f"## `[{name}]`", 1)[1].split("\n## ", 1)[0]
        rows = {line.split("|")[1].strip().strip("`"): line for line in section.splitlines() if line.startswith("| `")}
        for key, f in fields(cls):
            row = rows.get(key)
            assert row is not None, f"{name}.{key} missing"
            for bound in ("min", "max"):
                if bound in f.metadata:
                    assert repr(f.metadata[bound]) in row, (name, key, row)
            for choice in f.metadata.get("choices", ()):
                assert f'"{choice}"' in row, (name, key, choice)
