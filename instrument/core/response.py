"""Measured frequency response: points of a sweep, derived gain and phase, and their files.

A point holds the averaged Fourier coefficients ``(P, Q)`` of harmonic ``k`` of one output channel,
``y ~ P sin(2 pi k f t) + Q cos(2 pi k f t)``, for an input ``A_i sin(2 pi f t)``. Gain and phase are
derived from them; nothing derived is stored independently of ``p``, ``q`` and ``amplitude``.

Files (see :meth:`FrequencyResponse.save`): ``response.csv`` (one row per point) and the JSON sidecar
``response.json`` (case name, configuration, software version). This module does no plotting.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CSV_COLUMNS",
    "CSV_NAME",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "FrequencyResponse",
    "PHASE_UNDEFINED_STATUSES",
    "ResponsePoint",
    "ResultsError",
    "SIDECAR_NAME",
]

#: Statuses whose phase is not a number (the coefficient vector is below the resolution).
PHASE_UNDEFINED_STATUSES: tuple[str, ...] = ("below_resolution",)

CSV_NAME = "response.csv"
SIDECAR_NAME = "response.json"
FORMAT_NAME = "bodebench-response"
FORMAT_VERSION = 2

#: Columns of response.csv, in file order.
CSV_COLUMNS: tuple[str, ...] = (
    "frequency_hz",
    "harmonic",
    "channel",
    "amplitude",
    "gain",
    "gain_db",
    "phase_deg",
    "p",
    "q",
    "periods",
    "converged",
    "status",
    "uncertainty",
    "gain_ci",
    "gain_db_ci",
    "phase_ci_deg",
    "uncertainty_1d",
    "within_eps",
    "periods_needed",
)
#: Columns of a version-1 response.csv (read; the added columns take their defaults).
_CSV_COLUMNS_V1 = CSV_COLUMNS[:16]
_DERIVED_COLUMNS: tuple[str, ...] = ("gain", "gain_db", "phase_deg", "gain_ci", "gain_db_ci", "phase_ci_deg")
_DERIVED_RTOL = 1e-9
_FORBIDDEN_TOKEN_CHARS = frozenset(',"\r\n')


class ResultsError(ValueError):
    """A results file or sidecar is missing, malformed or inconsistent."""


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
    the requested tolerance would take (0: not estimated).
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

    def __post_init__(self) -> None:
        def set_(name: str, value: object) -> None:
            object.__setattr__(self, name, value)

        for name in ("frequency_hz", "amplitude", "p", "q", "uncertainty", "uncertainty_1d"):
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
        for name in ("uncertainty", "uncertainty_1d"):
            if not (math.isnan(getattr(self, name)) or getattr(self, name) >= 0.0):
                raise ValueError(f"{name} must be >= 0 or NaN, got {getattr(self, name)!r}")
        for name in ("within_eps", "converged"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
            set_(name, bool(getattr(self, name)))
        if not _is_int(self.periods_needed) or self.periods_needed < 0:
            raise ValueError(f"periods_needed must be an integer >= 0, got {self.periods_needed!r}")
        set_("periods_needed", int(self.periods_needed))
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


def _software_version() -> str:
    try:
        return metadata.version("bodebench")
    except metadata.PackageNotFoundError:
        return "unknown"


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


PLOTS_BYTES = 1 << 20
"""Room the plots of a finished case take at most (four files of 50-100 KB each, with margin), bytes."""
POINT_BYTES = 256
"""Room one point takes in response.csv at most, bytes."""


def check_output(directory: Path, points: int) -> bool:
    """Before a sweep: ``directory`` exists or can be made, a file can be written in it, and its file system has
    room for the results of ``points`` points (each save writes a new file before it replaces the old: twice the
    CSV and sidecar) and the plots. ResultsError naming the directory otherwise; True when it made the
    directory."""
    made = not directory.exists()
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ResultsError(f"{directory}: cannot create the results directory: {exc.strerror or exc}") from None
    probe = directory / ".bodebench-write-check"
    try:
        atomic_write_text(probe, "x" * POINT_BYTES)
        probe.unlink()
    except OSError as exc:
        raise ResultsError(f"{directory}: cannot write results there: {exc.strerror or exc}") from None
    need = 2 * (8192 + points * POINT_BYTES) + PLOTS_BYTES
    free = shutil.disk_usage(directory).free
    if free < need:
        if made:
            directory.rmdir()
        raise ResultsError(f"{directory}: {free / 1024:.0f} KiB free, the sweep's files need about "
                           f"{need / 1024:.0f} KiB")
    return made


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a synced temporary file in the same directory and os.replace."""
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)  # the permissions an ordinary open() would give, not mkstemp's 0600
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        try:
            os.unlink(tmp_name)
        except FileNotFoundError:
            pass
        raise
    try:  # make the rename itself durable where the platform allows it
        dir_fd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dir_fd)
    except OSError:
        pass
    finally:
        os.close(dir_fd)


