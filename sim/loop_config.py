"""``[simulator.loop]``, the simulated drive's own control loop as a configuration declares it, and the names of
the channels the loop adds (:mod:`bodebench.sim.servo_loop` runs it). Light: no plant is imported until a loop is
put around one."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bodebench.sim.plants import Plant

__all__ = ["CONTROL", "EFFORT", "INJECTIONS", "LoopConfig"]

EFFORT = "effort"
"""Channel of the plant input u = u_c + d over the period just ended."""
CONTROL = "control"
"""Channel of the controller output u_c over the period just ended."""
INJECTIONS = ("setpoint", "effort")
"""Where the host's value enters the loop: as its reference, or added to the controller's output."""


@dataclass(frozen=True)
class LoopConfig:
    """``[simulator.loop]``: the simulated drive's PID around [plant] (none while ``inject`` is empty)."""

    inject: str = field(default="", metadata={
        "choices": ("", *INJECTIONS),
        "doc": "where the host's value enters the drive's loop: setpoint (its reference) or effort (added to the "
               "controller's output, as a torque offset); empty: no loop, the value drives the plant"})
    kp: float = field(default=0.0, metadata={"doc": "proportional gain, plant input units per output unit"})
    ki: float = field(default=0.0, metadata={"doc": "integral gain, plant input units per output unit and s"})
    kd: float = field(default=0.0, metadata={"doc": "derivative gain (backward difference), plant input units "
                                                    "per output unit per s"})
    feedback: str = field(default="", metadata={"doc": "the plant output the loop regulates (default: its first, "
                                                       "position)"})

    def around(self, plant: Plant) -> Plant:
        """``plant`` inside this loop (itself where there is none)."""
        from bodebench.sim.servo_loop import ServoLoop

        if not self.inject:
            return plant
        return ServoLoop(plant, self.kp, self.ki, self.kd, self.inject, self.feedback)
