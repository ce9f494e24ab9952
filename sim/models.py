"""The plant a ``[plant]`` table describes: ``plant_from_config`` builds any model of sim.plants and sim.hydraulic."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

from bodebench.sim.hydraulic import HYDRAULIC_DEFAULTS, SUBSTEPS_PER_PERIOD, ElectrohydraulicDrive
from bodebench.sim.plants import CoulombOscillator, FirstOrderLag, LinearOscillator, Plant, ProportionalValve

__all__ = ["COMPILE_S", "compile_note", "load_kernels", "plant_from_config", "plant_from_table", "uncompiled"]

COMPILE_S = {"coulomb": 3.3, "linear": 1.6, "lag": 1.6, "valve": 1.6, "hydraulic": 3.3}
"""Seconds numba takes to compile each model's step loops where its cache has none (a 2-core machine, measured with
an empty ``NUMBA_CACHE_DIR``); later runs load them from the cache in well under a second."""


def plant_from_config(model: str, *, mass: float = 1.0, stiffness: float = 1.0, friction: float = 0.0,
                      damping_ratio: float = 0.0, time_constant: float = 1.0, gain: float = 1.0,
                      **hydraulic: float) -> Plant:
    """Build the plant a ``[plant]`` table describes (model: coulomb, linear, lag, hydraulic or valve).

    ``hydraulic``: the keyword parameters of :class:`sim.hydraulic.ElectrohydraulicDrive` (SI units); accepted by
    every model (a ``[plant]`` table carries them all), used by "hydraulic", and their valve natural frequency and
    damping ratio by "valve".
    """
    if model == "coulomb":
        return CoulombOscillator(mass, stiffness, friction, damping_ratio)
    if model == "linear":
        return LinearOscillator(mass, stiffness, damping_ratio)
    if model == "lag":
        return FirstOrderLag(time_constant, gain)
    if model == "valve":
        valve = {key: hydraulic.get(key, HYDRAULIC_DEFAULTS[key])
                 for key in ("valve_natural_frequency_hz", "valve_damping_ratio")}
        return ProportionalValve(**valve)
    if model == "hydraulic":
        unknown = sorted(set(hydraulic) - set(HYDRAULIC_DEFAULTS))
        if unknown:
            raise ValueError(f"unknown hydraulic plant parameters {unknown}")
        return ElectrohydraulicDrive(**hydraulic, substeps_per_period=SUBSTEPS_PER_PERIOD)
    raise ValueError(f"unknown plant model {model!r}")


def plant_from_table(table: Mapping[str, Any]) -> Plant:
    """The plant a ``[plant]`` table's values describe (its "model" and the keyword parameters of
    :func:`plant_from_config`)."""
    params = dict(table)
    return plant_from_config(params.pop("model"), **params)


def load_kernels(models: Collection[str]) -> None:
    """Compile the step loops of ``models`` (or load them from numba's on-disk cache): a few steps of each, sine
    and held input."""
    import numpy as np

    for model in models:
        plant = plant_from_config(model, friction=0.1, damping_ratio=0.1)
        plant.run_sine(plant.initial_state(), 0.0, 1e-3, 2, 1.0, 1.0)
        plant.run_held(plant.initial_state(), np.zeros(2), 1e-3)


def _step_loop(model: str) -> object:
    """The compiled function that runs ``model``'s steps (the others it calls compile with it)."""
    from bodebench.sim import _kernels, hydraulic

    return {"coulomb": _kernels.coulomb_run, "hydraulic": hydraulic.hydraulic_run}.get(model, _kernels.lti_run)


def uncompiled(models: Collection[str]) -> tuple[str, ...]:
    """The models among ``models`` whose step loops numba's cache does not hold yet (none without numba: the loops
    then run as plain Python), in order."""
    from bodebench.sim._jit import HAVE_NUMBA

    if not HAVE_NUMBA:
        return ()
    missing = []
    for model in sorted(set(models)):
        try:
            index = _step_loop(model)._cache._cache_file._index_path  # type: ignore[attr-defined]
        except AttributeError:  # a numba whose cache is laid out otherwise: say nothing rather than guess
            continue
        if not Path(index).exists():
            missing.append(model)
    return tuple(missing)


def compile_note(models: Collection[str]) -> str:
    """One line saying that the step loops of ``models`` are compiled first and about how long that takes ("" when
    numba's cache holds them all)."""
    missing = uncompiled(models)
    if not missing:
        return ""
    seconds = sum(COMPILE_S.get(m, max(COMPILE_S.values())) for m in missing)
    names = ", ".join(missing)
    return (f"compiling the step loops of the simulated plant ({names}): about {seconds:.0f} s on a 2-core machine, "
            "once; later runs load them from numba's cache")
