"""Identification of the friction link from its measured first-harmonic response (docs/METHOD.md section 3).

The link ``m Y'' = U - F_ct sign(V) - K_p Y`` is driven by ``U = A_F sin(2 pi f t)``; ``K_p`` and ``A_F`` are
known. Two routes recover the dry friction ``F_ct`` and the mass ``m`` (``f_n = sqrt(K_p/m) / (2 pi)``):

- :func:`paper_procedure`: the 2017 paper's engineering procedure, steps 1 to 8. ``f_-90`` by linear
  interpolation, the phase read at decade ticks 1, 2, 4 and 6 below and above it, one Fbar per reading from the
  calibration curves (:mod:`bodebench.analysis.calibration`), their mean, then ``f_n = f_-90 / r_90(Fbar)``. It applies
  only where the settled phase crosses -90 degrees, i.e. Fbar > pi/4, and says so otherwise.
- :func:`fit_link`: weighted least squares of the simulated link's settled first harmonic
  (:class:`bodebench.analysis.calibration.FrictionLink`, exact) to every converged point, in log gain and phase, with
  confidence intervals. Works at any Fbar and on any frequency grid; optionally frees ``K_p`` and a viscous
  damping ratio.

:func:`identify` runs both on a :class:`~bodebench.core.response.FrequencyResponse`, :func:`format_report` renders
the report as text and :func:`plot_identification` draws the measured points against both models.

Conventions: a measured point's ``uncertainty_1d`` is the 95 % half-width of (p, q) along one direction, taken
as ``1.96 * sigma`` with ``sigma`` the standard deviation of each of p and q (files without it: ``uncertainty``,
the 95 % disc radius, taken as ``sqrt(-2 ln 0.05) * sigma``); the relative standard deviation of the gain and of
the phase (radians) is then ``sigma / |p + jq|``.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats
from scipy.interpolate import PchipInterpolator
from scipy.optimize import least_squares

from bodebench.analysis.calibration import (
    CalibrationError,
    CalibrationTable,
    FrictionLink,
    SteadyStateError,
    load_calibration,
)
from bodebench.core.response import FrequencyResponse

__all__ = [
    "CONFIDENCE",
    "Excluded",
    "FitResult",
    "IdentificationError",
    "IdentificationReport",
    "MeasuredCurve",
    "NO_CROSSING",
    "ProcedureResult",
    "RELATIVE_FLOOR",
    "TICK_OFFSETS",
    "TickReading",
    "crossing_frequency",
    "decade_tick",
    "fit_link",
    "format_report",
    "identify",
    "link_parameters",
    "measured_curve",
    "paper_procedure",
    "plot_identification",
    "predicted_response",
    "tick_frequencies",
]

#: Confidence level of the fit's intervals.
CONFIDENCE = 0.95
#: Tick offsets read on each side of f_-90 (docs/METHOD.md section 3, step 2).
TICK_OFFSETS: tuple[int, ...] = (1, 2, 4, 6)
#: Smallest relative standard deviation given to a point's gain and phase (radians) in the fit: the scale of
#: what a settled measurement at eps = 0.01 % and K_f = 200 can promise (about 0.009 dB and 0.06 degrees).
RELATIVE_FLOOR = 1e-3
#: What the procedure says where it does not apply.
NO_CROSSING = "no -90 crossing: this procedure applies only for Fbar > pi/4 - use the fit"

_Z95 = 1.959963984540054  # two-sided 95 % normal quantile
_DISC95 = math.sqrt(-2.0 * math.log(0.05))  # radius of the 95 % disc of a circular 2-D normal, in sigmas
_PENALTY = 1e3  # residual of a point where the model has no settled motion (Fbar < pi/4 at f = f_n)
_SCORE_POINTS = 6  # points (besides those around the -90 degree crossing) used to rank start values
_PHASE_NOISE_SIGMAS = 3.0
_COARSE_BRACKET = 1.25  # frequency ratio of the points around f_-90 above which the procedure warns


class IdentificationError(ValueError):
    """The measured response cannot be identified as asked (no usable points, unknown K_p or A_F, ...)."""


# --------------------------------------------------------------------------------------------- measured points


@dataclass(frozen=True)
class Excluded:
    """A measured point left out, and why."""

    frequency_hz: float
    status: str
    reason: str


@dataclass(frozen=True)
class MeasuredCurve:
    """The converged points of one harmonic and channel, ascending in frequency.

    coefficient: p + jq (output units); sigma: standard deviation of each of p and q (output units; NaN where
    the point states no uncertainty); phase_deg: phase unwrapped along frequency (degrees; angle(p + jq) at
    the lowest frequency); amplitude: input amplitude of the points (input units); unsettled_hz: frequencies
    whose measurement did not converge (e.g. capped at the period limit).
    """

    frequency_hz: np.ndarray
    coefficient: np.ndarray
    sigma: np.ndarray
    phase_deg: np.ndarray
    amplitude: float
    harmonic: int
    channel: str
    excluded: tuple[Excluded, ...] = ()
    unsettled_hz: tuple[float, ...] = ()

    def __len__(self) -> int:
        return int(self.frequency_hz.size)

    @property
    def relative_sigma(self) -> np.ndarray:
        """sigma / |p + jq|: relative standard deviation of gain and phase (radians); NaN where unknown."""
        return self.sigma / np.abs(self.coefficient)


def measured_curve(response: FrequencyResponse, harmonic: int = 1, channel: str | None = None) -> MeasuredCurve:
    """The usable points of ``harmonic`` of ``channel`` (default: "position" if present, else the only channel).

    Points that did not converge, have no finite coefficients, a zero coefficient vector or an undefined
    phase are excluded, each with its reason. Raises IdentificationError if the selection is empty or the
    points were measured at different input amplitudes.
    """
    if not response.points:
        raise IdentificationError("the response holds no points")
    channels = response.channels
    if channel is None:
        if "position" in channels:
            channel = "position"
        elif len(channels) == 1:
            channel = channels[0]
        else:
            raise IdentificationError(f"several channels {list(channels)}: choose one (--channel)")
    elif channel not in channels:
        raise IdentificationError(f"channel {channel!r} not in the response (channels: {list(channels)})")
    if harmonic not in response.harmonics:
        raise IdentificationError(f"harmonic {harmonic} not in the response (harmonics: {list(response.harmonics)})")
    points = response.select(harmonic=harmonic, channel=channel).points
    amplitudes = sorted({p.amplitude for p in points})
    if amplitudes[-1] > amplitudes[0] * (1.0 + 1e-9):
        raise IdentificationError(f"the points were measured at different input amplitudes {amplitudes}; "
                                  "identification needs one A_F")
    used, excluded, unsettled = [], [], []
    for p in points:
        reason = None
        if not p.converged:
            reason = f"not converged ({p.status} after {p.periods} periods)"
            unsettled.append(p.frequency_hz)
        elif not (math.isfinite(p.p) and math.isfinite(p.q)) or p.magnitude == 0.0:
            reason = "no finite, non-zero coefficients"
        elif math.isnan(p.phase_deg):
            reason = f"phase undefined ({p.status})"
        if reason is None:
            used.append(p)
        else:
            excluded.append(Excluded(p.frequency_hz, p.status, reason))
    if not used:
        raise IdentificationError(f"no converged points of harmonic {harmonic} of {channel!r} to identify from")
    f = np.array([p.frequency_hz for p in used])
    c = np.array([complex(p.p, p.q) for p in used])
    sigma = np.array([p.uncertainty / _DISC95 if math.isnan(p.uncertainty_1d) else p.uncertainty_1d / _Z95
                      for p in used])
    phase = np.degrees(np.unwrap(np.angle(c)))
    return MeasuredCurve(f, c, sigma, phase, float(points[0].amplitude), harmonic, channel, tuple(excluded),
                         tuple(unsettled))


def link_parameters(response: FrequencyResponse, stiffness: float | None = None,
                    amplitude: float | None = None) -> tuple[float, str, float, str]:
    """K_p and A_F for a response, with where each came from: the options given win over the sidecar's config.

    Returns (stiffness, source, amplitude, source). A_F falls back on the points' input amplitude.
    Raises IdentificationError naming what is missing or invalid.
    """
    config = response.config if isinstance(response.config, dict) else {}
    plant_table, excitation_table = config.get("plant"), config.get("excitation")
    plant = plant_table if isinstance(plant_table, dict) else {}
    excitation = excitation_table if isinstance(excitation_table, dict) else {}

    def positive(name: str, value: object) -> float | None:
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise IdentificationError(f"{name} must be a finite number > 0, got {value!r}")
        return float(value)

    k = positive("--stiffness", stiffness)
    k_source = "option"
    if k is None:
        k = positive("sidecar plant.stiffness", plant.get("stiffness")) if "stiffness" in plant else None
        k_source = "sidecar"
    if k is None:
        raise IdentificationError("the stiffness K_p is unknown (the sidecar has no plant.stiffness): "
                                  "pass --stiffness")
    a = positive("--amplitude", amplitude)
    a_source = "option"
    if a is None and "amplitude" in excitation:
        a = positive("sidecar excitation.amplitude", excitation.get("amplitude"))
        a_source = "sidecar"
    if a is None and response.points:
        a = float(response.points[0].amplitude)
        a_source = "points"
    if a is None:
        raise IdentificationError("the input amplitude A_F is unknown: pass --amplitude")
    return k, k_source, a, a_source


# ------------------------------------------------------------------------------------------------- decade ticks


def decade_tick(index: int) -> float:
    """Tick number ``index`` of the decade scale 1, 2, ..., 9, 10, 20, ... (index 0 is 1 Hz, -1 is 0.9 Hz)."""
    exponent, digit = divmod(int(index), 9)
    return float(f"{digit + 1}e{exponent}")


def _tick_index_below(f: float) -> int:
    """Index of the largest tick strictly below ``f`` (a tick equal to ``f`` to 1e-9 counts as not below)."""
    if not (math.isfinite(f) and f > 0.0):
        raise ValueError(f"frequency must be finite and > 0 Hz, got {f!r}")
    exponent = math.floor(math.log10(f))
    index = 9 * exponent + min(8, max(0, int(f / 10.0 ** exponent) - 1))
    while decade_tick(index) >= f * (1.0 - 1e-9):
        index -= 1
    while decade_tick(index + 1) < f * (1.0 - 1e-9):
        index += 1
    return index


def tick_frequencies(f90: float, offsets: Sequence[int] = TICK_OFFSETS) -> tuple[list[float], list[float]]:
    """Decade ticks ``offsets`` ticks below and above ``f90`` (Hz), counted from the nearest tick on each side.

    The nearest ticks are offset 0: for f90 = 3.6 Hz they are 3 and 4 Hz, and offsets 1, 2, 4, 6 give
    2, 1, 0.8, 0.6 Hz below and 5, 6, 8, 10 Hz above. A tick equal to f90 belongs to neither side.
    """
    below = _tick_index_below(f90)
    above = below + 1
    if abs(decade_tick(above) - f90) <= 1e-9 * f90:
        above += 1
    for k in offsets:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
            raise ValueError(f"tick offsets must be integers >= 0, got {k!r}")
    return [decade_tick(below - k) for k in offsets], [decade_tick(above + k) for k in offsets]


def crossing_frequency(frequency_hz: np.ndarray, phase_deg: np.ndarray) -> list[tuple[float, int]]:
    """Every downward crossing of -90 degrees: (f, i) by linear interpolation between points i and i+1 (Hz).

    A point lying exactly on -90 degrees is a crossing at that point.
    """
    f = np.asarray(frequency_hz, dtype=float)
    d = np.asarray(phase_deg, dtype=float) + 90.0
    out = []
    for i in range(len(f) - 1):
        if d[i] > 0.0 >= d[i + 1]:
            out.append((float(f[i] + d[i] * (f[i + 1] - f[i]) / (d[i] - d[i + 1])), i))
    return out


# --------------------------------------------------------------------------------------- the paper's procedure


@dataclass(frozen=True)
class TickReading:
    """One reading of step 2-3: the measured phase at a tick and the Fbar the calibration gives for it.

    side: "below" or "above" f_-90; offset: ticks from the nearest one; phase_deg: measured phase there
    (interpolated in ln f; None if the tick is outside the measured span); fbar: None with ``note`` saying why.
    """

    side: str
    offset: int
    frequency_hz: float
    phase_deg: float | None
    fbar: float | None
    note: str = ""


@dataclass(frozen=True)
class ProcedureResult:
    """The engineering procedure's intermediates and results (None where it does not apply; ``reason`` says why).

    f90_hz: f_-90 (Hz); bracket: the two measured points around it, (f Hz, phase deg) each; readings: the
    tick readings; fbar_mean / fbar_right_mean: mean of all / of the above-f_-90 readings, with their sample
    standard deviations; fbar: the chosen value per ``fbar_rule``; r90: f_-90 / f_n at that Fbar; df_hz:
    f_n - f_-90; f_n_hz, mass, friction: the identified link (K_p, A_F as given).
    """

    applicable: bool
    reason: str | None = None
    f90_hz: float | None = None
    bracket: tuple[tuple[float, float], tuple[float, float]] | None = None
    readings: tuple[TickReading, ...] = ()
    fbar_mean: float | None = None
    fbar_std: float | None = None
    fbar_right_mean: float | None = None
    fbar_right_std: float | None = None
    fbar: float | None = None
    fbar_rule: str = ""
    r90: float | None = None
    df_hz: float | None = None
    f_n_hz: float | None = None
    mass: float | None = None
    friction: float | None = None
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """JSON types; every quantity present (null where it does not apply)."""
        return {
            "applicable": self.applicable,
            "reason": self.reason,
            "fbar": self.fbar,
            "friction": self.friction,
            "f_n_hz": self.f_n_hz,
            "mass": self.mass,
            "f_minus90_hz": self.f90_hz,
            "bracket": None if self.bracket is None else [
                {"frequency_hz": f, "phase_deg": ph} for f, ph in self.bracket],
            "readings": [{"side": r.side, "offset": r.offset, "frequency_hz": r.frequency_hz,
                          "phase_deg": r.phase_deg, "fbar": r.fbar, "note": r.note} for r in self.readings],
            "fbar_mean": self.fbar_mean,
            "fbar_std": self.fbar_std,
            "fbar_right_mean": self.fbar_right_mean,
            "fbar_right_std": self.fbar_right_std,
            "fbar_rule": self.fbar_rule,
            "r90": self.r90,
            "df_hz": self.df_hz,
            "notes": list(self.notes),
        }


def _interp_phase_log(curve: MeasuredCurve, f: float) -> float | None:
    """Measured phase at ``f`` by linear interpolation in ln f (None outside the measured span)."""
    fr = curve.frequency_hz
    if not fr[0] * (1.0 - 1e-12) <= f <= fr[-1] * (1.0 + 1e-12):
        return None
    return float(np.interp(math.log(f), np.log(fr), curve.phase_deg))


def _largest_steady_drop(table: CalibrationTable, ratio: float) -> float:
    """Largest phase drop (degrees) a settled link with Fbar in the table makes between two frequencies a factor
    ``ratio`` apart with f_-90 between them."""
    lo, hi = table.offset_range
    a = np.geomspace(max(lo, 1.0 / ratio), min(1.0, hi / ratio), 64)
    return float(np.max(table.curves(a) - table.curves(a * ratio)))


def _read_fbar(table: CalibrationTable, offset: float, phase: float) -> tuple[float | None, str]:
    """Fbar whose calibration curve passes through ``phase`` at f = offset * f_-90 (step 3)."""
    lo, hi = table.offset_range
    if not lo <= offset <= hi:
        return None, f"f/f_-90 = {offset:.3g} outside the calibration ({lo:g} to {hi:g})"
    curve = table.curve(offset)
    g = PchipInterpolator(table.fbar, curve - phase)
    roots = [float(r) for r in g.roots(extrapolate=False)]
    roots = sorted({round(r, 12) for r in roots})
    if not roots:
        return None, (f"phase {phase:.2f} deg outside the calibrated curve at f/f_-90 = {offset:.3g} "
                      f"({curve.min():.2f} to {curve.max():.2f} deg for Fbar {table.fbar[0]:g} to "
                      f"{table.fbar[-1]:g})")
    if len(roots) > 1:
        return None, f"ambiguous: Fbar {', '.join(f'{r:.4f}' for r in roots)} all match"
    return roots[0], ""


def paper_procedure(curve: MeasuredCurve, stiffness: float, amplitude: float,
                    table: CalibrationTable | None = None, offsets: Sequence[int] = TICK_OFFSETS) -> ProcedureResult:
    """The 2017 paper's procedure (docs/METHOD.md section 3, steps 1-8) on a measured first-harmonic curve.

    Refuses (``applicable`` False, ``reason`` starting with :data:`NO_CROSSING`) where the measured phase does
    not cross -90 degrees the way a settled link with Fbar > pi/4 does: no crossing, measurements near it that
    did not settle, or a drop across it larger than any settled crossing makes. Also refuses, saying so, when
    no tick phase lies on a calibrated curve. On coarse grids a jump cannot be told from a settled crossing;
    a note says when the points around -90 degrees are more than a factor 1.25 apart. Fbar rule: the mean of
    the readings above f_-90 (the paper: they spread less) when at least two of them exist, else the mean of
    all readings.
    """
    if curve.harmonic != 1:
        return ProcedureResult(False, f"the procedure reads first-harmonic phases, not harmonic {curve.harmonic}")
    table = load_calibration() if table is None else table
    crossings = crossing_frequency(curve.frequency_hz, curve.phase_deg)
    if not crossings:
        ph = curve.phase_deg
        where = "above" if np.all(ph > -90.0) else "below" if np.all(ph <= -90.0) else "around"
        return ProcedureResult(False, f"{NO_CROSSING} (the measured phase stays {where} -90 deg from "
                                      f"{curve.frequency_hz[0]:g} to {curve.frequency_hz[-1]:g} Hz)")
    notes = []
    f90, i = crossings[0]
    if len(crossings) > 1:
        notes.append("the phase crosses -90 deg more than once (at "
                      + ", ".join(f"{f:.4g}" for f, _ in crossings) + " Hz); the first crossing is used")
    fa, fb = float(curve.frequency_hz[i]), float(curve.frequency_hz[i + 1])
    pa, pb = float(curve.phase_deg[i]), float(curve.phase_deg[i + 1])
    bracket = ((fa, pa), (fb, pb))
    unsettled = [f for f in curve.unsettled_hz if fa <= f <= fb]
    if unsettled:
        return ProcedureResult(False, f"{NO_CROSSING} (the response does not settle at "
                                      f"{', '.join(f'{f:g}' for f in unsettled)} Hz between the points around "
                                      "-90 deg, as for Fbar < pi/4 near f_n)", f90_hz=None, bracket=bracket)
    rel = curve.relative_sigma[i:i + 2]
    noise = _PHASE_NOISE_SIGMAS * math.degrees(float(np.sum(np.where(np.isfinite(rel), rel, 0.0))))
    steady = _largest_steady_drop(table, fb / fa)
    if pa - pb > steady + noise + 0.5:
        return ProcedureResult(False, f"{NO_CROSSING} (the phase jumps from {pa:.1f} deg at {fa:g} Hz to "
                                      f"{pb:.1f} deg at {fb:g} Hz; a settled link with Fbar > pi/4 drops at most "
                                      f"{steady:.1f} deg over that interval)", bracket=bracket)
    if fb / fa > _COARSE_BRACKET:
        notes.append(f"the points around -90 deg are a factor {fb / fa:.3g} apart: f_-90 by linear interpolation "
                     "is coarse, and a jump (Fbar < pi/4) cannot be told from a settled crossing at this spacing")
    below, above = tick_frequencies(f90, offsets)
    readings = []
    for side, ticks in (("below", below), ("above", above)):
        for k, ft in zip(offsets, ticks, strict=True):
            phase = _interp_phase_log(curve, ft)
            if phase is None:
                readings.append(TickReading(side, int(k), ft, None, None, "tick outside the measured span"))
                continue
            fbar, note = _read_fbar(table, ft / f90, phase)
            readings.append(TickReading(side, int(k), ft, phase, fbar, note))
    values = [r.fbar for r in readings if r.fbar is not None]
    right = [r.fbar for r in readings if r.fbar is not None and r.side == "above"]
    if not values:
        lo, hi = table.fbar_range
        return ProcedureResult(False, f"no tick phase lies on a calibrated curve (Fbar {lo:g} to {hi:g}): either "
                                      f"Fbar < pi/4 and the -90 deg crossing is a jump, not a settled crossing, or "
                                      f"Fbar > {hi:g} - use the fit", f90_hz=f90, bracket=bracket,
                               readings=tuple(readings), notes=tuple(notes))

    def std(v: list[float]) -> float | None:
        return float(np.std(v, ddof=1)) if len(v) > 1 else None

    mean = float(np.mean(values))
    right_mean = float(np.mean(right)) if right else None
    if right_mean is not None and len(right) >= 2:
        fbar, rule = right_mean, f"mean of the {len(right)} readings above f_-90 (they spread less)"
    else:
        fbar, rule = mean, f"mean of all {len(values)} readings (fewer than two above f_-90)"
    r90 = table.crossing_ratio(fbar)
    f_n = f90 / r90
    return ProcedureResult(
        True, None, f90_hz=f90, bracket=bracket, readings=tuple(readings), fbar_mean=mean, fbar_std=std(values),
        fbar_right_mean=right_mean, fbar_right_std=std(right), fbar=fbar, fbar_rule=rule, r90=r90,
        df_hz=f_n - f90, f_n_hz=f_n, mass=stiffness / (4.0 * math.pi ** 2 * f_n ** 2), friction=fbar * amplitude,
        notes=tuple(notes))


# ------------------------------------------------------------------------------------------------- the fit


@dataclass(frozen=True)
class FitResult:
    """Least-squares identification of the link; ``*_ci`` are half-widths of the CONFIDENCE intervals.

    stiffness_ci is None when K_p was held at its known value, damping_ratio(_ci) None when no viscous term
    was fitted. residual_rms: root mean square of the weighted residuals (about 1 when the stated
    uncertainties are right and the model fits). method: how the intervals were formed.
    """

    applicable: bool
    reason: str | None = None
    fbar: float | None = None
    fbar_ci: float | None = None
    friction: float | None = None
    friction_ci: float | None = None
    f_n_hz: float | None = None
    f_n_ci_hz: float | None = None
    mass: float | None = None
    mass_ci: float | None = None
    stiffness: float | None = None
    stiffness_ci: float | None = None
    damping_ratio: float | None = None
    damping_ratio_ci: float | None = None
    points: int = 0
    residual_rms: float | None = None
    evaluations: int = 0
    converged: bool = False
    message: str = ""
    method: str = ""
    confidence: float = CONFIDENCE
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """JSON types; every quantity present (null where it does not apply)."""
        keys = ("applicable", "reason", "fbar", "fbar_ci", "friction", "friction_ci", "f_n_hz", "f_n_ci_hz",
                "mass", "mass_ci", "stiffness", "stiffness_ci", "damping_ratio", "damping_ratio_ci", "points",
                "residual_rms", "evaluations", "converged", "message", "method", "confidence")
        out = {k: getattr(self, k) for k in keys}
        out["notes"] = list(self.notes)
        return out


class _LinkModel:
    """Settled first harmonic of the dimensionless link at fixed measured frequencies, warm-started per point."""

    def __init__(self, frequency_hz: np.ndarray) -> None:
        self.frequency_hz = frequency_hz
        self._start: dict[int, tuple[float, float]] = {}
        self.failures = 0

    def __call__(self, fbar: float, f_n: float, zeta: float, warm: bool = True) -> np.ndarray:
        """z = P + jQ in units of A_F/K_p at every frequency (NaN where no settled motion exists)."""
        link = FrictionLink(fbar, zeta)
        out = np.empty(self.frequency_hz.size, dtype=complex)
        for i, f in enumerate(self.frequency_hz):
            start = self._start.get(i) if warm else None
            try:
                state = link.steady_state(f / f_n, start)
            except SteadyStateError:
                if start is None:
                    out[i] = complex("nan")
                    self.failures += 1
                    continue
                try:
                    state = link.steady_state(f / f_n)
                except SteadyStateError:
                    out[i] = complex("nan")
                    self.failures += 1
                    continue
            if warm:
                self._start[i] = (state.y0, state.v0)
            out[i] = state.z1
        return out


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _start_values(curve: MeasuredCurve, table: CalibrationTable | None) -> list[tuple[float, float]]:
    """Candidate (Fbar, f_n) to start the fit from, placed by the measured -90 degree crossing or jump."""
    f = curve.frequency_hz
    crossings = [fc for fc, _ in crossing_frequency(f, curve.phase_deg)]
    candidates: list[tuple[float, float]] = []
    for fc in crossings:
        candidates += [(fb, fc) for fb in (0.1, 0.3, 0.5, 0.65, 0.75)]  # Fbar < pi/4: the jump is at f_n
        if table is not None:  # Fbar > pi/4: the crossing is at r_90(Fbar) f_n
            candidates += [(fb, fc / table.crossing_ratio(fb)) for fb in (0.8, 0.87, 0.93, 0.98)]
    if not candidates:
        for f_n in np.geomspace(f[0] / 3.0, f[-1] * 3.0, 14):
            candidates += [(fb, float(f_n)) for fb in (0.1, 0.3, 0.5, 0.7, 0.8, 0.9, 0.97)]
    return candidates


def fit_link(curve: MeasuredCurve, stiffness: float, amplitude: float, *, fit_stiffness: bool = False,
             fit_damping: bool = False, relative_floor: float = RELATIVE_FLOOR,
             table: CalibrationTable | None = None) -> FitResult:
    """Fit the settled link's harmonic to the measured points (weighted least squares in log gain and phase).

    Parameters: Fbar in [0, 0.9999], ln f_n, and optionally ln K_p and the damping ratio zeta in [0, 2].
    Each point's residuals are (ln|model| - ln|measured|) / s and wrap(arg model - arg measured) / s with
    s = max(sigma / |p + jq|, relative_floor). scipy.optimize.least_squares (trust region reflective) from the
    best of a set of start values placed by the measured -90 degree crossing. Intervals: covariance
    s^2 (J^T J)^-1 from the Jacobian J of the weighted residuals at the solution, scaled by the residual
    variance s^2 = sum(r^2) / (n - p), times the Student t quantile with n - p degrees of freedom; derived
    quantities (f_n, m, F_ct) by first-order propagation. ``table`` (default: the shipped calibration) only
    places start values.
    """
    if curve.harmonic % 2 == 0:
        return FitResult(False, f"harmonic {curve.harmonic} of the link is zero in steady state (half-wave "
                                "symmetry): fit the first harmonic")
    if curve.harmonic != 1:
        return FitResult(False, "the fit models the first harmonic only")
    if not (math.isfinite(relative_floor) and relative_floor > 0.0):
        raise ValueError(f"relative_floor must be finite and > 0, got {relative_floor!r}")
    n_par = 2 + int(fit_stiffness) + int(fit_damping)
    n = len(curve)
    if 2 * n <= n_par:
        return FitResult(False, f"{n} points give {2 * n} residuals, too few for {n_par} parameters", points=n)
    if table is None:
        try:
            table = load_calibration()
        except CalibrationError:
            table = None
    rel = curve.relative_sigma
    s = np.where(np.isfinite(rel), np.maximum(rel, relative_floor), relative_floor)
    ln_c = np.log(np.abs(curve.coefficient))
    arg_c = np.angle(curve.coefficient)
    ln_scale = math.log(amplitude / stiffness)  # measured Y_1 = (A_F / K_p) z

    def unpack(x: np.ndarray) -> tuple[float, float, float, float]:
        k = 2
        ln_k_ratio = 0.0
        if fit_stiffness:
            ln_k_ratio = float(x[k])
            k += 1
        zeta = float(x[k]) if fit_damping else 0.0
        return float(x[0]), math.exp(float(x[1])), ln_k_ratio, zeta

    def residuals_of(z: np.ndarray, ln_k_ratio: float, idx: np.ndarray) -> np.ndarray:
        bad = ~np.isfinite(z) | (z == 0.0)
        zz = np.where(bad, 1.0, z)
        rg = (np.log(np.abs(zz)) + ln_scale - ln_k_ratio - ln_c[idx]) / s[idx]
        rp = _wrap(np.angle(zz) - arg_c[idx]) / s[idx]
        rg[bad] = _PENALTY
        rp[bad] = _PENALTY
        return np.concatenate([rg, rp])

    # start values: rank candidates on a spread subset of points, each solved from scratch
    pick = np.unique(np.round(np.linspace(0, n - 1, min(n, _SCORE_POINTS))).astype(int))
    for _, i in crossing_frequency(curve.frequency_hz, curve.phase_deg)[:1]:
        pick = np.unique(np.concatenate([pick, [i, i + 1]]))
    scout = _LinkModel(curve.frequency_hz[pick])
    best = None
    for fbar0, fn0 in _start_values(curve, table):
        cost = float(np.sum(residuals_of(scout(fbar0, fn0, 0.0, warm=False), 0.0, pick) ** 2))
        if best is None or cost < best[0]:
            best = (cost, fbar0, fn0)
    assert best is not None
    names = ["Fbar", "ln f_n"]  # of the parameters, in order
    x0 = [best[1], math.log(best[2])]
    lower, upper = [0.0, -np.inf], [0.9999, np.inf]
    if fit_stiffness:
        names.append("ln K_p")
        x0.append(0.0)
        lower.append(-np.inf)
        upper.append(np.inf)
    if fit_damping:
        names.append("zeta")
        x0.append(0.02)
        lower.append(0.0)
        upper.append(2.0)

    model = _LinkModel(curve.frequency_hz)
    every = np.arange(n)

    def fun(x: np.ndarray) -> np.ndarray:
        fbar, f_n, ln_k_ratio, zeta = unpack(x)
        return residuals_of(model(fbar, f_n, zeta), ln_k_ratio, every)

    sol = least_squares(fun, np.array(x0), bounds=(lower, upper), method="trf", x_scale="jac", diff_step=1e-6,
                        xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=200)
    fbar, f_n, ln_k_ratio, zeta = unpack(sol.x)
    dof = sol.fun.size - n_par
    ssr = float(np.sum(sol.fun ** 2))
    variance = ssr / dof
    jac = sol.jac
    cov = variance * np.linalg.pinv(jac.T @ jac)
    t = float(stats.t.ppf(0.5 + CONFIDENCE / 2.0, dof))
    half = t * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    k_fit = stiffness * math.exp(ln_k_ratio)
    mass = k_fit / (4.0 * math.pi ** 2 * f_n ** 2)
    # ln m = ln K - 2 ln f_n + const
    grad = np.zeros(n_par)
    grad[1] = -2.0
    if fit_stiffness:
        grad[2] = 1.0
    mass_ci = mass * t * math.sqrt(max(0.0, float(grad @ cov @ grad)))
    notes = []
    if model.failures:
        notes.append(f"the model had no settled motion at {model.failures} point evaluations (Fbar < pi/4 at "
                     "f = f_n); they were penalised")
    at_bound = [name for name, v, lo, hi in zip(names, sol.x, lower, upper, strict=True) if v <= lo or v >= hi]
    if at_bound:
        notes.append(f"{', '.join(at_bound)} at a bound: its interval is not reliable")
    method = (f"least squares (trust region reflective) in log gain and phase weighted by each point's "
              f"uncertainty (relative floor {relative_floor:g}); {100 * CONFIDENCE:g} % intervals from the "
              f"Jacobian at the solution, covariance scaled by the residual variance ({variance:.3g}, "
              f"{dof} degrees of freedom), Student t")
    return FitResult(
        True, None, fbar=fbar, fbar_ci=float(half[0]), friction=fbar * amplitude,
        friction_ci=float(half[0]) * amplitude, f_n_hz=f_n, f_n_ci_hz=f_n * float(half[1]), mass=mass,
        mass_ci=mass_ci, stiffness=k_fit, stiffness_ci=k_fit * float(half[2]) if fit_stiffness else None,
        damping_ratio=zeta if fit_damping else None, damping_ratio_ci=float(half[-1]) if fit_damping else None,
        points=n, residual_rms=math.sqrt(ssr / sol.fun.size), evaluations=int(sol.nfev),
        converged=bool(sol.status > 0), message=str(sol.message), method=method, notes=tuple(notes))


# ---------------------------------------------------------------------------------------------- the report


@dataclass(frozen=True)
class IdentificationReport:
    """Both identifications of one measured response, with what they were given."""

    case: str
    harmonic: int
    channel: str
    stiffness: float
    stiffness_source: str
    amplitude: float
    amplitude_source: str
    points_used: int
    excluded: tuple[Excluded, ...]
    procedure: ProcedureResult
    fit: FitResult
    reference: dict[str, float] | None = None
    plots: tuple[str, ...] = field(default=())

    def to_json(self) -> dict[str, Any]:
        """The report as JSON types (non-finite numbers become null)."""
        report: dict[str, object] = {
            "case": self.case,
            "harmonic": self.harmonic,
            "channel": self.channel,
            "stiffness": self.stiffness,
            "stiffness_source": self.stiffness_source,
            "amplitude": self.amplitude,
            "amplitude_source": self.amplitude_source,
            "points_used": self.points_used,
            "excluded": [{"frequency_hz": e.frequency_hz, "status": e.status, "reason": e.reason}
                         for e in self.excluded],
            "methods": {"procedure": self.procedure.to_json(), "fit": self.fit.to_json()},
            "reference": self.reference,
            "plots": list(self.plots),
        }
        return {key: _finite(value) for key, value in report.items()}


def _finite(value: object) -> object:
    """``value`` with every non-finite float replaced by None (strict JSON)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _reference(response: FrequencyResponse, amplitude: float) -> dict[str, float] | None:
    """The simulated link's own parameters, when the sidecar's config describes one."""
    plant = response.config.get("plant") if isinstance(response.config, dict) else None
    if not isinstance(plant, dict) or plant.get("model") != "coulomb":
        return None
    try:
        mass, k, friction = float(plant["mass"]), float(plant["stiffness"]), float(plant["friction"])
    except (KeyError, TypeError, ValueError):
        return None
    return {"fbar": friction / amplitude, "friction": friction, "f_n_hz": math.sqrt(k / mass) / (2.0 * math.pi),
            "mass": mass, "stiffness": k, "damping_ratio": float(plant.get("damping_ratio", 0.0))}


