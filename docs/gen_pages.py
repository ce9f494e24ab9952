"""Pages generated when the site is built (mkdocs-gen-files), each from the one place that holds its content:
the bus protocol from drivers/PROTOCOL.md, the configuration reference from the schema, and the list of
benchmarks from their own docstrings."""

from __future__ import annotations

import ast
from pathlib import Path

import mkdocs_gen_files

from bodebench.io.reference import configuration_reference

ROOT = Path(__file__).resolve().parent.parent

protocol = (ROOT / "drivers" / "PROTOCOL.md").read_text(encoding="utf-8")
with mkdocs_gen_files.open("protocol.md", "w") as page:
    page.write(protocol.replace("(../docs/", "(").replace("(docs/", "("))

with mkdocs_gen_files.open("reference/configuration.md", "w") as page:
    page.write(configuration_reference())

rows = []
for script in sorted((ROOT / "benchmarks").glob("bench_*.py")):
    doc = ast.get_docstring(ast.parse(script.read_text(encoding="utf-8"))) or ""
    first = " ".join(doc.split("\n\n")[0].split())
    rows.append(f"| `python benchmarks/{script.name}` | {first.replace('|', '/')} |")
with mkdocs_gen_files.open("reference/benchmarks.md", "w") as page:
    page.write("# Benchmarks\n\nEach benchmark is one command, run from a clone, that prints its figures against "
               "their targets (`python benchmarks/run_all.py` runs them all). What each one measures, from its own "
               "description:\n\n| command | what it measures |\n|---|---|\n" + "\n".join(rows) + "\n")
