"""The CANopen device profiles a sweep runs on (pure, no I/O): CiA 402 drives and CiA 408 fluid-power devices.

A ``DeviceProfile`` is what differs between them, read by the instrument's driver (``drivers.canopen_link``), the
``check`` command's plan and the configuration loader: the objects a device of the profile must have, its modes and
the mode object, the default set point and actual value objects of each mode, how its status word is decoded, the
steps that enable it, the steps that leave it safe on every exit, and its fault reset.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import StrEnum

from . import cia402, cia408

__all__ = ["PROFILES", "DeviceProfile", "Step"]


@dataclass(frozen=True)
class Step:
    """One control word written: its ``name``, the ``controlword`` and the ``targets`` (states) that confirm it."""

    name: str
    controlword: int
    targets: tuple[StrEnum, ...]


@dataclass(frozen=True)
class DeviceProfile:
    """What the instrument needs to know of a CANopen device profile (see the module docstring).

    number: 402 or 408; device: what the profile's devices are called in messages; modes: mode name -> code;
    mode_object / mode_display: where the mode is written and where it is read back; device_mode: an (index, value,
    name) written before the mode (CiA 408: device mode 0x6042 = 1, set points via the bus), or None; required:
    (index, name) of the objects every device of the profile has; default_mode; setpoints / actuals: mode ->
    default set point object, default actual channels (channel -> object); decode: status word -> state (None:
    undefined); running: the state a sweep runs in; enable: the steps from disabled to ``running``; leave: the
    steps on every exit; safe: the states that count as disabled at the end; faults: the fault states; reset: the
    fault reset (its control word written after 0) and the state it ends in; local_bit: the status word bit that
    says the device ignores the bus's control word (0: none); abort_connection: the profile has the abort
    connection option code 0x6007 (CiA 402), written for a lost host; without it the device's own fault reaction
    applies. position_modes: the modes whose set point is a position, which the host sets to the actual value
    (the mode's default actual object) where it excites an offset instead (``CanopenSetup.operating_point``).
    """

    number: int
    device: str
    modes: Mapping[str, int]
    mode_object: int
    mode_display: int
    device_mode: tuple[int, int, str] | None
    required: tuple[tuple[int, str], ...]
    default_mode: str
    setpoints: Mapping[str, str]
    actuals: Mapping[str, Mapping[str, str]]
    decode: Callable[[int], StrEnum | None]
    running: StrEnum
    enable: tuple[Step, ...]
    leave: tuple[Step, ...]
    safe: frozenset[StrEnum]
    faults: frozenset[StrEnum]
    reset: Step
    local_bit: int = 0
    abort_connection: bool = False
    position_modes: frozenset[str] = frozenset()

    @property
    def name(self) -> str:
        """"CiA 402" or "CiA 408"."""
        return f"CiA {self.number}"

    def stuck(self, step: Step, state: StrEnum | None) -> str:
        """Why a device in ``state`` may not have reached ``step``'s target, in words (empty when nothing is known)."""
        if self.number == 408 and state is cia408.State.DISABLED and step.targets[0] in (cia408.State.HOLD,
                                                                                        cia408.State.ACTIVE):
            return ("; a CiA 408 device stays DISABLED without its hardware enable input: check the enable signal "
                    "on its connector")
        if self.number == 402 and state is cia402.State.SWITCHED_ON and step.targets[0] is \
                cia402.State.OPERATION_ENABLED:
            return "; the drive refuses to enable operation: see its own error or warning objects"
        return ""


_D402 = cia402.State
CIA402 = DeviceProfile(
    number=402,
    device="drive",
    modes=cia402.MODES,
    mode_object=0x6060,
    mode_display=0x6061,
    device_mode=None,
    required=((0x6040, "controlword"), (0x6041, "statusword"), (0x6060, "modes of operation"),
              (0x6061, "modes of operation display")),
    default_mode="csp",
    setpoints={mode: f"0x{index:04X}" for mode, index in cia402.TARGET_OBJECTS.items()},
    actuals={mode: {"position": "0x6064"} for mode in cia402.MODES},
    decode=cia402.decode_statusword,
    running=_D402.OPERATION_ENABLED,
    enable=tuple(Step(str(command), cia402.CONTROLWORD[command], (target, _D402.FAULT)) for command, target in (
        (cia402.Command.SHUTDOWN, _D402.READY_TO_SWITCH_ON),
        (cia402.Command.SWITCH_ON, _D402.SWITCHED_ON),
        (cia402.Command.ENABLE_OPERATION, _D402.OPERATION_ENABLED))),
    leave=(Step(str(cia402.Command.QUICK_STOP), cia402.CONTROLWORD[cia402.Command.QUICK_STOP],
                (_D402.QUICK_STOP_ACTIVE, _D402.SWITCH_ON_DISABLED, _D402.FAULT)),
           Step(str(cia402.Command.DISABLE_VOLTAGE), cia402.CONTROLWORD[cia402.Command.DISABLE_VOLTAGE],
                (_D402.SWITCH_ON_DISABLED, _D402.FAULT))),
    safe=frozenset({_D402.SWITCH_ON_DISABLED, _D402.FAULT}),
    faults=frozenset({_D402.FAULT, _D402.FAULT_REACTION_ACTIVE}),
    reset=Step(str(cia402.Command.FAULT_RESET), cia402.CONTROLWORD[cia402.Command.FAULT_RESET],
               (_D402.SWITCH_ON_DISABLED,)),
    abort_connection=True,
    position_modes=frozenset({"csp"}),
)
"""CiA 402 drives: mode of operation 0x6060 (shown in 0x6061); shutdown, switch on, enable operation; quick stop
and disable voltage on exit."""

_D408 = cia408.State
CIA408 = DeviceProfile(
    number=408,
    device="device",
    modes=cia408.CONTROL_MODES,
    mode_object=0x6043,
    mode_display=0x6043,
    device_mode=(0x6042, 1, "device mode: set points via the bus"),
    required=((0x6040, "device control word"), (0x6041, "device status word"), (0x6042, "device mode"),
              (0x6043, "device control mode")),
    default_mode="spool",
    setpoints={mode: f"0x{pair[0]:04X}:1" for mode, pair in cia408.PROCESS_VALUES.items()},
    actuals={mode: {{0x6301: "spool", 0x6381: "pressure"}.get(pair[1], mode): f"0x{pair[1]:04X}:1"}
             for mode, pair in cia408.PROCESS_VALUES.items()},
    decode=cia408.decode_statusword,
    running=_D408.ACTIVE,
    enable=tuple(Step(state.value, cia408.CONTROLWORD[state], (state, *sorted(cia408.FAULT_STATES))) for state in
                 (_D408.DISABLED, _D408.HOLD, _D408.ACTIVE)),
    leave=(Step(_D408.HOLD.value, cia408.CONTROLWORD[_D408.HOLD], (_D408.HOLD, _D408.DISABLED,
                                                                  *sorted(cia408.FAULT_STATES))),
           Step(_D408.DISABLED.value, cia408.CONTROLWORD[_D408.DISABLED], (_D408.DISABLED,
                                                                          *sorted(cia408.FAULT_STATES))),
           Step("no bit set", 0x0000, (_D408.DISABLED, *sorted(cia408.FAULT_STATES)))),
    safe=frozenset({_D408.DISABLED, _D408.FAULT_DISABLED}),
    faults=cia408.FAULT_STATES,
    reset=Step("reset fault", cia408.RESET_BIT, (_D408.DISABLED,)),
    local_bit=0x0010,
    position_modes=frozenset({"position"}),
)
"""CiA 408 valves and hydraulic drives: device mode 0x6042 = 1, control mode 0x6043; DISABLED, HOLD, ACTIVE; HOLD,
DISABLED and no bit on exit."""

PROFILES: dict[str, DeviceProfile] = {"402": CIA402, "408": CIA408}
"""The profiles by the name ``canopen.profile`` gives them."""
