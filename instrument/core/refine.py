"""Where an adaptive sweep adds frequencies: the plan's rule, pure (no I/O).

A sweep measures a coarse grid, then asks :func:`next_round` where to measure next. Two things call for a new
frequency:

- **A figure not yet known to its accuracy.** Each requested figure of the summary
  (:mod:`bodebench.core.summary`) carries an estimate of the error that interpolating between the points makes.
  Where that estimate exceeds the requested accuracy (a percent of the figure for one read as a frequency, dB or
  degrees for the others), the next frequency is the figure's own estimate (the crossing, the resonance's vertex):
  measured there, the figure's bracket closes around it, and its interpolation error with it. For the resonance
  peak the distance between the vertex and the largest measured point counts as its frequency's error; a peak the
  points do not resolve gets the middles of the two intervals around the largest point.
- **A curve that bends between two points** (unless the plan asks for its figures alone, ``curve`` false).
  Where the gain or the phase interpolated halfway between two neighbours may be off by more than the curve's
  accuracy (their curvature, as the summary estimates it), the middle (in log frequency) is added. This finds
  what no figure names: a lightly damped mode between two coarse points shows as a phase drop that bends the
  curve there. Where the interval is too narrow to take a point (see below), the curve's standing says it is
  not within its accuracy there: a jump, or a mode narrower than the resolution asked for.

A figure whose 95 % interval is wider than its accuracy is limited by the measurement, not by the spacing:
more frequencies do not help it and none are added for it; its standing says so. Nothing is added closer to a
measured frequency than :data:`MIN_GAP_SHARE` of the frequency accuracy (relative): the spacing has done its part
there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bodebench.core.response import FrequencyResponse
from bodebench.core.summary import (
    ChannelCurve,
    Figure,
    channel_curves,
    interpolation_error,
    summarize_response,
    unwrapped_phase,
)

__all__ = ["FIGURE_NAMES", "MIN_GAP_SHARE", "Addition", "PlanTargets", "Round", "Standing", "next_round"]

FIGURE_NAMES = {
    "bandwidth": "bandwidth (-3 dB)",
    "resonance": "resonance peak",
    "phase_90": "phase -90 deg",
    "phase_180": "phase -180 deg",
    "phase_margin": "phase margin",
    "gain_margin": "gain margin",
}
"""A plan's name of each figure it can pin down -> the summary's name of it."""

MIN_GAP_SHARE = 0.25
"""No frequency is added within this share of the frequency accuracy (relative) of one already measured."""


class PlanTargets(Protocol):
    """The accuracies an adaptive plan asks for (``excitation.frequencies.adaptive``)."""

    @property
    def figures(self) -> tuple[str, ...]: ...
    @property
    def frequency_percent(self) -> float: ...
    @property
    def gain_db(self) -> float: ...
    @property
    def phase_deg(self) -> float: ...
    @property
    def curve(self) -> bool: ...
    @property
    def curve_gain_db(self) -> float: ...
    @property
    def curve_phase_deg(self) -> float: ...


@dataclass(frozen=True)
class Addition:
    """A frequency (Hz) the plan adds, and why."""

    frequency_hz: float
    reason: str


@dataclass(frozen=True)
class Standing:
    """Where a requested figure stands: ``found`` in the measured range or not, ``met`` when its interpolation
    error is within ``accuracy`` (both in ``unit``); ``measurement`` is its 95 % half-interval; ``text`` says it
    in words."""

    channel: str
    figure: str
    unit: str
    accuracy: float
    interpolation: float
    measurement: float
    found: bool
    met: bool
    text: str


@dataclass(frozen=True)
class Round:
    """The plan's next step: the frequencies to add (none: the plan is done) and where each figure stands."""

    additions: tuple[Addition, ...]
    standings: tuple[Standing, ...]


def _accuracy(figure: Figure, targets: PlanTargets) -> float:
    """The accuracy asked of ``figure``, in its unit."""
    if figure.unit == "Hz":
        return targets.frequency_percent / 100.0 * figure.value
    return targets.gain_db if figure.unit == "dB" else targets.phase_deg


def _peak_frequency_error(figure: Figure, f: np.ndarray, gain: np.ndarray) -> float:
    """The resonance frequency's error (Hz): the vertex's distance from the largest measured point (inf when the
    points do not resolve the peak)."""
    if not math.isfinite(figure.interpolation):
        return math.inf
    return abs(figure.at_hz - float(f[int(np.argmax(gain))]))


def _figure_round(curve: ChannelCurve, figure: Figure, key: str, targets: PlanTargets
                  ) -> tuple[list[list[Addition]], Standing]:
    """What one requested figure of one channel asks for: frequencies to add, each with the alternatives to take
    where it is too near one measured, and the figure's standing."""
    f = curve.frequency_hz
    accuracy = _accuracy(figure, targets)
    half = (figure.high - figure.low) / 2.0 if math.isfinite(figure.high - figure.low) else math.inf
    label = f"{curve.channel}: {figure.name}"
    if not figure.found:
        return [], Standing(curve.channel, key, figure.unit, accuracy, math.nan, math.nan, False, False,
                            f"{label}: {figure.note}")
    errors = [(figure.interpolation, accuracy, figure.unit, figure.value)]
    wanted = figure.at_hz if math.isfinite(figure.at_hz) else figure.value
    if key == "resonance":
        f_accuracy = targets.frequency_percent / 100.0 * figure.at_hz
        errors.append((_peak_frequency_error(figure, f, curve.gain_db), f_accuracy, "Hz", figure.at_hz))
    over = [(e, a, u, v) for e, a, u, v in errors if not e <= a]
    met = not over
    if met:
        text = f"{label}: interpolation +-{figure.interpolation:.3g} {figure.unit}, within {accuracy:.3g}"
    else:
        e, a, u, v = over[0]
        shown = "not resolved by the points" if not math.isfinite(e) else f"+-{e:.3g} {u}"
        text = f"{label} ({v:.4g} {u}): interpolation {shown} > {a:.3g} {u}"
    if half > accuracy:
        text += f"; its 95 % interval (+-{half:.3g} {figure.unit}) is wider than that: limited by the measurement"
    standing = Standing(curve.channel, key, figure.unit, accuracy, figure.interpolation, half, True, met, text)
    if met or half > accuracy:  # within its accuracy, or out of the spacing's reach
        return [], standing
    if key == "resonance" and not math.isfinite(figure.interpolation):
        i = int(np.argmax(curve.gain_db))
        return [[Addition(math.sqrt(f[i - 1] * f[i]), text)], [Addition(math.sqrt(f[i] * f[i + 1]), text)]], standing
    # at the figure's estimate; where a point is there already, the middle of the interval it lies in
    i = min(max(int(np.searchsorted(f, wanted)) - 1, 0), len(f) - 2)
    return [[Addition(float(wanted), text), Addition(math.sqrt(f[i] * f[i + 1]), text)]], standing