def _format_float(value: float) -> str:
    return repr(float(value))  # shortest round-tripping form; 'nan', 'inf', '-inf' for non-finite values


def _point_row(point: ResponsePoint) -> str:
    values: dict[str, str] = {
        "frequency_hz": _format_float(point.frequency_hz),
        "harmonic": str(point.harmonic),
        "channel": point.channel,
        "amplitude": _format_float(point.amplitude),
        "p": _format_float(point.p),
        "q": _format_float(point.q),
        "periods": str(point.periods),
        "converged": "true" if point.converged else "false",
        "status": point.status,
        "uncertainty": _format_float(point.uncertainty),
        "uncertainty_1d": _format_float(point.uncertainty_1d),
        "within_eps": "true" if point.within_eps else "false",
        "periods_needed": str(point.periods_needed),
    }
    for name in _DERIVED_COLUMNS:
        values[name] = _format_float(getattr(point, name))
    return ",".join(values[name] for name in CSV_COLUMNS)


def _agree(stored: float, computed: float) -> bool:
    if math.isnan(stored) or math.isnan(computed):
        return math.isnan(stored) and math.isnan(computed)
    if math.isinf(stored) or math.isinf(computed):
        return stored == computed
    return abs(stored - computed) <= _DERIVED_RTOL * max(abs(stored), abs(computed))


