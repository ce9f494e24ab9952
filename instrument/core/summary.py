"""The figures a servo engineer reads off a measured response: bandwidth, resonance peak, phase crossings and,
for an open loop, the gain and phase margins with their crossover frequencies.

Everything is computed on the measured points of the first harmonic of one channel, never on a fitted model.
Between two points the gain in dB and the unwrapped phase in degrees are interpolated linearly in log10
frequency; nothing is extrapolated beyond the lowest or the highest measured frequency: a figure whose
defining crossing lies outside is reported as not found, with the reason.

Each figure carries three things:

- ``value``: the figure from the measured values;
- ``low``/``high``: its 95 % interval, the same construction run on the lower and upper bounds of each point's
  95 % gain and phase intervals (NaN where such a bound leaves the measured range);
- ``interpolation``: an estimate of the error that linear interpolation between the points makes, from the
  curvature of the neighbouring points (twice the classical ``(x - x_i)(x_{i+1} - x) |y''| / 2``, the factor a
  margin for curvature that changes between the points), in the figure's units; for the resonance peak, what
  the local pole-pair form through the three points around the largest adds to the largest measured gain. It
  is separate from the interval, which is about the measurement, and shrinks as the square of the point
  spacing.

Pure numerics: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bodebench.core.response import FrequencyResponse

__all__ = [
    "CONFIDENCE",
    "ChannelCurve",
    "RESPONSE_KINDS",
    "Figure",
    "ResponseSummary",
    "channel_curves",
    "interpolation_error",
    "summarize",
    "summarize_response",
    "unwrapped_phase",
]

CONFIDENCE = 0.95
"""Level of every interval of the summary (that of the points' intervals)."""

RESPONSE_KINDS = ("system", "closed_loop", "open_loop")
"""What a measured response is: a system's (a plant or a drive), a closed loop's, or an open loop's (margins)."""

BANDWIDTH_DROP_DB = 10.0 * math.log10(2.0)
"""The bandwidth is where the gain has fallen this far below the reference gain: half the power (a gain ratio of
1/sqrt(2), 3.01 dB)."""

_FLOOR_DB = -400.0  # a lower gain bound of a point whose interval holds zero


@dataclass(frozen=True)
class Figure:
    """One summary figure. ``value``, ``low``, ``high`` and ``interpolation`` are in ``unit``; for a figure read at
    a frequency (a peak, a margin) ``at_hz`` is that frequency with its 95 % interval ``at_low_hz``/``at_high_hz``.
    NaN means not found (``value``) or not bounded within the measured range (an interval end); ``note`` says
    why a figure is not found, or qualifies one that is."""

    name: str
    unit: str
    value: float = math.nan
    low: float = math.nan
    high: float = math.nan
    interpolation: float = math.nan
    at_hz: float = math.nan
    at_low_hz: float = math.nan
    at_high_hz: float = math.nan
    note: str = ""

    @property
    def found(self) -> bool:
        return math.isfinite(self.value)

    def to_json(self) -> dict[str, Any]:
        """JSON types only (NaN becomes null)."""
        out: dict[str, Any] = {"name": self.name, "unit": self.unit, "found": self.found}
        for key in ("value", "low", "high", "interpolation", "at_hz", "at_low_hz", "at_high_hz"):
            value = getattr(self, key)
            out[key] = float(value) if math.isfinite(value) else None
        out["note"] = self.note
        return out

    def text(self) -> str:
        """One line, e.g. ``bandwidth (-3 dB): 4.21 Hz (95 %: 4.18 to 4.25; interpolation +-0.01)``."""
        if not self.found:
            return f"{self.name}: {self.note}"

        def show(value: float) -> str:
            return f"{value:.4g}" if math.isfinite(value) else "?"

        unit = f" {self.unit}" if self.unit else ""
        line = f"{self.name}: {show(self.value)}{unit}"
        if math.isfinite(self.at_hz):
            line += f" at {show(self.at_hz)} Hz"
        extra = [f"95 %: {show(self.low)} to {show(self.high)}"]
        if math.isfinite(self.at_hz):
            extra.append(f"frequency {show(self.at_low_hz)} to {show(self.at_high_hz)} Hz")
        if math.isfinite(self.interpolation) and self.interpolation >= abs(self.value) > 0.0:
            extra.append("interpolation error larger than the figure: measure more frequencies near it")
        elif math.isfinite(self.interpolation):
            extra.append(f"interpolation +-{self.interpolation:.2g}")
        line += f" ({'; '.join(extra)})"
        if self.note:
            line += f"; {self.note}"
        return line


@dataclass(frozen=True)
class ResponseSummary:
    """The summary of harmonic 1 of one channel. ``reference_db`` is the gain the bandwidth and the resonance peak
    are relative to: the gain at the lowest measured frequency ``reference_hz``, with its 95 % interval."""

    channel: str
    kind: str
    points: int
    reference_hz: float
    reference_db: float
    reference_low_db: float
    reference_high_db: float
    figures: tuple[Figure, ...]
    note: str = ""

    def figure(self, name: str) -> Figure:
        """The figure called ``name`` (KeyError if absent)."""
        for item in self.figures:
            if item.name == name:
                return item
        raise KeyError(name)

    def to_json(self) -> dict[str, Any]:
        def num(value: float) -> float | None:
            return float(value) if math.isfinite(value) else None

        return {
            "harmonic": 1,
            "channel": self.channel,
            "response": self.kind,
            "confidence": CONFIDENCE,
            "points": self.points,
            "reference": {"frequency_hz": num(self.reference_hz), "gain_db": num(self.reference_db),
                          "low_db": num(self.reference_low_db), "high_db": num(self.reference_high_db),
                          "meaning": "gain at the lowest measured frequency; bandwidth and peak are relative "
                                     "to it"},
            "figures": [f.to_json() for f in self.figures],
            "note": self.note,
        }

    def lines(self) -> list[str]:
        """Human-readable lines, the first naming the channel and the reference."""
        head = (f"{self.channel}, harmonic 1 ({self.kind.replace('_', ' ')}, {self.points} points; intervals "
                f"{CONFIDENCE:.0%}): reference gain {self.reference_db:.4g} dB at {self.reference_hz:.4g} Hz")
        if self.note:
            head += f"; {self.note}"
        return [head] + ["  " + f.text() for f in self.figures]


# --------------------------------------------------------------------------------------------------- curves


@dataclass(frozen=True)
class _Curve:
    """One quantity against x = log10(f): the value and its 95 % bounds at each point."""

    x: np.ndarray
    y: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def _interp(curve_x: np.ndarray, y: np.ndarray, x: float) -> float:
    return float(np.interp(x, curve_x, y))


def _crossings(x: np.ndarray, y: np.ndarray, level: float, downward: bool) -> list[tuple[int, float]]:
    """Segments i where y passes ``level`` (downward: from above to at-or-below), with the interpolated x."""
    out: list[tuple[int, float]] = []
    d = y - level if downward else level - y
    for i in range(len(x) - 1):
        if d[i] > 0.0 >= d[i + 1]:
            t = d[i] / (d[i] - d[i + 1])
            out.append((i, float(x[i] + t * (x[i + 1] - x[i]))))
    return out


def _curvature(x: np.ndarray, y: np.ndarray, i: int) -> float:
    """Largest |y''| of the second divided differences of the point triples around segment i (0: too few)."""
    best = 0.0
    for j in (i - 1, i, i + 1):
        if j - 1 >= 0 and j + 1 < len(x):
            s1 = (y[j] - y[j - 1]) / (x[j] - x[j - 1])
            s2 = (y[j + 1] - y[j]) / (x[j + 1] - x[j])
            best = max(best, abs(2.0 * (s2 - s1) / (x[j + 1] - x[j - 1])))
    return best


def interpolation_error(x: np.ndarray, y: np.ndarray, i: int, at: float) -> float:
    """Estimated error of y linearly interpolated at ``at`` in segment i, y's units: twice the classical estimate,
    as a margin for curvature that changes between the points."""
    return 1.0 * (at - x[i]) * (x[i + 1] - at) * _curvature(x, y, i)


def _crossing_x_error(x: np.ndarray, y: np.ndarray, i: int, at: float) -> float:
    """Estimated error of a crossing's x in segment i (decades), from the value error over the slope."""
    slope = (y[i + 1] - y[i]) / (x[i + 1] - x[i])
    if slope == 0.0:
        return math.inf
    return interpolation_error(x, y, i, at) / abs(slope)


def _hz(x: float) -> float:
    return 10.0**x if math.isfinite(x) else math.nan


def _hz_error(x: float, dx: float) -> float:
    """A frequency's error in Hz from its log10 error ``dx`` (the larger side)."""
    return 10.0**x * (10.0**dx - 1.0) if math.isfinite(dx) else math.nan


def _nearest(found: list[tuple[int, float]], x: float) -> float:
    return min((c for _, c in found), key=lambda c: abs(c - x)) if found else math.nan


def _range_name(x: np.ndarray) -> str:
    return f"{10.0 ** x[0]:.4g} to {10.0 ** x[-1]:.4g} Hz"


# --------------------------------------------------------------------------------------------------- figures


def _bandwidth(gain: _Curve, ref: float, ref_lo: float, ref_hi: float) -> Figure:
    name = "bandwidth (-3 dB)"
    found = _crossings(gain.x, gain.y, ref - BANDWIDTH_DROP_DB, True)
    if not found:
        return Figure(name, "Hz", note=f"not found in the measured range ({_range_name(gain.x)}): the gain stays "
                                       f"above {ref - BANDWIDTH_DROP_DB:.4g} dB")
    i, xc = found[0]
    # Earliest plausible crossing: the gain as low and the reference as high as their intervals allow.
    low = _crossings(gain.x, gain.lo, ref_hi - BANDWIDTH_DROP_DB, True)
    high = _crossings(gain.x, gain.hi, ref_lo - BANDWIDTH_DROP_DB, True)
    dx = _crossing_x_error(gain.x, gain.y, i, xc)
    return Figure(name, "Hz", value=_hz(xc), low=_hz(low[0][1]) if low else math.nan,
                  high=_hz(high[0][1]) if high else math.nan, interpolation=_hz_error(xc, dx))


def _pole_pair(x: np.ndarray, y: np.ndarray) -> tuple[float, float] | None:
    """Vertex (x, y) of the local pole-pair form through three points: 1/|G|^2 quadratic in f^2, which a lightly
    damped pair of poles follows exactly (a second-order system: (1 - u^2)^2 + (2 zeta u)^2 with u = f/f_n).
    None where the three points do not have that shape (no minimum of 1/|G|^2 above zero between them)."""
    v = 10.0 ** (2.0 * np.asarray(x, dtype=float))
    w = 10.0 ** (-np.asarray(y, dtype=float) / 10.0)
    a, b, c = np.polyfit(v / v[1], w / w[1], 2)
    if not a > 0.0:
        return None
    vv = -b / (2.0 * a)
    wv = c - b * b / (4.0 * a)
    if not (v[0] / v[1] <= vv <= v[2] / v[1]) or not wv > 0.0:
        return None
    return float(0.5 * math.log10(vv * v[1])), float(-10.0 * math.log10(wv * w[1]))


def _peak(gain: _Curve, ref: float, ref_lo: float, ref_hi: float) -> Figure:
    name = "resonance peak"
    i = int(np.argmax(gain.y))
    if i == 0:
        return Figure(name, "dB", note="none: the gain never rises above its value at the lowest frequency")
    if i == len(gain.x) - 1:
        return Figure(name, "dB", note=f"not found in the measured range ({_range_name(gain.x)}): the gain still "
                                       "rises at the highest frequency")
    around = slice(i - 1, i + 2)
    xs = gain.x[around]
    largest = float(gain.y[i])
    pair = _pole_pair(xs, gain.y[around])
    if pair is None:  # the points do not resolve the peak's shape: the largest of them, a lower bound
        xv, yv = float(gain.x[i]), largest
        interpolation = math.nan
        note = "not resolved by the points (the largest measured gain: the peak may be higher)"
    else:
        xv, yv = pair
        interpolation = abs(yv - largest)  # what the local form adds to the largest measured gain
        note = f"largest measured: {largest - ref:.4g} dB at {_hz(float(gain.x[i])):.4g} Hz"
    note = f"above the gain at {_hz(float(gain.x[0])):.4g} Hz; {note}"
    bounds = []
    for curve in (gain.lo, gain.hi):
        at = _pole_pair(xs, curve[around]) if pair is not None else None
        bounds.append(max(at[1] if at is not None else float(curve[i]), float(curve[i])))
    # The points that could be the largest: their upper bound reaches the largest point's lower bound.
    could = np.flatnonzero(gain.hi >= gain.lo[i])
    first, last = max(int(could[0]) - 1, 0), min(int(could[-1]) + 1, len(gain.x) - 1)
    return Figure(name, "dB", value=yv - ref, low=bounds[0] - ref_hi, high=bounds[1] - ref_lo,
                  interpolation=interpolation, at_hz=_hz(xv), at_low_hz=_hz(float(gain.x[first])),
                  at_high_hz=_hz(float(gain.x[last])), note=note)


def _phase_crossing(phase: _Curve, level: float) -> Figure:
    name = f"phase {level:g} deg"
    found = _crossings(phase.x, phase.y, level, True)
    if not found:
        side = "above" if phase.y[-1] > level else "below"
        return Figure(name, "Hz", note=f"not found in the measured range ({_range_name(phase.x)}): the phase stays "
                                       f"{side} {level:g} deg")
    i, xc = found[0]
    ends = [_nearest(_crossings(phase.x, b, level, True), xc) for b in (phase.lo, phase.hi)]
    known = [e for e in ends if math.isfinite(e)]
    low = _hz(min(known)) if len(known) == 2 else math.nan
    high = _hz(max(known)) if len(known) == 2 else math.nan
    if len(known) == 1:  # one bound leaves the range: that side of the interval is open
        if known[0] <= xc:
            low = _hz(known[0])
        else:
            high = _hz(known[0])
    dx = _crossing_x_error(phase.x, phase.y, i, xc)
    note = f"first of {len(found)} crossings" if len(found) > 1 else ""
    return Figure(name, "Hz", value=_hz(xc), low=low, high=high, interpolation=_hz_error(xc, dx), note=note)


def _span(x: np.ndarray, a: float, b: float) -> np.ndarray:
    """The x values where a curve's extremes over [a, b] can lie: the ends and the points inside."""
    inside = x[(x > a) & (x < b)]
    return np.concatenate(([a, b], inside))


def _margin(driver: _Curve, reader: _Curve, level: float, name: str, unit: str,
            value_of: Any, what: str) -> Figure:
    """A margin read on ``reader`` where ``driver`` crosses ``level`` downward; the smallest over all crossings.

    ``value_of(reading)`` maps a reading of ``reader`` to the margin (increasing or decreasing in it)."""
    found = _crossings(driver.x, driver.y, level, True)
    if not found:
        return Figure(name, unit, note=f"not found in the measured range ({_range_name(driver.x)}): {what}")
    best: Figure | None = None
    for i, xc in found:
        reading = _interp(reader.x, reader.y, xc)
        value = float(value_of(reading))
        ends = [_nearest(_crossings(driver.x, b, level, True), xc) for b in (driver.lo, driver.hi)]
        a = min((e for e in ends if math.isfinite(e)), default=math.nan)
        b = max((e for e in ends if math.isfinite(e)), default=math.nan)
        open_interval = not all(math.isfinite(e) for e in ends)
        if open_interval:
            low = high = math.nan
            a_hz = b_hz = math.nan
        else:
            xs = _span(reader.x, a, b)
            candidates = [float(value_of(np.interp(xs, reader.x, bound)).min()) for bound in (reader.lo, reader.hi)]
            candidates += [float(value_of(np.interp(xs, reader.x, bound)).max()) for bound in (reader.lo, reader.hi)]
            low, high = min(candidates), max(candidates)
            a_hz, b_hz = _hz(a), _hz(b)
        dx = _crossing_x_error(driver.x, driver.y, i, xc)
        j = min(int(np.searchsorted(reader.x, xc, side="right")) - 1, len(reader.x) - 2)
        slope = (reader.y[j + 1] - reader.y[j]) / (reader.x[j + 1] - reader.x[j])
        interp = interpolation_error(reader.x, reader.y, j, xc) + abs(slope) * dx
        figure = Figure(name, unit, value=value, low=low, high=high, interpolation=float(interp), at_hz=_hz(xc),
                        at_low_hz=a_hz, at_high_hz=b_hz,
                        note=f"the smallest of {len(found)} crossovers" if len(found) > 1 else "")
        if best is None or figure.value < best.value:
            best = figure
    assert best is not None
    return best


def summarize(frequency_hz: Sequence[float] | np.ndarray, gain_db: Sequence[float] | np.ndarray,
              gain_low_db: Sequence[float] | np.ndarray, gain_high_db: Sequence[float] | np.ndarray,
              phase_deg: Sequence[float] | np.ndarray, phase_ci_deg: Sequence[float] | np.ndarray,
              kind: str = "system", channel: str = "", converged: Sequence[bool] | np.ndarray | None = None
              ) -> ResponseSummary:
    """The summary of a response given per point: frequency (Hz, > 0), gain (dB) with its 95 % bounds (dB),
    phase (degrees, unwrapped, or folded: it is unwrapped here) with its 95 % half-width (degrees). ``converged``
    (per point, default all): a figure read from a point that did not converge says so in its note.

    Points are sorted by frequency; at least two are needed. ``kind`` (:data:`RESPONSE_KINDS`): "open_loop" adds
    the margins and leaves out the bandwidth and the resonance peak, which belong to the closed loop."""
    if kind not in RESPONSE_KINDS:
        raise ValueError(f"kind must be one of {', '.join(RESPONSE_KINDS)}, got {kind!r}")
    f = np.asarray(frequency_hz, dtype=float)
    columns = [np.asarray(c, dtype=float) for c in (gain_db, gain_low_db, gain_high_db, phase_deg, phase_ci_deg)]
    if any(c.shape != f.shape for c in columns) or f.ndim != 1:
        raise ValueError("every column must be one-dimensional and as long as frequency_hz")
    if f.size < 2:
        raise ValueError(f"a summary needs at least two points, got {f.size}")
    if not (np.all(np.isfinite(f)) and np.all(f > 0.0)):
        raise ValueError("frequencies must be finite and > 0 Hz")
    if np.unique(f).size != f.size:
        raise ValueError("frequencies must be distinct")
    order = np.argsort(f)
    f = f[order]
    g, g_lo, g_hi, ph, ph_ci = (c[order] for c in columns)
    settled = np.ones(f.size, dtype=bool) if converged is None else np.asarray(converged, dtype=bool)[order]
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(ph)) and np.all(np.isfinite(g_hi))):
        raise ValueError("gains, their upper bounds and phases must be finite")
    g_lo = np.where(np.isfinite(g_lo), g_lo, _FLOOR_DB)
    ph_ci = np.where(np.isfinite(ph_ci), ph_ci, 180.0)
    ph = unwrapped_phase(ph)
    x = np.log10(f)
    gain = _Curve(x, g, g_lo, g_hi)
    phase = _Curve(x, ph, ph - ph_ci, ph + ph_ci)
    ref, ref_lo, ref_hi = float(g[0]), float(g_lo[0]), float(g_hi[0])
    figures: list[Figure] = []
    if kind != "open_loop":
        figures += [_bandwidth(gain, ref, ref_lo, ref_hi), _peak(gain, ref, ref_lo, ref_hi)]
    figures += [_phase_crossing(phase, -90.0), _phase_crossing(phase, -180.0)]
    if kind == "open_loop":
        figures.append(_margin(gain, phase, 0.0, "phase margin", "deg", lambda p: 180.0 + np.asarray(p),
                               "the gain does not fall through 0 dB"))
        figures.append(_margin(phase, gain, -180.0, "gain margin", "dB", lambda g_: -np.asarray(g_),
                               "the phase does not fall through -180 deg"))
    figures = [_unconverged_note(figure, f, settled) for figure in figures]
    return ResponseSummary(channel=channel, kind=kind, points=int(f.size), reference_hz=float(f[0]),
                           reference_db=ref, reference_low_db=ref_lo, reference_high_db=ref_hi,
                           figures=tuple(figures))


