"""A drive's own control loop around its plant: a discrete PID at the control rate, with the host's value injected
at its setpoint or added to its output (``[simulator.loop]``).

Each control period of length h the drive reads the plant output it regulates (the sample at the end of the
previous period), forms the error e = r - y, the controller output

    u_c = kp e + ki h sum(e) + kd (e - e_previous) / h

(the integral includes this period's error), and holds the plant input u = u_c + d over the period. With
``inject = "setpoint"`` the host's value is r and d = 0 (the loop's reference); with ``inject = "effort"`` it is d
and r = 0 (the host excites the plant input of a closed loop, as a drive's torque or velocity offset does).
Besides the plant's outputs the loop reports ``effort`` (u over the period just ended) and ``control`` (u_c over
it), so that ratios of its channels give the plant (y/u), the loop gain (-u_c/u) and the sensitivities.

In z over one control period, with P(z) the plant from the input held over a period to the output at its end:
L(z) = z^-1 C(z) P(z), C(z) = kp + ki h / (1 - z^-1) + kd (1 - z^-1) / h.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bodebench.sim.loop_config import CONTROL, EFFORT, INJECTIONS, LoopConfig
from bodebench.sim.plants import Plant, PlantState

__all__ = ["EFFORT", "CONTROL", "INJECTIONS", "LoopConfig", "LoopState", "ServoLoop"]

@dataclass
class LoopState(PlantState):
    """The plant's state (``inner``) and the controller's: ``x`` = [integral of the error (unit s), the previous
    error, the latest regulated output]."""

    inner: PlantState | None = None

    def copy(self) -> LoopState:
        """An independent copy."""
        assert self.inner is not None
        return LoopState(self.x.copy(), self.mode, self.inner.copy())


class ServoLoop(Plant):
    """``plant`` under a discrete PID (gains kp, ki in 1/s, kd in s, in the plant's input units per output unit)
    regulating its output ``feedback``; the host's value enters at ``inject`` (module docstring)."""

    def __init__(self, plant: Plant, kp: float, ki: float = 0.0, kd: float = 0.0, inject: str = "effort",
                 feedback: str = "") -> None:
        if inject not in INJECTIONS:
            raise ValueError(f"inject must be one of {INJECTIONS}, got {inject!r}")
        feedback = feedback or plant.output_names[0]
        if feedback not in plant.output_names:
            raise ValueError(f"feedback {feedback!r} is not an output of the plant ({', '.join(plant.output_names)})")
        self.plant = plant
        self.kp, self.ki, self.kd = kp, ki, kd
        self.inject = inject
        self._feedback = plant.output_names.index(feedback)
        self.output_names = (*plant.output_names, EFFORT, CONTROL)
        self._u = np.zeros(1)

    def initial_state(self) -> LoopState:
        return LoopState(np.zeros(3), 0.0, self.plant.initial_state())

    def run_sine(self, state: PlantState, t_start: float, h: float, n_steps: int,
                 amplitude: float, frequency_hz: float) -> np.ndarray:
        """Not defined: a drive's loop steps at its control rate (use ``run_held``)."""
        raise NotImplementedError("a drive's control loop runs on held setpoints only")

    def run_held(self, state: PlantState, setpoints: np.ndarray, h: float) -> np.ndarray:
        assert isinstance(state, LoopState) and state.inner is not None
        out = np.empty((len(setpoints), len(self.output_names)))
        integral, previous, measured = (float(v) for v in state.x)
        effort_injected = self.inject == "effort"
        for k, value in enumerate(np.asarray(setpoints, dtype=float).tolist()):
            reference, injected = (0.0, value) if effort_injected else (value, 0.0)
            error = reference - measured
            integral += error * h
            control = self.kp * error + self.ki * integral + self.kd * (error - previous) / h
            previous = error
            self._u[0] = control + injected
            y = self.plant.run_held(state.inner, self._u, h)[0]
            measured = float(y[self._feedback])
            out[k, :-2] = y
            out[k, -2] = self._u[0]
            out[k, -1] = control
        state.x[:] = (integral, previous, measured)
        return out

    @property
    def natural_frequency_hz(self) -> float | None:
        return self.plant.natural_frequency_hz
