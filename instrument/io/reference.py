"""The configuration reference as Markdown, generated from the one declaration of each key (the table dataclasses
of :mod:`bodebench.io.tables` and the rules :mod:`bodebench.io.schema` enforces), for the documentation site."""

from __future__ import annotations

import inspect

from bodebench.io.config import FRAMES, TABLES
from bodebench.io.schema import describe_table

__all__ = ["configuration_reference"]


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ") if text else ""


def configuration_reference() -> str:
    """Every table and key a configuration file takes: type, default, allowed values and meaning, as Markdown."""
    lines = [
        "# Configuration reference",
        "",
        "Every key a configuration file takes, generated from the declaration the loader enforces: a bound or a",
        "choice shown here is the one a file is checked against. A key marked with a condition belongs to that",
        "model or mode only, and giving it otherwise is an error. Any table may also appear inside",
        "`[cases.NAME]`; `--set TABLE.KEY=VALUE` sets a key as if the file said so.",
        "",
    ]
    for name, cls in TABLES.items():
        doc = inspect.getdoc(cls) or ""
        lines += [f"## `[{name}]`", "", doc.split("\n\n")[0].replace("\n", " "), ""]
        lines += ["| key | type | default | allowed | meaning |", "|---|---|---|---|---|"]
        for key in describe_table(cls):
            meaning = key.doc + (f" (only with {key.only_if})" if key.only_if else "")
            lines.append(f"| `{key.key}` | {key.type} | `{_cell(key.default)}` | {_cell(key.rule)} | "
                         f"{_cell(meaning)} |")
        lines.append("")
    lines += [f"## `[{FRAMES}]`", "",
              "The frame layout of a CAN or serial bench (setpoint, feedback, enable, disable and heartbeat frames, "
              "or a DBC file): see [the bus protocol](../protocol.md), section 2.", ""]
    return "\n".join(lines)