def unwrapped_phase(phase_deg: np.ndarray) -> np.ndarray:
    """Phases (deg, ascending frequency) unwrapped: the lowest frequency's on the branch (-180, 180], so that a
    response starting at 0 deg is not read as starting at -360, then the 360 deg jumps between neighbours removed."""
    ph = np.asarray(phase_deg, dtype=float)
    start = ph[0] - 360.0 * math.floor((ph[0] + 180.0) / 360.0)
    if start == -180.0:
        start = 180.0
    return np.asarray(np.unwrap(ph - ph[0], period=360.0) + start)


def _unconverged_note(figure: Figure, f: np.ndarray, settled: np.ndarray) -> Figure:
    """``figure`` with a note naming the points it was read between (the two around its frequency, or the one it
    sits on) that did not converge; the reference point too, for the figures relative to it."""
    if not figure.found:
        return figure
    at = figure.at_hz if math.isfinite(figure.at_hz) else figure.value
    i = int(np.searchsorted(f, at))
    used = {j for j in (i - 1, i) if 0 <= j < f.size} if not np.any(np.isclose(f, at)) else \
        {int(np.argmin(np.abs(f - at)))}
    if figure.unit == "dB" or figure.name.startswith("bandwidth"):
        used.add(0)  # relative to the reference gain, at the lowest frequency
    loose = sorted(float(f[j]) for j in used if not settled[j])
    if not loose:
        return figure
    shown = ", ".join(f"{x:.4g}" for x in loose)
    note = f"read from points that did not converge ({shown} Hz)"
    return replace(figure, note=f"{note}; {figure.note}" if figure.note else note)


