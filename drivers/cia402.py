"""The CiA 402 power state machine of a drive (pure, no I/O): statusword decoding, controlword commands, and the
transitions a drive makes on them.

Both ends use it: the instrument decodes the statusword it reads and walks the drive through its states with
controlwords; the simulated CiA 402 drive changes state with the same table.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = [
    "ABORT_CONNECTION_OPTIONS",
    "MODES",
    "TARGET_OBJECTS",
    "Command",
    "State",
    "command_of",
    "decode_statusword",
    "next_state",
    "statusword",
]


class State(StrEnum):
    """The states of the CiA 402 power state machine."""

    NOT_READY = "not ready to switch on"
    SWITCH_ON_DISABLED = "switch on disabled"
    READY_TO_SWITCH_ON = "ready to switch on"
    SWITCHED_ON = "switched on"
    OPERATION_ENABLED = "operation enabled"
    QUICK_STOP_ACTIVE = "quick stop active"
    FAULT_REACTION_ACTIVE = "fault reaction active"
    FAULT = "fault"


class Command(StrEnum):
    """The controlword commands of the power state machine."""

    SHUTDOWN = "shutdown"
    SWITCH_ON = "switch on"
    ENABLE_OPERATION = "enable operation"
    DISABLE_OPERATION = "disable operation"
    DISABLE_VOLTAGE = "disable voltage"
    QUICK_STOP = "quick stop"
    FAULT_RESET = "fault reset"


CONTROLWORD: dict[Command, int] = {
    Command.SHUTDOWN: 0x0006,
    Command.SWITCH_ON: 0x0007,
    Command.ENABLE_OPERATION: 0x000F,
    Command.DISABLE_OPERATION: 0x0007,
    Command.DISABLE_VOLTAGE: 0x0000,
    Command.QUICK_STOP: 0x0002,
    Command.FAULT_RESET: 0x0080,
}
"""The controlword the instrument writes for each command (bits 0-3 and 7; the others zero)."""

# statusword bits 0-3, 5 and 6 (mask, value) of each state
_PATTERNS: tuple[tuple[int, int, State], ...] = (
    (0x4F, 0x00, State.NOT_READY),
    (0x4F, 0x40, State.SWITCH_ON_DISABLED),
    (0x6F, 0x21, State.READY_TO_SWITCH_ON),
    (0x6F, 0x23, State.SWITCHED_ON),
    (0x6F, 0x27, State.OPERATION_ENABLED),
    (0x6F, 0x07, State.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, State.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, State.FAULT),
)

_STATUSWORD: dict[State, int] = {
    State.NOT_READY: 0x0000,
    State.SWITCH_ON_DISABLED: 0x0040,
    State.READY_TO_SWITCH_ON: 0x0021,
    State.SWITCHED_ON: 0x0023,
    State.OPERATION_ENABLED: 0x0027,
    State.QUICK_STOP_ACTIVE: 0x0007,
    State.FAULT_REACTION_ACTIVE: 0x000F,
    State.FAULT: 0x0008,
}

MODES: dict[str, int] = {
    "pv": 3,    # profile velocity
    "tq": 4,    # profile torque
    "csp": 8,   # cyclic synchronous position
    "csv": 9,   # cyclic synchronous velocity
    "cst": 10,  # cyclic synchronous torque
}
"""Modes of operation (object 0x6060) the instrument can run a sweep in, by their short names."""

ABORT_CONNECTION_OPTIONS: dict[str, int] = {"fault": 1, "disable voltage": 2, "quick stop": 3}
"""Abort connection option codes (object 0x6007) by name: what a drive in "operation enabled" does when it loses its
connection to the host (for the instrument: the host's heartbeat, watched by the drive's heartbeat consumer 0x1016).
Code 0 (no action) and the manufacturer's negative codes are left out: none of them stops the drive for certain."""

