"""bodebench: frequency responses of servo drives by monoharmonic autointegration, over CAN or serial.

The Python interface (:mod:`bodebench.api`)::

    import bodebench
    r = bodebench.simulate("configs/paper2013.toml", case="fbar_0.8")   # or bodebench.run(config, out)
    r.gain_db, r.phase_deg, r.to_frd(), r.to_mat("r.mat"), r.to_dataframe()
    r = bodebench.load("results/sim_can")

Its names are imported on first use, so ``import bodebench`` (and the command line) stays light.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bodebench.api import ConfigSource, Response, configure, load, run, simulate
    from bodebench.bench.events import SessionError
    from bodebench.core.response import FrequencyResponse, ResponsePoint
    from bodebench.io.config import ConfigError, ExperimentConfig
    from bodebench.io.export import MissingDependency
    from bodebench.io.results import ResultsError
    from bodebench.status import PointStatus

_EXPORTS: dict[str, str] = {
    "ConfigSource": "bodebench.api",
    "Response": "bodebench.api",
    "configure": "bodebench.api",
    "load": "bodebench.api",
    "run": "bodebench.api",
    "simulate": "bodebench.api",
    "SessionError": "bodebench.bench.events",
    "FrequencyResponse": "bodebench.core.response",
    "ResponsePoint": "bodebench.core.response",
    "ConfigError": "bodebench.io.config",
    "ExperimentConfig": "bodebench.io.config",
    "MissingDependency": "bodebench.io.export",
    "ResultsError": "bodebench.io.results",
    "PointStatus": "bodebench.status",
}

__all__ = [
    "ConfigError", "ConfigSource", "ExperimentConfig", "FrequencyResponse", "MissingDependency", "PointStatus",
    "Response", "ResponsePoint", "ResultsError", "SessionError", "__version__", "configure", "load", "run", "simulate",
]


def __getattr__(name: str) -> Any:
    if name == "__version__":
        from importlib import metadata

        try:
            return metadata.version("bodebench")
        except metadata.PackageNotFoundError:
            return "0+unknown"
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'bodebench' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
