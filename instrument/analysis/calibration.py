"""Steady response of the friction link in dimensionless form, and the calibration table built from it.

The link of docs/METHOD.md section 2, ``m Y'' = U - F_ct sign(V) - K_p Y (- c V)``, driven by
``U = A_F sin(2 pi f t)``, has a settled first harmonic that depends only on ``Fbar = F_ct / A_F``, the
frequency ratio ``r = f / f_n`` and the viscous damping ratio ``zeta``; in units of the static deflection
``A_F / K_p`` it is a complex number ``z = P + jQ`` (``Y_1 = |z| A_F / K_p sin(2 pi f t + arg z)``).

:class:`FrictionLink` computes ``z`` with the project's exact simulator
(:class:`bodebench.sim.plants.CoulombOscillator`, ``m = 1/(2 pi)^2``, ``K_p = 1``, ``A_F = 1``, hence
``f_n = 1`` Hz and ``f = r`` Hz). It does not wait for the start-up transient to die out (near resonance that takes
thousands of periods) but solves for the periodic
motion directly: the settled motion is half-wave symmetric, ``x(t + T/2) = -x(t)`` for the state
``x = (Y, V)``, so its state at phase zero is a root of ``Phi(x) + x`` where ``Phi`` is the exact half-period
map of the simulator. Newton's method with a finite-difference Jacobian and a backtracking line search finds
it, after a few plain iterations of the map (which settle any sticking regime at once). The first harmonic is
the trapezoidal rule over the period at :data:`STEPS_PER_PERIOD` samples, as the instrument would measure it.

:class:`CalibrationTable` holds what the identification procedure of docs/METHOD.md section 3 reads: the phase
``phase(Fbar, r)`` on a grid of ``Fbar`` above ``pi/4`` and a log grid of ``r``, and ``r_90(Fbar)`` where the
phase crosses -90 degrees (root finding on the computed phase). :func:`compute_calibration` generates it
(``bodebench calibrate``); :func:`load_calibration` reads the copy shipped in ``instrument/data``.

Pure numerics apart from :meth:`CalibrationTable.save` / :func:`load_calibration`.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from importlib import metadata
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
from scipy.interpolate import CubicSpline, PchipInterpolator
from scipy.optimize import brentq

from bodebench.io.results import atomic_write_text, read_json_file
from bodebench.sim.plants import CoulombOscillator, PlantState

__all__ = [
    "CalibrationError",
    "CalibrationTable",
    "DATA_FILE",
    "DEFAULT_FBAR_GRID",
    "DEFAULT_OFFSET_GRID",
    "FBAR_CRITICAL",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "FrictionLink",
    "LinkState",
    "STEPS_PER_PERIOD",
    "SteadyStateError",
    "calibration_row",
    "compute_calibration",
    "crossing_ratio",
    "fold_phase_deg",
    "link_response",
    "load_calibration",
]

#: Samples per period of the simulated motion (and of the trapezoidal first harmonic).
STEPS_PER_PERIOD = 400

#: Where the shipped calibration table lives: the package data folder, bodebench/data.
DATA_FILE = Path(__file__).resolve().parent.parent / "data" / "friction_calibration.json"
FORMAT_NAME = "bodebench-friction-calibration"
FORMAT_VERSION = 1

#: Fbar = pi/4: below it the first-harmonic phase never crosses -90 degrees in steady state.
FBAR_CRITICAL = math.pi / 4.0

_MASS = 1.0 / (2.0 * math.pi) ** 2  # m of the dimensionless link: f_n = 1 Hz with K_p = 1
_WARMUP_HALF_PERIODS = 12
_NEWTON_ITERATIONS = 60
_PLAIN_FALLBACK_HALF_PERIODS = 4_000
_TOLERANCE = 1e-12  # residual of the half-wave condition relative to the state's size
_FD_STEP = 1e-7  # finite-difference step of the Jacobian, relative to the state's size
_LINE_SEARCH_HALVINGS = 14


class SteadyStateError(RuntimeError):
    """No settled periodic motion was found (e.g. Fbar < pi/4 exactly at resonance, where none exists)."""


class CalibrationError(ValueError):
    """A calibration file is missing, malformed or of another format version."""


@dataclass(frozen=True)
class LinkState:
    """The settled motion of the dimensionless link at one frequency ratio.

    y0, v0: displacement and velocity at phase zero of the input (units of A_F/K_p, and of A_F/K_p per
    second with f_n = 1 Hz); z1: first-harmonic coefficient P + jQ (units of A_F/K_p); sticks: whether the
    link sticks during the period; half_periods: half-period maps evaluated to find it.
    """

    fbar: float
    ratio: float
    damping_ratio: float
    y0: float
    v0: float
    z1: complex
    sticks: bool
    half_periods: int

    @property
    def gain(self) -> float:
        """|z1|: first-harmonic gain in units of 1/K_p."""
        return abs(self.z1)

    @property
    def phase_deg(self) -> float:
        """Phase of the first harmonic, degrees, folded into (-360, 0]."""
        return fold_phase_deg(self.z1)


def fold_phase_deg(z: complex) -> float:
    """Phase of ``z`` in degrees folded into (-360, 0] (the instrument's convention)."""
    phase = math.degrees(math.atan2(z.imag, z.real))
    return phase - 360.0 if phase > 0.0 else phase


def _check_fbar(fbar: float) -> float:
    value = float(fbar)
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"fbar (F_ct / A_F) must be finite and >= 0, got {fbar!r}")
    return value


