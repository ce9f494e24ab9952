"""Optional packages: which extra of bodebench installs each, and the one-line error that says so.

A documented path that needs a package bodebench does not require (canopen for transport "canopen", msgpack for
python-can's udp_multicast interface) raises :class:`MissingDependency` naming the extra to install, never a bare
``ModuleNotFoundError``.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["EXTRAS", "MissingDependency", "missing", "require"]

EXTRAS: dict[str, tuple[str, str]] = {
    "canopen": ("canopen", "canopen"),
    "msgpack": ("msgpack", "rehearse"),
    "control": ("control", "export"),
    "pandas": ("pandas", "export"),
}
"""Module -> (the package pip installs it from, the extra of bodebench that installs it), as pyproject.toml lists."""


class MissingDependency(ImportError):
    """A package the path taken needs is not installed; the message (one line) names the package and the extra."""


def missing(module: str, what: str) -> MissingDependency:
    """The error for ``what`` (a key, an interface, a command) that needs ``module``, one of :data:`EXTRAS`."""
    package, extra = EXTRAS[module]
    return MissingDependency(f"{what} needs the {package} package: pip install 'bodebench[{extra}]' (or pip install "
                             f"{package})")


def require(module: str, what: str) -> ModuleType:
    """``module`` imported; :class:`MissingDependency` for ``what`` when it is not installed."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise missing(module, what) from None
