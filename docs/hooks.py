"""Build hook: the tree mkdocstrings reads the API from, laid out as the installed package is (bodebench/ =
instrument/, bodebench/drivers = drivers/, bodebench/sim = sim/), made of links to the repository's modules.

It runs before any plugin reads its configuration: the Python handler keeps only search paths that exist then."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from mkdocs.plugins import event_priority

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "build" / "docs-package" / "bodebench"


@event_priority(100)
def on_config(config: Any) -> Any:
    """Link every module of instrument/, drivers/ and sim/ into build/docs-package/bodebench."""
    if PACKAGE.exists():
        shutil.rmtree(PACKAGE)
    for source, target in ((ROOT / "instrument", PACKAGE), (ROOT / "drivers", PACKAGE / "drivers"),
                           (ROOT / "sim", PACKAGE / "sim")):
        for module in source.rglob("*.py"):  # real folders, linked files: the finder walks no linked folder
            link = target / module.relative_to(source)
            link.parent.mkdir(parents=True, exist_ok=True)
            link.symlink_to(module)
    return config