def _check_ratio(ratio: float) -> float:
    value = float(ratio)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"frequency ratio f/f_n must be finite and > 0, got {ratio!r}")
    return value


class FrictionLink:
    """The dimensionless link (f_n = 1 Hz, K_p = 1, A_F = 1) with friction ``fbar`` and damping ratio ``zeta``."""

    def __init__(self, fbar: float, damping_ratio: float = 0.0) -> None:
        self.fbar = _check_fbar(fbar)
        zeta = float(damping_ratio)
        if not (math.isfinite(zeta) and zeta >= 0.0):
            raise ValueError(f"damping_ratio must be finite and >= 0, got {damping_ratio!r}")
        self.damping_ratio = zeta
        self._plant = CoulombOscillator(_MASS, 1.0, self.fbar, zeta)
        half = STEPS_PER_PERIOD // 2
        theta = 2.0 * math.pi * np.arange(half) / STEPS_PER_PERIOD
        self._sin = np.sin(theta)
        self._cos = np.cos(theta)

    def _half_map(self, x: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
        """State after half a period from state ``x`` at phase zero, and the samples (Y, V) along the way."""
        state = PlantState(np.array([x[0], x[1]], dtype=float), 0.0)
        out = self._plant.run_sine(state, 0.0, 1.0 / (STEPS_PER_PERIOD * ratio), STEPS_PER_PERIOD // 2, 1.0, ratio)
        return state.x.copy(), out

    def _describing_guess(self, ratio: float) -> np.ndarray | None:
        """Start state from the describing function of friction (exists only for 4 Fbar / pi < 1)."""
        c = 4.0 * self.fbar / math.pi
        if c >= 1.0:
            return None
        a = 1.0 - ratio * ratio
        b = 2.0 * self.damping_ratio * ratio
        s = a * a + b * b
        if s == 0.0:
            return None
        mag = (-b * c + math.sqrt(b * b * c * c - s * (c * c - 1.0))) / s
        if not (mag > 0.0 and math.isfinite(mag)):
            return None
        phi = -math.atan2(b + c / mag, a)
        omega = 2.0 * math.pi * ratio
        return np.array([mag * math.sin(phi), omega * mag * math.cos(phi)])

    def steady_state(self, ratio: float, guess: tuple[float, float] | None = None) -> LinkState:
        """The settled periodic motion at ``f = ratio * f_n``; ``guess``: a start state (y0, v0), e.g. a neighbour's.

        Raises SteadyStateError when no periodic motion is found.
        """
        ratio = _check_ratio(ratio)
        omega = 2.0 * math.pi * ratio
        weights = np.array([1.0, 1.0 / omega])  # state measured as (Y, V / omega)
        maps = 0

        def residual(x: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
            nonlocal maps
            maps += 1
            x1, out = self._half_map(x, ratio)
            f = x1 + x
            return f, float(np.hypot(*(f * weights))), x1, out

        def size(x: np.ndarray, x1: np.ndarray) -> float:
            return max(float(np.hypot(*(x * weights))), float(np.hypot(*(x1 * weights))), 1e-300)

        if guess is not None:
            x = np.array(guess, dtype=float)
        else:
            start = self._describing_guess(ratio)
            x = np.zeros(2) if start is None else start
            for _ in range(_WARMUP_HALF_PERIODS):
                x1, _ = self._half_map(x, ratio)
                maps += 1
                x = -x1
        f, res, x1, out = residual(x)
        for _ in range(_NEWTON_ITERATIONS):
            scale = size(x, x1)
            if res <= _TOLERANCE * scale:
                return self._finish(ratio, x, out, maps)
            jac = np.empty((2, 2))
            for k in range(2):
                dx = _FD_STEP * scale / weights[k]
                xp = x.copy()
                xp[k] += dx
                fp, _, _, _ = residual(xp)
                jac[:, k] = (fp - f) / dx
            step = np.linalg.lstsq(jac * weights[:, None], -f * weights, rcond=1e-12)[0]
            accepted = False
            lam = 1.0
            if np.all(np.isfinite(step)):
                for _ in range(_LINE_SEARCH_HALVINGS):
                    xn = x + lam * step
                    fn, resn, x1n, outn = residual(xn)
                    if resn < res:
                        x, f, res, x1, out = xn, fn, resn, x1n, outn
                        accepted = True
                        break
                    lam *= 0.5
            if not accepted:  # plain steps of the map instead, which approach an attracting motion
                for _ in range(4):
                    x = -x1
                    f, res, x1, out = residual(x)
        for _ in range(_PLAIN_FALLBACK_HALF_PERIODS):
            if res <= _TOLERANCE * size(x, x1):
                return self._finish(ratio, x, out, maps)
            x = -x1
            f, res, x1, out = residual(x)
        raise SteadyStateError(
            f"no settled motion of the friction link at Fbar = {self.fbar:g}, f/f_n = {ratio:g}, "
            f"damping ratio {self.damping_ratio:g} (half-wave residual {res / size(x, x1):.2e} after {maps} "
            "half periods)")

    def _finish(self, ratio: float, x: np.ndarray, out: np.ndarray, maps: int) -> LinkState:
        # the second half period is the negative of the first: the trapezoid over the period is twice the half
        y = np.concatenate([[x[0]], out[:-1, 0]])
        p = 4.0 / STEPS_PER_PERIOD * float(np.dot(y, self._sin))
        q = 4.0 / STEPS_PER_PERIOD * float(np.dot(y, self._cos))
        sticks = bool(np.any(out[:, 1] == 0.0)) or x[1] == 0.0
        return LinkState(self.fbar, ratio, self.damping_ratio, float(x[0]), float(x[1]), complex(p, q), sticks,
                         maps)


def link_response(fbar: float, ratio: float, damping_ratio: float = 0.0) -> complex:
    """First-harmonic coefficient P + jQ of the settled link, in units of A_F / K_p, at f = ratio * f_n."""
    return FrictionLink(fbar, damping_ratio).steady_state(ratio).z1


def _phase_of(link: FrictionLink, ratio: float) -> float:
    return link.steady_state(ratio).phase_deg


def crossing_ratio(fbar: float, lo: float = 0.005, hi: float = 1.0, damping_ratio: float = 0.0) -> float:
    """r_90 = f_-90 / f_n: where the settled first-harmonic phase crosses -90 degrees (Fbar > pi/4 only).

    Found by Brent's method on the computed phase in ln r (tolerance 1e-13 in ln r); the bracket
    [lo, hi] is scanned on a log grid for the first sign change of phase + 90.
    """
    fbar = _check_fbar(fbar)
    if fbar <= FBAR_CRITICAL or fbar >= 1.0:
        raise ValueError(f"fbar must lie in (pi/4, 1) for a -90 degree crossing, got {fbar!r}")
    link = FrictionLink(fbar, damping_ratio)
    grid = np.geomspace(lo, hi, 25)
    values = [_phase_of(link, r) + 90.0 for r in grid]
    for (a, b), (va, vb) in zip(pairwise(grid), pairwise(values), strict=True):
        if va == 0.0:
            return float(a)
        if va > 0.0 > vb:
            u = brentq(lambda s: _phase_of(link, math.exp(s)) + 90.0, math.log(a), math.log(b),
                       xtol=1e-13, rtol=1e-13)
            return float(math.exp(u))
    raise SteadyStateError(f"the phase at Fbar = {fbar:g} does not cross -90 degrees between f/f_n = {lo:g} "
                           f"and {hi:g}")


# ------------------------------------------------------------------------------------------- the calibration table


def _grid(values: Sequence[float]) -> tuple[float, ...]:
    return tuple(sorted({float(f"{v:.12g}") for v in values}))


#: Friction levels of the shipped table: just above pi/4 to 0.99 (finer above 0.95, where r_90 falls fast).
DEFAULT_FBAR_GRID: tuple[float, ...] = _grid([0.79 + 0.005 * i for i in range(33)]
                                             + [0.95 + 0.0025 * i for i in range(1, 17)])
#: Frequency offsets f/f_-90 of the shipped table: 0.12 to 10 at 50 a decade (6 decade ticks either side of any
#: f_-90 lie within 0.125 and 8 times it), plus steps of 0.005 over 0.97 to 1.1, where the phase drops steeply
#: just above the crossing.
DEFAULT_OFFSET_GRID: tuple[float, ...] = _grid(list(np.geomspace(0.12, 10.0, 97))
                                               + [0.97 + 0.005 * i for i in range(27)])


@dataclass(frozen=True)
class CalibrationTable:
    """Calibration curves of the f_-90 procedure (docs/METHOD.md section 3), in dimensionless form.

    fbar: (n_f,) friction levels F_ct/A_F, ascending, in (pi/4, 1); offset: (n_o,) frequency offsets
    ``rho = f / f_-90``, ascending; phase_deg: (n_f, n_o) settled first-harmonic phase (degrees) at
    ``f / f_n = rho * r90``; r90: (n_f,) ``f_-90 / f_n``; parameters: how the table was generated; software: the
    generating software's version.

    The curves are kept against ``f / f_-90`` rather than ``f / f_n``: the procedure reads them at tick offsets
    from ``f_-90``, and the steep drop of the phase just above the crossing (at ``rho`` of 1.01 to 1.05 for every
    Fbar) stays at nearly the same column. Between nodes the phase is interpolated monotonically (PCHIP) in
    ``ln rho`` and then in Fbar, ``ln r90`` by a cubic spline in Fbar.
    """

    fbar: np.ndarray
    offset: np.ndarray
    phase_deg: np.ndarray
    r90: np.ndarray
    parameters: dict[str, Any] = field(default_factory=dict)
    software: str = "unknown"

    def __post_init__(self) -> None:
        for name in ("fbar", "offset", "phase_deg", "r90"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=float))
        nf, no = self.fbar.size, self.offset.size
        if self.fbar.ndim != 1 or self.offset.ndim != 1 or nf < 4 or no < 4:
            raise CalibrationError(f"calibration table needs 1-D grids of at least 4 Fbar and 4 offsets, got "
                                   f"shapes {self.fbar.shape} and {self.offset.shape}")
        for name, shape in (("phase_deg", (nf, no)), ("r90", (nf,))):
            if getattr(self, name).shape != shape:
                raise CalibrationError(f"calibration table: {name} has shape {getattr(self, name).shape}, "
                                       f"expected {shape}")
        for name in ("fbar", "offset"):
            values = getattr(self, name)
            if not (np.all(np.isfinite(values)) and np.all(np.diff(values) > 0.0)):
                raise CalibrationError(f"calibration table: {name} must be finite and strictly ascending")
        if not (self.fbar[0] > FBAR_CRITICAL and self.fbar[-1] < 1.0 and self.offset[0] > 0.0):
            raise CalibrationError("calibration table: Fbar must lie in (pi/4, 1) and offsets be > 0")
        if not (np.all(np.isfinite(self.phase_deg)) and np.all(np.isfinite(self.r90)) and np.all(self.r90 > 0.0)):
            raise CalibrationError("calibration table: phase_deg and r90 must be finite (r90 > 0)")

    @functools.cached_property
    def _rows(self) -> PchipInterpolator:
        return PchipInterpolator(np.log(self.offset), self.phase_deg, axis=1)

    @functools.cached_property
    def _r90_spline(self) -> CubicSpline:
        return CubicSpline(self.fbar, np.log(self.r90))

    @property
    def fbar_range(self) -> tuple[float, float]:
        """Smallest and largest Fbar of the table."""
        return float(self.fbar[0]), float(self.fbar[-1])

    @property
    def offset_range(self) -> tuple[float, float]:
        """Smallest and largest f/f_-90 of the table."""
        return float(self.offset[0]), float(self.offset[-1])

    def _check_offset(self, offset: float) -> float:
        lo, hi = self.offset_range
        if not (math.isfinite(offset) and lo <= offset <= hi):
            raise ValueError(f"f/f_-90 = {offset!r} outside the calibration table ({lo:g} to {hi:g})")
        return float(offset)

    def _check_fbar(self, fbar: float) -> float:
        lo, hi = self.fbar_range
        if not (math.isfinite(fbar) and lo <= fbar <= hi):
            raise ValueError(f"Fbar {fbar!r} outside the calibration table ({lo:g} to {hi:g})")
        return float(fbar)

    def curve(self, offset: float) -> np.ndarray:
        """The calibration curve of one offset: the phase (degrees) at f = offset * f_-90 for every Fbar node."""
        return np.asarray(self._rows(math.log(self._check_offset(offset))), dtype=float)

    def curves(self, offsets: np.ndarray | Sequence[float]) -> np.ndarray:
        """Phase (degrees) at f = offset * f_-90 for every Fbar node and offset: shape (n_f, len(offsets))."""
        values = np.asarray(offsets, dtype=float)
        for v in values.reshape(-1):
            self._check_offset(float(v))
        return np.asarray(self._rows(np.log(values)), dtype=float)

    def phase(self, fbar: float, offset: float) -> float:
        """Settled first-harmonic phase (degrees) at Fbar and f/f_-90 = offset."""
        fbar = self._check_fbar(fbar)
        return float(PchipInterpolator(self.fbar, self.curve(offset))(fbar))

    def crossing_ratio(self, fbar: float) -> float:
        """r_90(Fbar) = f_-90 / f_n."""
        return float(math.exp(self._r90_spline(self._check_fbar(fbar))))

    def to_json(self) -> dict[str, Any]:
        """The table as JSON types (floats written in shortest round-tripping form by ``json``)."""
        return {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "software": {"name": "bodebench", "version": self.software},
            "parameters": self.parameters,
            "fbar": [float(v) for v in self.fbar],
            "offset": [float(v) for v in self.offset],
            "r90": [float(v) for v in self.r90],
            "phase_deg": [[float(v) for v in row] for row in self.phase_deg],
        }

    def to_text(self) -> str:
        """The JSON file's text: one line per phase row, phases rounded to 1e-9 degrees, nothing time-dependent."""
        data = self.to_json()
        rows = data.pop("phase_deg")
        items = [f"{json.dumps(key)}: {json.dumps(value)}" for key, value in data.items()]
        body = ",\n  ".join(json.dumps([round(v, 9) for v in row]) for row in rows)
        items.append(f'"phase_deg": [\n  {body}\n ]')
        return "{\n " + ",\n ".join(items) + "\n}\n"

    def save(self, path: str | Path) -> None:
        """Write the table as JSON (through a temporary file in the same directory, then renamed)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, self.to_text())

    @classmethod
    def from_json(cls, data: object, source: str = "<calibration>") -> CalibrationTable:
        """Build a table from :meth:`to_json` output; raises CalibrationError naming ``source``."""
        if not isinstance(data, dict):
            raise CalibrationError(f"{source}: expected a JSON object")
        if data.get("format") != FORMAT_NAME:
            raise CalibrationError(f"{source}: not a friction calibration file (format {data.get('format')!r})")
        if data.get("version") != FORMAT_VERSION:
            raise CalibrationError(f"{source}: calibration format version {data.get('version')!r}, this software "
                                   f"reads version {FORMAT_VERSION} (run bodebench calibrate)")
        software = data.get("software")
        parameters = data.get("parameters", {})
        if not isinstance(parameters, dict):
            raise CalibrationError(f"{source}: parameters must be an object")
        try:
            return cls(
                fbar=np.array(data["fbar"], dtype=float),
                offset=np.array(data["offset"], dtype=float),
                phase_deg=np.array(data["phase_deg"], dtype=float),
                r90=np.array(data["r90"], dtype=float),
                parameters=dict(parameters),
                software=str(software.get("version", "unknown")) if isinstance(software, dict) else "unknown",
            )
        except KeyError as exc:
            raise CalibrationError(f"{source}: missing key {exc.args[0]!r}") from None
        except CalibrationError as exc:
            raise CalibrationError(f"{source}: {exc}") from None
        except (TypeError, ValueError) as exc:
            raise CalibrationError(f"{source}: malformed array: {exc}") from None


def _software_version() -> str:
    try:
        return metadata.version("bodebench")
    except metadata.PackageNotFoundError:
        return "unknown"


def calibration_row(fbar: float, offsets: Sequence[float]) -> tuple[float, list[float]]:
    """One row of the table: r_90(Fbar) and the phase (degrees) at f = offset * f_-90 for every offset.

    Every point is solved from scratch, so a row does not depend on which other rows or points are computed.
    """
    r90 = crossing_ratio(fbar)
    link = FrictionLink(fbar)
    return r90, [link.steady_state(rho * r90).phase_deg for rho in offsets]


def compute_calibration(fbar_grid: Sequence[float] = DEFAULT_FBAR_GRID,
                        offset_grid: Sequence[float] = DEFAULT_OFFSET_GRID,
                        executor: Executor | None = None) -> CalibrationTable:
    """Compute the calibration table with the simulator (rows in parallel on ``executor`` if given).

    The same grids give the same numbers whatever the executor.
    """
    fbar = [float(v) for v in fbar_grid]
    offsets = [float(v) for v in offset_grid]
    if executor is None:
        rows = [calibration_row(f, offsets) for f in fbar]
    else:
        futures = [executor.submit(calibration_row, f, offsets) for f in fbar]
        rows = [fut.result() for fut in futures]
    parameters = {
        "model": "m Y'' = U - F_ct sign(V) - K_p Y with exact sticking (sim.plants.CoulombOscillator)",
        "units": "m = 1/(2 pi)^2, K_p = 1, A_F = 1, so f_n = 1 Hz; offset = f/f_-90; r90 = f_-90/f_n",
        "steady_state": "half-wave periodic solution, Newton shooting on the exact half-period map",
        "shooting_tolerance": _TOLERANCE,
        "steps_per_period": STEPS_PER_PERIOD,
        "first_harmonic": "trapezoidal rule over one period",
        "r90": "Brent's method on the computed phase in ln(f/f_n), tolerance 1e-13",
        "phase_rounding_deg": 1e-9,
    }
    return CalibrationTable(fbar=np.array(fbar), offset=np.array(offsets),
                            phase_deg=np.array([row[1] for row in rows]), r90=np.array([row[0] for row in rows]),
                            parameters=parameters, software=_software_version())


def load_calibration(path: str | Path | None = None) -> CalibrationTable:
    """Read a calibration file (default: the one shipped with the package); raises CalibrationError."""
    if path is None:
        return _shipped_table()
    return _read_table(Path(path))


def _read_table(path: Path) -> CalibrationTable:
    data = read_json_file(path, CalibrationError, "calibration file", " (run bodebench calibrate)")
    return CalibrationTable.from_json(data, str(path))


@functools.lru_cache(maxsize=1)
def _shipped_table() -> CalibrationTable:
    return _read_table(DATA_FILE)