def identify(response: FrequencyResponse, stiffness: float | None = None, amplitude: float | None = None, *,
             harmonic: int = 1, channel: str | None = None, fit_stiffness: bool = False,
             fit_damping: bool = False, table: CalibrationTable | None = None) -> IdentificationReport:
    """Run the paper's procedure and the fit on a measured response (K_p, A_F: options win over the sidecar)."""
    k, k_source, a, a_source = link_parameters(response, stiffness, amplitude)
    curve = measured_curve(response, harmonic, channel)
    table = load_calibration() if table is None else table
    procedure = paper_procedure(curve, k, a, table)
    fit = fit_link(curve, k, a, fit_stiffness=fit_stiffness, fit_damping=fit_damping, table=table)
    return IdentificationReport(response.case, harmonic, curve.channel, k, k_source, a, a_source, len(curve),
                                curve.excluded, procedure, fit, _reference(response, a))


def _g(value: float | None, digits: int = 6) -> str:
    return "-" if value is None else f"{value:.{digits}g}"


def _pm(value: float | None, ci: float | None, digits: int = 6) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}g}" if ci is None else f"{value:.{digits}g} +- {ci:.2g}"


def format_report(report: IdentificationReport) -> str:
    """The report as plain text: a side-by-side table, then the procedure's intermediates and the notes."""
    p, fit = report.procedure, report.fit
    head = (f"identify {report.case or '(no case)'}: harmonic {report.harmonic} of {report.channel}, "
            f"K_p = {report.stiffness:g} ({report.stiffness_source}), A_F = {report.amplitude:g} "
            f"({report.amplitude_source}); {report.points_used} points used")
    lines = [head]
    if report.excluded:
        lines.append(f"excluded ({len(report.excluded)}): "
                     + "; ".join(f"{e.frequency_hz:g} Hz {e.reason}" for e in report.excluded))
    rows: list[tuple[str, ...]] = [
        ("Fbar = F_ct/A_F", _g(p.fbar), _pm(fit.fbar, fit.fbar_ci)),
        ("F_ct", _g(p.friction), _pm(fit.friction, fit.friction_ci)),
        ("f_n, Hz", _g(p.f_n_hz), _pm(fit.f_n_hz, fit.f_n_ci_hz)),
        ("m", _g(p.mass), _pm(fit.mass, fit.mass_ci)),
        ("K_p", f"{report.stiffness:g}", _pm(fit.stiffness, fit.stiffness_ci)),
    ]
    if fit.damping_ratio is not None:
        rows.append(("damping ratio", "0", _pm(fit.damping_ratio, fit.damping_ratio_ci)))
    ref = report.reference
    header: tuple[str, ...] = ("quantity", "paper procedure", f"fit ({100 * fit.confidence:g} % CI)")
    if ref is not None:
        header += ("configured",)
        values = {"Fbar = F_ct/A_F": ref["fbar"], "F_ct": ref["friction"], "f_n, Hz": ref["f_n_hz"],
                  "m": ref["mass"], "K_p": ref["stiffness"], "damping ratio": ref["damping_ratio"]}
        rows = [row + (_g(values[row[0]]),) for row in rows]
    widths = [max(len(r[c]) for r in [header, *rows]) for c in range(len(header))]
    lines.append("")
    for cells in [header, *rows]:
        lines.append("  ".join(cell.ljust(w) for cell, w in zip(cells, widths, strict=True)).rstrip())
    lines.append("")
    if not p.applicable or p.bracket is None:  # an applicable procedure always has its bracket
        lines.append(f"procedure: {p.reason}")
    else:
        (fa, pa), (fb, pb) = p.bracket
        lines.append(f"procedure: f_-90 = {p.f90_hz:.5g} Hz (between {fa:g} Hz at {pa:.2f} deg and {fb:g} Hz at "
                     f"{pb:.2f} deg)")
        for r in p.readings:
            phase = "-" if r.phase_deg is None else f"{r.phase_deg:8.2f} deg"
            fb_text = f"Fbar {r.fbar:.4f}" if r.fbar is not None else r.note
            ticks = "tick " if r.offset == 1 else "ticks"
            lines.append(f"  {r.offset} {ticks} {r.side:5s} {r.frequency_hz:8.4g} Hz  {phase}  {fb_text}")
        lines.append(f"  Fbar: mean {p.fbar_mean:.4f} (sd {_g(p.fbar_std, 2)}), above f_-90 "
                     f"{_g(p.fbar_right_mean)} (sd {_g(p.fbar_right_std, 2)}); chosen: {p.fbar_rule}")
        lines.append(f"  r_90 = f_-90/f_n = {p.r90:.5g}, df = f_n - f_-90 = {p.df_hz:.4g} Hz")
    for note in p.notes:
        lines.append(f"  note: {note}")
    if fit.applicable:
        lines.append(f"fit: {fit.points} points, weighted residual rms {fit.residual_rms:.3g}, "
                     f"{fit.evaluations} evaluations; {fit.method}")
        for note in fit.notes:
            lines.append(f"  note: {note}")
    else:
        lines.append(f"fit: {fit.reason}")
    if report.plots:
        lines.append("plots: " + ", ".join(report.plots))
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------- the plot