@dataclass(frozen=True)
class ChannelCurve:
    """Harmonic 1 of one channel as the summary reads it: its points with a finite gain and a defined phase (the
    latest of a frequency measured again), by ascending frequency (Hz); gains and their 95 % bounds in dB, phases
    and their 95 % half-widths in degrees (as measured, not unwrapped); ``unstated``: points that state no interval
    (taken as exact)."""

    channel: str
    frequency_hz: np.ndarray
    gain_db: np.ndarray
    low_db: np.ndarray
    high_db: np.ndarray
    phase_deg: np.ndarray
    phase_ci_deg: np.ndarray
    converged: np.ndarray
    unstated: int


def channel_curves(response: FrequencyResponse) -> list[ChannelCurve]:
    """One curve per channel of harmonic 1 of ``response`` (:class:`ChannelCurve`); a channel with fewer than two
    points that have a finite gain and a defined phase (a point below the resolution has none) is left out."""
    out: list[ChannelCurve] = []
    first = response.select(harmonic=1)
    for channel in first.channels:
        points = [p for p in first.select(channel=channel).points
                  if math.isfinite(p.gain_db) and math.isfinite(p.phase_deg)]
        latest = {p.frequency_hz: p for p in points}  # a frequency measured again: its latest point
        points = sorted(latest.values(), key=lambda p: p.frequency_hz)
        if len(points) < 2:
            continue
        gain_db = np.array([p.gain_db for p in points])
        width = np.array([p.gain_ci * p.amplitude for p in points])
        unstated = int(np.count_nonzero(~np.isfinite(width)))
        magnitude = np.array([p.magnitude for p in points])
        amplitude = np.array([p.amplitude for p in points])
        width = np.where(np.isfinite(width), width, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            low = np.where(magnitude > width, 20.0 * np.log10((magnitude - width) / amplitude), -np.inf)
            high = 20.0 * np.log10((magnitude + width) / amplitude)
        phase_ci = np.array([p.phase_ci_deg for p in points])
        out.append(ChannelCurve(channel, np.array([p.frequency_hz for p in points]), gain_db, low, high,
                                np.array([p.phase_deg for p in points]),
                                np.where(np.isfinite(phase_ci), phase_ci, 0.0),
                                np.array([p.converged for p in points], dtype=bool), unstated))
    return out


def summarize_response(response: FrequencyResponse, kind: str = "system") -> list[ResponseSummary]:
    """One summary per channel of harmonic 1 of ``response`` (the curves of :func:`channel_curves`)."""
    out: list[ResponseSummary] = []
    for c in channel_curves(response):
        summary = summarize(c.frequency_hz, c.gain_db, c.low_db, c.high_db, c.phase_deg, c.phase_ci_deg, kind=kind,
                            channel=c.channel, converged=c.converged)
        if c.unstated:
            summary = replace(summary, note=f"{c.unstated} points state no interval: taken as exact")
        out.append(summary)
    return out