TARGET_OBJECTS: dict[str, int] = {"pv": 0x60FF, "tq": 0x6071, "csp": 0x607A, "csv": 0x60FF, "cst": 0x6071}
"""The standard setpoint object of each mode: target position, target velocity, target torque."""


def decode_statusword(word: int) -> State | None:
    """The state a statusword reports; None for a pattern CiA 402 does not define."""
    for mask, value, state in _PATTERNS:
        if word & mask == value:
            return state
    return None


def statusword(state: State, *, voltage: bool = True, remote: bool = True, warning: bool = False) -> int:
    """The statusword a drive in ``state`` reports: the state's bits, voltage enabled (bit 4), warning (bit 7) and
    remote (bit 9)."""
    word = _STATUSWORD[state]
    if voltage and state not in (State.NOT_READY, State.SWITCH_ON_DISABLED):
        word |= 0x0010
    if warning:
        word |= 0x0080
    if remote:
        word |= 0x0200
    return word


def command_of(controlword: int, previous: int = 0) -> Command | None:
    """The command a controlword gives (a fault reset on the rising edge of bit 7 from ``previous``); None for a
    pattern that commands nothing."""
    if controlword & 0x80 and not previous & 0x80:
        return Command.FAULT_RESET
    if controlword & 0x02 == 0:
        return Command.DISABLE_VOLTAGE
    if controlword & 0x06 == 0x02:
        return Command.QUICK_STOP
    if controlword & 0x87 == 0x06:
        return Command.SHUTDOWN
    if controlword & 0x8F == 0x07:
        return Command.SWITCH_ON  # also "disable operation" from operation enabled
    if controlword & 0x8F == 0x0F:
        return Command.ENABLE_OPERATION
    return None


_TRANSITIONS: dict[tuple[State, Command], State] = {
    (State.SWITCH_ON_DISABLED, Command.SHUTDOWN): State.READY_TO_SWITCH_ON,             # 2
    (State.READY_TO_SWITCH_ON, Command.SWITCH_ON): State.SWITCHED_ON,                   # 3
    (State.SWITCHED_ON, Command.ENABLE_OPERATION): State.OPERATION_ENABLED,             # 4
    (State.OPERATION_ENABLED, Command.SWITCH_ON): State.SWITCHED_ON,                    # 5 (disable operation)
    (State.SWITCHED_ON, Command.SHUTDOWN): State.READY_TO_SWITCH_ON,                    # 6
    (State.READY_TO_SWITCH_ON, Command.DISABLE_VOLTAGE): State.SWITCH_ON_DISABLED,      # 7
    (State.READY_TO_SWITCH_ON, Command.QUICK_STOP): State.SWITCH_ON_DISABLED,           # 7
    (State.OPERATION_ENABLED, Command.SHUTDOWN): State.READY_TO_SWITCH_ON,              # 8
    (State.OPERATION_ENABLED, Command.DISABLE_VOLTAGE): State.SWITCH_ON_DISABLED,       # 9
    (State.SWITCHED_ON, Command.DISABLE_VOLTAGE): State.SWITCH_ON_DISABLED,             # 10
    (State.SWITCHED_ON, Command.QUICK_STOP): State.SWITCH_ON_DISABLED,                  # 10
    (State.OPERATION_ENABLED, Command.QUICK_STOP): State.QUICK_STOP_ACTIVE,             # 11
    (State.QUICK_STOP_ACTIVE, Command.DISABLE_VOLTAGE): State.SWITCH_ON_DISABLED,       # 12
    (State.FAULT, Command.FAULT_RESET): State.SWITCH_ON_DISABLED,                       # 15
}


def next_state(state: State, command: Command | None) -> State:
    """The state a drive in ``state`` goes to on ``command`` (the numbered transitions of CiA 402; a command that
    is no transition from ``state`` leaves it there)."""
    if command is None:
        return state
    return _TRANSITIONS.get((state, command), state)