def _parse_csv(path: Path) -> list[ResponsePoint]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ResultsError(f"{path}: results file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ResultsError(f"{path}: cannot read results file: {exc}") from None
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()  # final newline
    if not lines:
        raise ResultsError(f"{path}: line 1: empty file, expected header {','.join(CSV_COLUMNS)!r}")
    header = lines[0].rstrip("\r").split(",")
    columns = _CSV_COLUMNS_V1 if tuple(header) == _CSV_COLUMNS_V1 else CSV_COLUMNS
    if tuple(header) != columns:
        for index, (got, want) in enumerate(zip(header, CSV_COLUMNS)):
            if got != want:
                raise ResultsError(
                    f"{path}: line 1: bad header, column {index + 1} is {got!r}, expected {want!r}"
                )
        raise ResultsError(
            f"{path}: line 1: bad header, {len(header)} columns, expected {len(CSV_COLUMNS)}: {','.join(CSV_COLUMNS)!r}"
        )
    points: list[ResponsePoint] = []
    for lineno, line in enumerate(lines[1:], start=2):
        cells = line.rstrip("\r").split(",")
        if len(cells) != len(columns):
            raise ResultsError(f"{path}: line {lineno}: {len(cells)} columns, expected {len(columns)}")
        row = dict(zip(columns, cells))
        points.append(_parse_row(path, lineno, row))
    return points


def _parse_row(path: Path, lineno: int, row: dict[str, str]) -> ResponsePoint:
    where = f"{path}: line {lineno}"

    def number(name: str) -> float:
        cell = row[name]
        try:
            return float(cell)
        except ValueError:
            raise ResultsError(f"{where}: column {name!r}: cannot parse {cell!r} as a number") from None

    def integer(name: str) -> int:
        cell = row[name]
        try:
            return int(cell)
        except ValueError:
            raise ResultsError(f"{where}: column {name!r}: cannot parse {cell!r} as an integer") from None

    def boolean(name: str) -> bool:
        cell = row.get(name, "false")
        if cell not in ("true", "false"):
            raise ResultsError(f"{where}: column {name!r}: expected 'true' or 'false', got {cell!r}")
        return cell == "true"

    try:
        point = ResponsePoint(
            frequency_hz=number("frequency_hz"),
            harmonic=integer("harmonic"),
            channel=row["channel"],
            amplitude=number("amplitude"),
            p=number("p"),
            q=number("q"),
            periods=integer("periods"),
            converged=boolean("converged"),
            status=row["status"],
            uncertainty=number("uncertainty"),
            uncertainty_1d=number("uncertainty_1d") if "uncertainty_1d" in row else math.nan,
            within_eps=boolean("within_eps"),
            periods_needed=integer("periods_needed") if "periods_needed" in row else 0,
        )
    except ResultsError:
        raise
    except ValueError as exc:
        raise ResultsError(f"{where}: invalid point: {exc}") from None
    for name in _DERIVED_COLUMNS:
        stored = number(name)
        computed = getattr(point, name)
        if not _agree(stored, computed):
            raise ResultsError(
                f"{where}: column {name!r}: stored value {row[name]!r} disagrees with {computed!r} "
                "recomputed from p, q and amplitude"
            )
    return point


def read_json_file(path: Path, error: type[Exception], what: str, missing_hint: str = "") -> Any:
    """The JSON value stored in ``path``; ``error`` naming the file (and the line) when it is missing (with
    ``missing_hint`` appended), unreadable or not JSON. ``what`` names the file's role, e.g. "sidecar file"."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: {what} not found{missing_hint}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read {what}: {exc}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: line {exc.lineno}: {what} is not valid JSON: {exc.msg}") from None


def _parse_sidecar(path: Path) -> tuple[str, dict[str, Any]]:
    data = read_json_file(path, ResultsError, "sidecar file")
    if not isinstance(data, dict):
        raise ResultsError(f"{path}: sidecar must hold a JSON object, got {type(data).__name__}")
    for key in ("format", "version", "case", "config"):
        if key not in data:
            raise ResultsError(f"{path}: key {key!r} missing from sidecar")
    if data["format"] != FORMAT_NAME:
        raise ResultsError(f"{path}: key 'format': unknown format {data['format']!r}, expected {FORMAT_NAME!r}")
    if not _is_int(data["version"]) or data["version"] not in (1, FORMAT_VERSION):
        raise ResultsError(
            f"{path}: key 'version': unsupported version {data['version']!r}, expected {FORMAT_VERSION}"
        )
    if not isinstance(data["case"], str):
        raise ResultsError(f"{path}: key 'case': expected a string, got {data['case']!r}")
    if not isinstance(data["config"], dict):
        raise ResultsError(f"{path}: key 'config': expected a JSON object, got {type(data['config']).__name__}")
    return data["case"], data["config"]


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
        out = FrequencyResponse(case=self.case)
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

    def save(self, directory: str | Path) -> None:
        """Write ``directory/response.csv`` and ``directory/response.json`` atomically (creates the directory)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        sidecar = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "case": self.case,
            "config": _normalise_config(self.config),
            "software": {"name": "bodebench", "version": _software_version()},
        }
        csv_text = "".join(line + "\n" for line in [",".join(CSV_COLUMNS), *map(_point_row, self.points)])
        atomic_write_text(directory / SIDECAR_NAME, json.dumps(sidecar, indent=2) + "\n")
        atomic_write_text(directory / CSV_NAME, csv_text)

    @classmethod
    def load(cls, directory: str | Path) -> FrequencyResponse:
        """Read a response written by :meth:`save`; raises ResultsError for missing, malformed or tampered files."""
        directory = Path(directory)
        case, config = _parse_sidecar(directory / SIDECAR_NAME)
        points = _parse_csv(directory / CSV_NAME)
        return cls(points, config=config, case=case)

    def write_point(self, directory: str | Path, point: ResponsePoint) -> None:
        """Add ``point`` and save the whole response to ``directory``."""
        self.add(point)
        self.save(directory)
