"""The example configurations shipped with bodebench: the repository's ``configs/`` folder, installed as the data
package ``bodebench.configs`` (pyproject.toml maps one onto the other, so there is one copy of each file).

An example is named by its file name without ``.toml`` (``sim_can``), or by its whole file name for the other
files a configuration names (``real_can.dbc``). Each has one line that says what it is: a configuration's
``title``, a DBC file's database comment (its ``CM_ "..."`` line).
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

__all__ = ["Example", "ExampleError", "example", "examples", "examples_folder"]

SUFFIXES = (".toml", ".dbc")
"""The files of the folder that are examples: configurations and the DBC files they name."""

_DBC_COMMENT = re.compile(r'^CM_\s+"(?P<text>[^"]*)"\s*;', re.MULTILINE)


class ExampleError(ValueError):
    """No example of that name (the message, one line, lists the names there are)."""


@dataclass(frozen=True)
class Example:
    """One shipped file: ``name`` as ``bodebench example`` takes it, ``file`` its file name, ``line`` what it is."""

    name: str
    file: str
    line: str
    source: Traversable

    def text(self) -> str:
        """The file's content (UTF-8)."""
        return self.source.read_text(encoding="utf-8")


def examples_folder() -> Traversable:
    """Where the examples are: ``bodebench/configs`` of an installed wheel, else (a source checkout, an editable
    install) the repository's ``configs/`` beside the package's folder."""
    installed = resources.files("bodebench") / "configs"
    if installed.is_dir():
        return installed
    return Path(__file__).resolve().parents[2] / "configs"


def _line(file: str, text: str) -> str:
    if file.endswith(".toml"):
        title = tomllib.loads(text).get("title")
        return str(title) if title else ""
    found = _DBC_COMMENT.search(text)
    return found["text"] if found else ""


def examples() -> list[Example]:
    """Every shipped example, sorted by name."""
    found = []
    for entry in examples_folder().iterdir():
        if entry.is_file() and entry.name.endswith(SUFFIXES):
            name = entry.name.removesuffix(".toml")
            found.append(Example(name, entry.name, _line(entry.name, entry.read_text(encoding="utf-8")), entry))
    return sorted(found, key=lambda e: e.name)


def example(name: str) -> Example:
    """The example called ``name`` (with or without ``.toml``); :class:`ExampleError` when there is none."""
    every = examples()
    for item in every:
        if name in (item.name, item.file):
            return item
    raise ExampleError(f"no example {name!r} (there are: {', '.join(e.name for e in every)})")
