"""Measured frequency response: points of a sweep, derived gain and phase.

A point holds the averaged Fourier coefficients ``(P, Q)`` of harmonic ``k`` of one output channel,
``y ~ P sin(2 pi k f t) + Q cos(2 pi k f t)``, for an input ``A_i sin(2 pi f t)``. Gain and phase are
derived from them; nothing derived is stored independently of ``p``, ``q`` and ``amplitude``.

Pure data: the files are :mod:`bodebench.io.results`, the plots :mod:`bodebench.apps.plots`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bodebench.status import PointStatus

__all__ = ["FrequencyResponse", "PHASE_UNDEFINED_STATUSES", "ResponsePoint"]

#: Statuses whose phase is not a number (the coefficient vector is below the resolution).
PHASE_UNDEFINED_STATUSES: tuple[str, ...] = (PointStatus.BELOW_RESOLUTION,)

_FORBIDDEN_TOKEN_CHARS = frozenset(',"\r\n')


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _check_token(name: str, value: object) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{name} must be a string, got {type(value).__name__}")
    if not value or value != value.strip():
        raise ValueError(f"{name} must be a non-empty token without surrounding whitespace, got {value!r}")
    bad = sorted(_FORBIDDEN_TOKEN_CHARS.intersection(value))
    if bad:
        raise ValueError(f"{name} {value!r} contains forbidden characters {bad!r} (no commas, quotes or newlines)")
    return value


def _fold_phase_deg(p: float, q: float) -> float:
    """Phase of ``p + i q`` in degrees folded into (-360, 0]."""
    phase = math.degrees(math.atan2(q, p))
    if phase > 0.0:
        phase -= 360.0
        if phase <= -360.0:  # a positive angle too small to survive the subtraction
            phase = math.nextafter(-360.0, 0.0)
    return phase


@dataclass(frozen=True)
class ResponsePoint:
    """One measured point: harmonic ``harmonic`` of channel ``channel`` at excitation frequency ``frequency_hz``.

    ``p``/``q`` are the averaged sine/cosine coefficients (output units), ``amplitude`` the input amplitude
    (input units, > 0), ``periods`` the periods integrated including skipped ones, ``uncertainty`` the radius
    of the 95 % confidence disc of the vector ``(p, q)`` (output units; NaN when unknown), ``uncertainty_1d``
    the 95 % half-width of its projection on one direction, from which the gain and phase intervals derive
    (output units; NaN: not stated, then ``uncertainty`` stands in), ``within_eps`` whether the stated
    uncertainty is within the requested tolerance, ``periods_needed`` for a noise-limited point the periods
    the requested tolerance would take (0: not estimated), ``thd`` on a harmonic-1 point the total harmonic
    distortion of the channel's output from the harmonics measured (dimensionless; NaN: none measured, or not a
    harmonic-1 point), ``coherence`` the series' coherence with the excitation over its later analysed periods
    (dimensionless, 0 to 1; NaN: not stated), both defined in :mod:`bodebench.core.quality` and left out of
    comparisons between points (NaN, their usual value where not stated, equals nothing), ``periods_discarded``
    the periods not integrated because a gap in the samples touched them (not among ``periods``), ``drift_per_s``
    the channel's linear drift over the analysed periods, taken off every period's coefficients (output units per
    second; NaN: not estimated, as offline; left out of comparisons), ``tolerance_percent`` the tolerance the point
    was measured to, percent (``within_eps`` is against it; NaN: not recorded, as in files of earlier formats).
    ``p`` and ``q`` may be NaN (e.g. a failed point) but not infinite.
    """

    frequency_hz: float
    harmonic: int
    channel: str
    amplitude: float
    p: float
    q: float
    periods: int
    converged: bool
    status: str
    uncertainty: float = math.nan
    uncertainty_1d: float = math.nan
    within_eps: bool = False
    periods_needed: int = 0
    thd: float = field(default=math.nan, compare=False)
    coherence: float = field(default=math.nan, compare=False)
    periods_discarded: int = 0
    drift_per_s: float = field(default=math.nan, compare=False)
    tolerance_percent: float = field(default=math.nan, compare=False)

    def __post_init__(self) -> None:
        def set_(name: str, value: object) -> None:
            object.__setattr__(self, name, value)

        for name in ("frequency_hz", "amplitude", "p", "q", "uncertainty", "uncertainty_1d", "thd", "coherence",
                     "drift_per_s", "tolerance_percent"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ValueError(f"{name} must be a real number, got {value!r}")
            set_(name, float(value))
        if not (math.isfinite(self.frequency_hz) and self.frequency_hz > 0.0):
            raise ValueError(f"frequency_hz must be finite and > 0 Hz, got {self.frequency_hz!r}")
        if not (math.isfinite(self.amplitude) and self.amplitude > 0.0):
            raise ValueError(f"amplitude must be finite and > 0, got {self.amplitude!r}")
        for name in ("p", "q"):
            if math.isinf(getattr(self, name)):
                raise ValueError(f"{name} must be finite or NaN, got {getattr(self, name)!r}")
        for name in ("uncertainty", "uncertainty_1d", "thd", "tolerance_percent"):
            if not (math.isnan(getattr(self, name)) or getattr(self, name) >= 0.0):
                raise ValueError(f"{name} must be >= 0 or NaN, got {getattr(self, name)!r}")
        if not (math.isnan(self.coherence) or 0.0 <= self.coherence <= 1.0):
            raise ValueError(f"coherence must be within [0, 1] or NaN, got {self.coherence!r}")
        for name in ("within_eps", "converged"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
            set_(name, bool(getattr(self, name)))
        if not _is_int(self.periods_needed) or self.periods_needed < 0:
            raise ValueError(f"periods_needed must be an integer >= 0, got {self.periods_needed!r}")
        set_("periods_needed", int(self.periods_needed))
        if not _is_int(self.periods_discarded) or self.periods_discarded < 0:
            raise ValueError(f"periods_discarded must be an integer >= 0, got {self.periods_discarded!r}")
        set_("periods_discarded", int(self.periods_discarded))
        if not _is_int(self.harmonic) or self.harmonic < 1:
            raise ValueError(f"harmonic must be an integer >= 1, got {self.harmonic!r}")
        set_("harmonic", int(self.harmonic))
        if not _is_int(self.periods) or self.periods < 0:
            raise ValueError(f"periods must be an integer >= 0, got {self.periods!r}")
        set_("periods", int(self.periods))
        _check_token("channel", self.channel)
        _check_token("status", self.status)

    @property
    def magnitude(self) -> float:
        """|(p, q)|, output units."""
        return math.hypot(self.p, self.q)

    @property
    def gain(self) -> float:
        """|(p, q)| / amplitude (output units per input unit)."""
        return self.magnitude / self.amplitude

    @property
    def gain_db(self) -> float:
        """20 log10(gain), dB (-inf for a zero coefficient vector)."""
        g = self.gain
        if g == 0.0:
            return -math.inf
        return 20.0 * math.log10(g)

    @property
    def phase_deg(self) -> float:
        """Phase lag in degrees folded into (-360, 0]; NaN when the status makes the phase undefined, or when
        a point that did not converge has a confidence disc that contains zero."""
        if self.status in PHASE_UNDEFINED_STATUSES or (not self.converged and self.uncertainty >= self.magnitude):
            return math.nan
        return _fold_phase_deg(self.p, self.q)

    @property
    def _line_uncertainty(self) -> float:
        """The 95 % half-width along one direction: ``uncertainty_1d``, or the disc radius where it is not stated."""
        return self.uncertainty if math.isnan(self.uncertainty_1d) else self.uncertainty_1d

    @property
    def gain_ci(self) -> float:
        """Half-width of the 95 % gain confidence interval (output units per input unit)."""
        return self._line_uncertainty / self.amplitude

    @property
    def gain_db_ci(self) -> float:
        """Half-width of the 95 % gain confidence interval in dB, 20 log10((|c| + u) / |c|); inf if u >= |c|."""
        u, c = self._line_uncertainty, self.magnitude
        if math.isnan(u) or math.isnan(c):
            return math.nan
        if u >= c:
            return math.inf
        return 20.0 * math.log10((c + u) / c)

    @property
    def phase_ci_deg(self) -> float:
        """Half-width of the 95 % phase confidence interval in degrees, asin(u / |c|); 180 if u >= |c|."""
        u, c = self._line_uncertainty, self.magnitude
        if math.isnan(u) or math.isnan(c):
            return math.nan
        if u >= c:
            return 180.0
        return math.degrees(math.asin(min(1.0, u / c)))


def _normalise_config(value: Any, where: str = "config") -> Any:
    """Deep copy of ``value`` made of JSON types (tuples become lists); raises ValueError naming the bad key."""
    if value is None or isinstance(value, (str, bool)):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):
        out: dict[str, Any] = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise ValueError(f"{where}: key {key!r} is not a string")
            out[key] = _normalise_config(item, f"{where}[{key!r}]")
        return out
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_normalise_config(item, f"{where}[{i}]") for i, item in enumerate(value)]
    raise ValueError(f"{where}: value {value!r} of type {type(value).__name__} is not JSON serialisable")



class FrequencyResponse:
    """Points of a sweep (any harmonics/channels), with the configuration that produced them.

    ``config`` is kept as a JSON-type deep copy (tuples become lists) so that it survives save/load unchanged.
    Columnar properties return arrays over the points in stored order.
    """

    points: list[ResponsePoint]
    config: dict[str, Any]
    case: str

    def __init__(
        self,
        points: Iterable[ResponsePoint] = (),
        config: Mapping[str, Any] | None = None,
        case: str = "",
    ) -> None:
        if not isinstance(case, str):
            raise ValueError(f"case must be a string, got {case!r}")
        if config is not None and not isinstance(config, Mapping):
            raise ValueError(f"config must be a mapping, got {type(config).__name__}")
        self.points = []
        self.config = _normalise_config(config if config is not None else {})
        self.case = case
        for point in points:
            self.add(point)

    def add(self, point: ResponsePoint) -> None:
        """Append one point."""
        if not isinstance(point, ResponsePoint):
            raise ValueError(f"expected a ResponsePoint, got {type(point).__name__}")
        self.points.append(point)

    def __len__(self) -> int:
        return len(self.points)

    def __iter__(self) -> Iterator[ResponsePoint]:
        return iter(self.points)

    def __repr__(self) -> str:
        return (
            f"FrequencyResponse(case={self.case!r}, points={len(self.points)}, "
            f"harmonics={self.harmonics}, channels={self.channels})"
        )

    def select(self, harmonic: int | None = None, channel: str | None = None) -> FrequencyResponse:
        """Points of the given harmonic and/or channel (None: any), sorted by frequency (stable)."""
        chosen = [
            pt
            for pt in self.points
            if (harmonic is None or pt.harmonic == harmonic) and (channel is None or pt.channel == channel)
        ]
        chosen.sort(key=lambda pt: pt.frequency_hz)
        out = type(self)(case=self.case)
        out.config = _normalise_config(self.config)
        out.points = chosen
        return out

    def _column(self, name: str, dtype: type = float) -> np.ndarray:
        return np.array([getattr(pt, name) for pt in self.points], dtype=dtype)

    @property
    def frequency_hz(self) -> np.ndarray:
        """Excitation frequencies, Hz."""
        return self._column("frequency_hz")

    @property
    def gain(self) -> np.ndarray:
        """Gains, output units per input unit."""
        return self._column("gain")

    @property
    def gain_db(self) -> np.ndarray:
        """Gains, dB."""
        return self._column("gain_db")

    @property
    def phase_deg(self) -> np.ndarray:
        """Phases folded into (-360, 0], degrees (NaN where undefined)."""
        return self._column("phase_deg")

    @property
    def gain_db_ci(self) -> np.ndarray:
        """Gain confidence half-widths, dB."""
        return self._column("gain_db_ci")

    @property
    def phase_ci_deg(self) -> np.ndarray:
        """Phase confidence half-widths, degrees."""
        return self._column("phase_ci_deg")

    @property
    def periods(self) -> np.ndarray:
        """Periods integrated per point (integers)."""
        return self._column("periods", dtype=np.int64)

    @property
    def converged(self) -> np.ndarray:
        """Convergence flags (bool)."""
        return self._column("converged", dtype=bool)

    @property
    def harmonics(self) -> tuple[int, ...]:
        """Distinct harmonics, ascending."""
        return tuple(sorted({pt.harmonic for pt in self.points}))

    @property
    def channels(self) -> tuple[str, ...]:
        """Distinct channel names in order of first appearance."""
        return tuple(dict.fromkeys(pt.channel for pt in self.points))

    def phase_unwrapped_deg(self) -> np.ndarray:
        """Phase in degrees with 360-degree jumps between frequency-successive points removed.

        Needs a single harmonic and channel. Points are taken in order of frequency (the result is aligned
        with ``self.points``); NaN phases stay NaN and are stepped over. The lowest-frequency defined phase
        keeps its folded value in (-360, 0].
        """
        if len(self.harmonics) > 1 or len(self.channels) > 1:
            raise ValueError(
                "phase_unwrapped_deg needs a single harmonic and channel, got harmonics "
                f"{self.harmonics} and channels {self.channels}; use select() first"
            )
        phase = self.phase_deg
        order = np.argsort(self.frequency_hz, kind="stable")
        ordered = phase[order]
        defined = ~np.isnan(ordered)
        ordered[defined] = np.unwrap(ordered[defined], period=360.0)
        result = np.empty_like(phase)
        result[order] = ordered
        return result

    def complex_response(self) -> np.ndarray:
        """G = (p + i q) / amplitude per point, so that angle(G) equals the phase (modulo 360 degrees)."""
        return np.array([complex(pt.p, pt.q) / pt.amplitude for pt in self.points], dtype=complex)
