"""The words the floors exchange: how a point ended and why a sweep stopped.

String enums: a member equals its value (``PointStatus.CAPPED == "capped"``), which is what the results files
hold, so files written before these types existed read back unchanged.
"""

from __future__ import annotations

from enum import StrEnum


class PointStatus(StrEnum):
    """How the stopping rule ended a series (one channel, one harmonic, one frequency)."""

    CONVERGED = "converged"
    """The rule's error bound is within the tolerance."""
    BELOW_RESOLUTION = "below_resolution"
    """The coefficient is zero to within the instrument's resolution (phase undefined)."""
    NOISE_LIMITED = "noise_limited"
    """The noise would need more periods than allowed; the interval is stated, not within the tolerance."""
    CAPPED = "capped"
    """The period limit came first; the interval is stated, not within the tolerance."""
    DISTURBED = "disturbed"
    """A periodic disturbance line ([analysis] disturbance_hz) lies within the point's resolution of its harmonic:
    whatever of it reached the output is in the value, and the interval cannot show it; or what a line near a
    harmonic above the measured ones leaks into it kept the interval over the tolerance until the periods ran out;
    not converged."""
    ALIAS_LIMITED = "alias_limited"
    """The sample rate folds content of the response above the measured harmonics onto this one, the same in every
    period, and the bound on it the record gives (bodebench.core.benchgrid.fold_bound) does not fit in the tolerance:
    the interval includes that bound; not converged."""
    DIVISOR_LIMITED = "divisor_limited"
    """Two-channel mode: the divisor's fundamental scatters from period to period by more than a quarter of its size
    (bodebench.core.autointegration.MAX_DIVISOR_SCATTER), where a period's noise may come near the divisor itself
    and the average of the periods' ratios is biased beyond what their spread shows; not converged."""
    UNTIED = "untied"
    """Realtime clock, and the drive gives no way to date the sine on its own clock (no setpoint echo, no SYNC):
    the host's latency is in the phase; the gain stands, the phase does not; not converged."""
    FIXED = "fixed"
    """A fixed number of periods was averaged (criterion "fixed")."""


class FaultKind(StrEnum):
    """Why a bench sweep stopped before its end. In every case the drive was sent zero and disabled first."""

    WATCHDOG = "watchdog"
    """No valid feedback within the safety watchdog, or the host itself silent for longer than the drive's watchdog
    (the drive has then zeroed and disabled itself)."""
    FEEDBACK_LIMIT = "feedback_limit"
    """A feedback sample left its [safety] window."""
    BUS = "bus"
    """The bus or the drive link failed (bus off, send errors, a worker that went away)."""
    DRIVE = "drive"
    """The drive reported a fault (a CANopen emergency message, a CiA 402 fault state), fell silent (no heartbeat)
    or refused to enable."""
    ERROR = "error"
    """An unexpected error in the bus worker."""
    TIMEOUT = "timeout"
    """The bus worker did not answer in time."""
    NO_RESPONSE = "no_response"
    """The feedback stopped answering the sine: an output or the setpoint echo held one value for whole periods (a
    drive disabled or tripped by its own watchdog, a setpoint below the resolution of its frame)."""
    ABORT = "abort"
    """The user aborted (Ctrl-C, the abort key, SIGTERM or SIGHUP)."""
    OUTPUT = "output"
    """A converged point could not be written to the results directory."""