def _curve_round(curve: ChannelCurve, targets: PlanTargets) -> tuple[list[list[Addition]], Standing]:
    """The middles of the intervals where the gain or the phase may bend more than the curve's accuracy, and where
    the curve stands: not within its accuracy where such an interval is too narrow to split."""
    x = np.log10(curve.frequency_hz)
    phase = unwrapped_phase(curve.phase_deg)
    out: list[list[Addition]] = []
    unsplit: list[str] = []
    narrowest = 2.0 * MIN_GAP_SHARE * targets.frequency_percent / 100.0 / math.log(10.0)  # decades: no middle
    worst = 0.0
    for i in range(len(x) - 1):
        middle = 0.5 * (x[i] + x[i + 1])
        gain_error = interpolation_error(x, curve.gain_db, i, middle)
        phase_error = interpolation_error(x, phase, i, middle)
        a, b = curve.frequency_hz[i], curve.frequency_hz[i + 1]
        between = f"{curve.channel}: the curve between {a:.4g} and {b:.4g} Hz"
        if gain_error > targets.curve_gain_db:
            said = f"gain interpolation +-{gain_error:.3g} dB > {targets.curve_gain_db:g} dB"
        elif phase_error > targets.curve_phase_deg:
            said = f"phase interpolation +-{phase_error:.3g} deg > {targets.curve_phase_deg:g} deg"
        else:
            continue
        worst = max(worst, gain_error / targets.curve_gain_db, phase_error / targets.curve_phase_deg)
        if x[i + 1] - x[i] < narrowest:  # its middle would lie nearer a point than the plan adds any: a jump,
            unsplit.append(f"{a:.4g} to {b:.4g} Hz")  # or a mode narrower than the resolution asked for
        else:
            out.append([Addition(float(10.0**middle), f"{between}: {said}")])
    if unsplit:
        text = (f"{curve.channel}: the curve: bends beyond its accuracy between points too close to add one "
                f"between ({', '.join(unsplit)}): a jump, or a mode narrower than the resolution asked for "
                "(frequency_percent)")
    elif out:
        text = f"{curve.channel}: the curve: bends beyond its accuracy in {len(out)} intervals"
    else:
        text = f"{curve.channel}: the curve: within {targets.curve_gain_db:g} dB and {targets.curve_phase_deg:g} deg"
    return out, Standing(curve.channel, "curve", "", 1.0, worst, math.nan, True, not unsplit and not out, text)


def next_round(response: FrequencyResponse, targets: PlanTargets, kind: str = "system",
               measured_hz: Sequence[float] = (), apart_from_points: bool = True) -> Round:
    """The frequencies (Hz) to measure next, and where each requested figure stands, from the harmonic-1 points of
    ``response`` read as ``kind`` (:data:`~bodebench.core.summary.RESPONSE_KINDS`). ``measured_hz``: frequencies
    measured or planned already besides those with points (a point that ended without a result); nothing is added
    near any of them, nor near the points of ``response`` unless ``apart_from_points`` is False (the points are an
    overview's lines, not measured frequencies of the sweep). Each addition lies between the lowest and the
    highest of these frequencies; the additions
    are in the order of need (the figures' first, then the curve's), one per place (the first reason given for
    it)."""
    curves = {c.channel: c for c in channel_curves(response)}
    summaries = summarize_response(response, kind)
    gap = MIN_GAP_SHARE * targets.frequency_percent / 100.0
    taken = sorted({*measured_hz, *(float(f) for c in curves.values() for f in c.frequency_hz
                                     if apart_from_points)})
    wanted: list[list[Addition]] = []
    standings: list[Standing] = []
    for summary in summaries:
        curve = curves[summary.channel]
        names = {figure.name: figure for figure in summary.figures}
        for key in targets.figures:
            figure = names.get(FIGURE_NAMES[key])
            if figure is None:  # not a figure of this kind of response
                continue
            more, standing = _figure_round(curve, figure, key, targets)
            wanted += more
            standings.append(standing)
    for curve in curves.values() if targets.curve else ():
        more, standing = _curve_round(curve, targets)
        wanted += more
        standings.append(standing)
    lo, hi = (min(taken), max(taken)) if taken else (math.inf, -math.inf)
    chosen: list[Addition] = []
    for alternatives in wanted:
        for addition in alternatives:
            f = addition.frequency_hz
            if lo < f < hi and all(abs(math.log(f / g)) >= gap for g in [*taken, *(a.frequency_hz for a in chosen)]):
                chosen.append(addition)
                break
    return Round(tuple(chosen), tuple(standings))
