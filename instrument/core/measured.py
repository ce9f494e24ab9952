"""What a sweep measures, formed from the drive's feedback channels (``[analysis] measured``).

With the excitation d added to a closed loop's controller output u_c at the plant input (a drive's torque or
velocity offset), the plant input is u = u_c + d, and with y the plant's output:

- ``output`` (default): each output channel against the excitation (the closed loop from where the host injects);
- ``plant``: each output channel relative to the effort channel u: y / u = P;
- ``loop``: the control channel relative to the effort channel, negated: -u_c / u = L, the loop gain;
- ``sensitivity``: u / d = 1 / (1 + L), d = u - u_c;
- ``complementary``: -u_c / d = L / (1 + L).

The modes but ``output`` are ratios of two measured channels, taken period by period (two-channel mode,
:class:`~bodebench.core.autointegration.Autointegrator` ``reference``), so the delay of the path from the host to
the drive never enters them, and noise common to both channels is handled where it arises, in each period's ratio.
Each analysed column is a signed sum of feedback channels (d = u - u_c is the difference of two). Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MEASURED", "RATIO_MODES", "INJECTION", "Formed", "FormError", "formed_columns"]

MEASURED = ("output", "plant", "loop", "sensitivity", "complementary")
"""What a sweep may measure (module docstring)."""
RATIO_MODES = ("loop", "sensitivity", "complementary")
"""Modes formed from the effort and control channels alone, at harmonic 1."""
INJECTION = "injection"
"""Name of the column d = u - u_c, the excitation as the plant input received it."""


class FormError(ValueError):
    """A mode lacks a channel: ``field`` names the bench key (effort_channel, control_channel, output_channels)."""

    def __init__(self, field: str, text: str) -> None:
        super().__init__(text)
        self.field = field


@dataclass(frozen=True)
class Formed:
    """The analysed columns of a mode: ``outputs`` then ``reference`` ("" for none), each a signed sum of the
    feedback channels ``raw`` (``terms``: per analysed column, (index into raw, weight) pairs)."""

    outputs: tuple[str, ...]
    reference: str
    raw: tuple[str, ...]
    terms: tuple[tuple[tuple[int, float], ...], ...]

    @property
    def selects(self) -> bool:
        """True when every analysed column is one raw channel as it is (no sum, no sign)."""
        return all(len(t) == 1 and t[0][1] == 1.0 for t in self.terms) and len(self.terms) == len(self.raw)

    def formulas(self) -> tuple[str, ...]:
        """Each analysed column as the drive's channels form it, for a reader ("loop = -control / effort",
        "position against the excitation")."""
        def expression(column: tuple[tuple[int, float], ...]) -> str:
            (first, sign), *rest = column
            text = ("-" if sign < 0 else "") + self.raw[first]
            text += "".join(f" {'-' if weight < 0 else '+'} {self.raw[index]}" for index, weight in rest)
            return f"({text})" if rest else text

        divisor = f" / {expression(self.terms[-1])}" if self.reference else " against the excitation"
        numerators = (expression(column) for column in self.terms[:len(self.outputs)])
        return tuple(f"{name}{divisor}" if numerator == name else f"{name} = {numerator}{divisor}"
                     for name, numerator in zip(self.outputs, numerators, strict=True))

    def combine(self, values: np.ndarray) -> np.ndarray:
        """(n, len(raw)) feedback samples -> (n, analysed columns)."""
        if self.selects:
            return values[:, [t[0][0] for t in self.terms]]
        out = np.zeros((values.shape[0], len(self.terms)))
        for j, column in enumerate(self.terms):
            for index, weight in column:
                out[:, j] += weight * values[:, index]
        return out


def formed_columns(measured: str, output_channels: tuple[str, ...], reference_channel: str = "",
                   effort_channel: str = "", control_channel: str = "") -> Formed:
    """The analysed columns of ``measured`` (:data:`MEASURED`); :class:`FormError` naming what a mode lacks."""
    if measured not in MEASURED:
        raise ValueError(f"measured must be one of {', '.join(MEASURED)}, got {measured!r}")
    if measured == "output":
        return _selected(output_channels, reference_channel)
    if not effort_channel:
        raise FormError("effort_channel", f"missing: {measured} divides by the plant input after the excitation "
                                          "(the effort channel)")
    if measured == "plant":
        outputs = tuple(name for name in output_channels if name != effort_channel)
        if not outputs:
            raise FormError("output_channels", "plant: needs an output channel besides the effort channel")
        return _selected(outputs, effort_channel)
    if not control_channel:
        raise FormError("control_channel", f"missing: {measured} needs the controller output before the "
                                           "excitation (the control channel)")
    if control_channel == effort_channel:
        raise FormError("control_channel", f"{measured}: the control and effort channels must differ")
    raw = (effort_channel, control_channel)
    effort, minus_control, injection = ((0, 1.0),), ((1, -1.0),), ((0, 1.0), (1, -1.0))
    if measured == "loop":
        return Formed(("loop",), effort_channel, raw, (minus_control, effort))
    if measured == "sensitivity":
        return Formed(("sensitivity",), INJECTION, raw, (effort, injection))
    return Formed(("complementary",), INJECTION, raw, (minus_control, injection))


def _selected(outputs: tuple[str, ...], reference: str) -> Formed:
    """Columns that are channels as they are: ``outputs``, then the divisor ``reference`` ("" for none)."""
    raw = (*outputs, *((reference,) if reference else ()))
    return Formed(outputs, reference, raw, tuple(((i, 1.0),) for i in range(len(raw))))
