"""The plant a ``[plant]`` table describes: ``plant_from_config`` builds any model of sim.plants and sim.hydraulic."""

from __future__ import annotations

from collections.abc import Collection

from bodebench.sim.hydraulic import HYDRAULIC_DEFAULTS, SUBSTEPS_PER_PERIOD, ElectrohydraulicDrive
from bodebench.sim.plants import CoulombOscillator, FirstOrderLag, LinearOscillator, Plant, ProportionalValve

__all__ = ["load_kernels", "plant_from_config"]


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


def load_kernels(models: Collection[str]) -> None:
    """Compile the step loops of ``models`` (or load them from numba's on-disk cache): a few steps of each, sine
    and held input."""
    import numpy as np

    for model in models:
        plant = plant_from_config(model, friction=0.1, damping_ratio=0.1)
        plant.run_sine(plant.initial_state(), 0.0, 1e-3, 2, 1.0, 1.0)
        plant.run_held(plant.initial_state(), np.zeros(2), 1e-3)
