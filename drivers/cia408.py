"""The CiA 408 device state machine of a fluid-power device (a proportional valve or a hydraulic drive; pure, no
I/O): status word decoding, control words, and the transitions a device makes on them.

CiA 408 is not CiA 402: the control word 0x6040 carries four bits, D (bit 0, disabled), H (bit 1, hold), M (bit 2,
device mode active) and R (bit 3, reset fault, on its rising edge), and the bits set ask for a state: D alone
DISABLED, D and H HOLD, D, H and M ACTIVE. The status word 0x6041 reports the state in its low four bits (R M H D).
DISABLED is the hydraulic fail-safe (the spool at its fail-safe position), HOLD runs the device's control loop on
the hold set point (bus set points have no effect), ACTIVE makes the bus set points effective (with device mode
0x6042 = 1). A hardware enable input gates HOLD and ACTIVE: without it a device stays DISABLED. A fault takes the
device to FAULT_REACTION (with an EMCY) and then FAULT_HOLD or FAULT_DISABLED, until a reset.

Both ends use it: the instrument decodes the status word it reads and walks the device through its states; the
simulated CiA 408 device changes state with the same table.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = [
    "CONTROLWORD",
    "CONTROL_MODES",
    "DEFAULT_SPOOL_REFERENCE",
    "FAULT_STATES",
    "PREFIX_SUBINDEX",
    "PROCESS_VALUES",
    "RESET_BIT",
    "SPOOL_REFERENCE",
    "State",
    "decode_statusword",
    "is_spool_value",
    "next_state",
    "process_value_scale",
    "requested_state",
    "statusword",
]


class State(StrEnum):
    """The states of the CiA 408 device state machine."""

    NOT_READY = "NOT READY"
    INIT = "INIT"
    DISABLED = "DISABLED"
    HOLD = "HOLD"
    ACTIVE = "ACTIVE"
    FAULT_REACTION = "FAULT_REACTION"
    FAULT_HOLD = "FAULT_HOLD"
    FAULT_DISABLED = "FAULT_DISABLED"


_NIBBLE: dict[State, int] = {
    State.NOT_READY: 0b0000,
    State.INIT: 0b1000,
    State.DISABLED: 0b1001,
    State.HOLD: 0b1011,
    State.ACTIVE: 0b1111,
    State.FAULT_REACTION: 0b0111,
    State.FAULT_HOLD: 0b0011,
    State.FAULT_DISABLED: 0b0001,
}
_BY_NIBBLE = {nibble: state for state, nibble in _NIBBLE.items()}

FAULT_STATES = frozenset({State.FAULT_REACTION, State.FAULT_HOLD, State.FAULT_DISABLED})
"""The states a device reaches on a fault; left only by a reset (control word bit 3)."""

CONTROLWORD: dict[State, int] = {State.DISABLED: 0x0001, State.HOLD: 0x0003, State.ACTIVE: 0x0007}
"""The control word the instrument writes to ask for each state (bits D, H, M; the others zero)."""

RESET_BIT = 0x0008
"""Control word bit 3 (R): a fault is reset on its rising edge."""

CONTROL_MODES: dict[str, int] = {
    "spool_open_loop": 1,  # spool position, open loop
    "spool": 2,            # spool position, closed loop
    "pq": 5,               # pressure/flow (p/Q): the pressure set point swept
    "velocity": 7,         # axis velocity
    "position": 9,         # axis position
}
"""Control modes (object 0x6043) the instrument can run a sweep in, by their short names."""

PROCESS_VALUES: dict[str, tuple[int, int]] = {
    "spool_open_loop": (0x6300, 0x6301),
    "spool": (0x6300, 0x6301),
    "pq": (0x6380, 0x6381),
    "velocity": (0x6500, 0x6501),
    "position": (0x6600, 0x6601),
}
"""The (set point, actual value) process-value records of each control mode; the value is sub-index 1, its SI
unit code sub-index 2 and its decimal prefix sub-index 3."""


def decode_statusword(word: int) -> State | None:
    """The state a status word reports in its low four bits; None for a pattern CiA 408 does not define."""
    return _BY_NIBBLE.get(word & 0x0F)


def statusword(state: State, *, local: bool = False) -> int:
    """The status word a device in ``state`` reports: the state's bits and bit 4 (local: the device does not take
    its control word from the bus)."""
    return _NIBBLE[state] | (0x0010 if local else 0)


def requested_state(controlword: int) -> State:
    """The state the D, H and M bits of ``controlword`` ask for: ACTIVE, HOLD, DISABLED, or NOT_READY for none
    (a device left with no bit set stays in DISABLED)."""
    if controlword & 0x07 == 0x07:
        return State.ACTIVE
    if controlword & 0x03 == 0x03:
        return State.HOLD
    if controlword & 0x01:
        return State.DISABLED
    return State.NOT_READY


def next_state(state: State, controlword: int, previous: int = 0, *, enable_input: bool = True) -> State:
    """The state a device in ``state`` goes to on ``controlword`` (``previous``: the control word before it, for the
    reset edge). A fault state is left only by a rising edge of bit 3, to DISABLED; HOLD and ACTIVE need the
    hardware enable input; without any of bits D, H, M the device stays DISABLED (its fail-safe), and NOT_READY and
    INIT are left by the device itself, not by a control word."""
    if state in FAULT_STATES:
        if state is not State.FAULT_REACTION and controlword & RESET_BIT and not previous & RESET_BIT:
            return State.DISABLED
        return state
    if state in (State.NOT_READY, State.INIT):
        return state
    wanted = requested_state(controlword)
    if wanted in (State.HOLD, State.ACTIVE) and not enable_input:
        return State.DISABLED
    if wanted is State.NOT_READY:
        return State.DISABLED
    return wanted

SPOOL_REFERENCE = (0x6311, 1)
"""The spool position reference value (index, sub-index): the increments that stand for 100 %."""
DEFAULT_SPOOL_REFERENCE = 16384
"""The spool reference value of common devices, where an EDS gives none."""
PREFIX_SUBINDEX = 3
"""The sub-index of a process value record that holds its decimal prefix (sub-index 2: its SI unit code)."""


def is_spool_value(index: int) -> bool:
    """Whether object ``index`` is one of the spool position values (0x6300 to 0x637F), counted in increments of the
    reference value."""
    return 0x6300 <= index < 0x6380


def process_value_scale(index: int, *, reference: int = DEFAULT_SPOOL_REFERENCE, prefix: int = 0) -> float:
    """Engineering units per count of process value ``index``: a spool value in % of ``reference``; any other
    10**``prefix`` of its SI unit."""
    if is_spool_value(index):
        return 100.0 / reference
    return 10.0 ** prefix