def predicted_response(fbar: float, f_n_hz: float, frequency_hz: Sequence[float] | np.ndarray, stiffness: float,
                       amplitude: float, input_amplitude: float | None = None,
                       damping_ratio: float = 0.0) -> np.ndarray:
    """What the instrument measures on the settled link: (p + jq) / A_i at each frequency (Hz), NaN where the
    link has no settled motion (Fbar < pi/4 at f = f_n).

    stiffness: K_p; amplitude: the force amplitude A_F; input_amplitude: the points' input amplitude A_i in the
    instrument's units (default A_F).
    """
    a_i = amplitude if input_amplitude is None else input_amplitude
    link = FrictionLink(fbar, damping_ratio)
    f = np.asarray(frequency_hz, dtype=float).reshape(-1)
    z = np.full(f.size, complex("nan"))
    for i, fi in enumerate(f):
        with contextlib.suppress(SteadyStateError):
            z[i] = link.steady_state(fi / f_n_hz).z1
    return z * amplitude / (stiffness * a_i)


def _gain_phase(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gain in dB and phase folded into (-360, 0] degrees."""
    phase = np.degrees(np.angle(g))
    with np.errstate(divide="ignore", invalid="ignore"):
        return 20.0 * np.log10(np.abs(g)), np.where(phase > 0.0, phase - 360.0, phase)


def plot_identification(response: FrequencyResponse, report: IdentificationReport, stem: str | Path,
                        points: int = 120) -> list[Path]:
    """Measured points (with their intervals; unsettled ones marked) against both identified models.

    Writes ``stem``.png and ``stem``.svg (matplotlib Agg); returns the paths.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    curve = measured_curve(response, report.harmonic, report.channel)
    pts = response.select(harmonic=report.harmonic, channel=report.channel).points
    fig = Figure(figsize=(8.0, 6.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax_g, ax_p = fig.subplots(2, 1, sharex=True)
    f = curve.frequency_hz
    gain_db = 20.0 * np.log10(np.abs(curve.coefficient) / curve.amplitude)
    phase = np.degrees(np.angle(curve.coefficient))
    phase = np.where(phase > 0.0, phase - 360.0, phase)
    rel = np.where(np.isfinite(curve.relative_sigma), curve.relative_sigma, 0.0)
    ax_g.errorbar(f, gain_db, yerr=20.0 / math.log(10.0) * _Z95 * rel, fmt="o", ms=4, color="k",
                  label="measured")
    ax_p.errorbar(f, phase, yerr=np.degrees(_Z95 * rel), fmt="o", ms=4, color="k", label="measured")
    unsettled = [p for p in pts if not p.converged]
    if unsettled:
        fu = [p.frequency_hz for p in unsettled]
        ax_g.plot(fu, [p.gain_db for p in unsettled], "x", color="tab:red", label="not settled (excluded)")
        ax_p.plot(fu, [p.phase_deg for p in unsettled], "x", color="tab:red", label="not settled (excluded)")
    lo = min(f[0], *(p.frequency_hz for p in pts))
    hi = max(f[-1], *(p.frequency_hz for p in pts))
    grid = np.geomspace(lo, hi, points)
    fit, proc = report.fit, report.procedure
    if fit.applicable and fit.fbar is not None and fit.f_n_hz is not None:
        k_fit = fit.stiffness if fit.stiffness is not None else report.stiffness
        g, ph = _gain_phase(predicted_response(fit.fbar, fit.f_n_hz, grid, k_fit, report.amplitude,
                                               curve.amplitude, fit.damping_ratio or 0.0))
        label = f"fit: Fbar {fit.fbar:.4g}, f_n {fit.f_n_hz:.4g} Hz"
        ax_g.plot(grid, g, "-", color="tab:blue", label=label)
        ax_p.plot(grid, ph, "-", color="tab:blue", label=label)
    if proc.applicable and proc.fbar is not None and proc.f_n_hz is not None:
        g, ph = _gain_phase(predicted_response(proc.fbar, proc.f_n_hz, grid, report.stiffness, report.amplitude,
                                               curve.amplitude))
        label = f"paper procedure: Fbar {proc.fbar:.4g}, f_n {proc.f_n_hz:.4g} Hz"
        ax_g.plot(grid, g, "--", color="tab:orange", label=label)
        ax_p.plot(grid, ph, "--", color="tab:orange", label=label)
        ax_p.axvline(proc.f90_hz, color="0.6", lw=0.8)
        read = [r for r in proc.readings if r.phase_deg is not None]
        ax_p.plot([r.frequency_hz for r in read], [r.phase_deg for r in read], "s", mfc="none",
                  color="tab:orange", ms=7, label="tick readings")
    ax_p.axhline(-90.0, color="0.6", lw=0.8)
    ax_g.set_xscale("log")
    ax_g.set_ylabel("gain, dB")
    ax_p.set_ylabel("phase, deg")
    ax_p.set_xlabel("frequency, Hz")
    for ax in (ax_g, ax_p):
        ax.grid(True, which="both", alpha=0.3)
    ax_p.legend(fontsize=7, loc="lower left")
    fig.suptitle(f"friction link identification {report.case}".strip())
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = [stem.with_suffix(".png"), stem.with_suffix(".svg")]
    for path in paths:
        fig.savefig(path)
    return paths
