"""Results files: ``response.csv`` (one row per point) and its JSON sidecar ``response.json``.

The sidecar names the case and holds the configuration that made the points and the software version. Points are
appended to the CSV as they are measured (:class:`ResultsWriter`), each row synced before the writer returns, so a
point is on disk the moment it is measured; a crash can at worst leave the last row unterminated: the reader
refuses such a file by default, and a resumed sweep drops that row (never confirmed written) and goes on.
:func:`save_response` writes a whole response atomically; :func:`load_response` reads either and checks every
derived column against ``p``, ``q`` and ``amplitude``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
import tempfile
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

from bodebench.core.response import FrequencyResponse, ResponsePoint, _is_int, _normalise_config
from bodebench.core.summary import CONFIDENCE
from bodebench.drivers.stop_signals import signals_held
from bodebench.io.csvstyle import CsvStyle, csv_metadata, style_of_config, style_of_header

__all__ = [
    "CSV_COLUMNS",
    "CSV_METADATA_NAME",
    "CSV_NAME",
    "CHECKSUMS",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "ResultsError",
    "ResultsWriter",
    "RowsOnDiskError",
    "SIDECAR_NAME",
    "check_output",
    "load_response",
    "save_response",
    "sidecar_runs",
    "update_sidecar",
    "verify_results",
    "write_summary",
]

CSV_NAME = "response.csv"
SIDECAR_NAME = "response.json"
CSV_METADATA_NAME = "response.csv-metadata.json"
"""Beside response.csv: its columns' meanings and units, the confidence level, the dialect (CSVW)."""
PLOT_FIGURES = ("bode", "periods")
"""The figures a results directory holds: the stems of their files (the suffix is the format)."""
FORMAT_NAME = "bodebench-response"
FORMAT_VERSION = 6

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
    "thd",
    "coherence",
    "periods_discarded",
    "drift_per_s",
    "tolerance_percent",
)
#: Columns of a version-1 to -5 response.csv (read; the added columns take their defaults).
_CSV_COLUMNS_V1 = CSV_COLUMNS[:16]
_CSV_COLUMNS_V2 = CSV_COLUMNS[:19]
_CSV_COLUMNS_V3 = CSV_COLUMNS[:21]
_CSV_COLUMNS_V4 = CSV_COLUMNS[:22]
_CSV_COLUMNS_V5 = CSV_COLUMNS[:23]
_OLDER_COLUMNS = (_CSV_COLUMNS_V1, _CSV_COLUMNS_V2, _CSV_COLUMNS_V3, _CSV_COLUMNS_V4, _CSV_COLUMNS_V5)
_DERIVED_COLUMNS: tuple[str, ...] = ("gain", "gain_db", "phase_deg", "gain_ci", "gain_db_ci", "phase_ci_deg")
_DERIVED_RTOL = 1e-9
_DEFAULT_STYLE = CsvStyle()

class ResultsError(ValueError):
    """A results file or sidecar is missing, malformed or inconsistent."""


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
    if directory.is_symlink() and not directory.exists():
        raise ResultsError(f"{directory}: a symbolic link to {os.readlink(directory)}, which does not exist; give a "
                           "directory, or make the link's target first")
    if directory.exists() and not directory.is_dir():
        raise ResultsError(f"{directory}: not a directory (a file is there); give a directory for the results")
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
    """Write ``text`` (UTF-8) to ``path`` as :func:`atomic_write_bytes` does."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a synced temporary file in the same directory and os.replace."""
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        # the permissions an ordinary open() would give, not mkstemp's 0600; by path, as every platform has it
        # (os.fchmod came to Windows only with Python 3.13, where it sets the read-only flag alone, as os.chmod does)
        os.chmod(tmp_name, 0o666 & ~_UMASK)
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
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


def _point_row(point: ResponsePoint, style: CsvStyle = _DEFAULT_STYLE) -> str:
    def num(value: float) -> str:
        return style.number(_format_float(value))

    values: dict[str, str] = {
        "frequency_hz": num(point.frequency_hz),
        "harmonic": str(point.harmonic),
        "channel": point.channel,
        "amplitude": num(point.amplitude),
        "p": num(point.p),
        "q": num(point.q),
        "periods": str(point.periods),
        "converged": "true" if point.converged else "false",
        "status": point.status,
        "uncertainty": num(point.uncertainty),
        "uncertainty_1d": num(point.uncertainty_1d),
        "within_eps": "true" if point.within_eps else "false",
        "periods_needed": str(point.periods_needed),
        "thd": num(point.thd),
        "coherence": num(point.coherence),
        "periods_discarded": str(point.periods_discarded),
        "drift_per_s": num(point.drift_per_s),
        "tolerance_percent": num(point.tolerance_percent),
    }
    for name in _DERIVED_COLUMNS:
        values[name] = num(getattr(point, name))
    try:
        return style.join([values[name] for name in CSV_COLUMNS])
    except ValueError as exc:
        raise ResultsError(f"point at {point.frequency_hz:g} Hz: {exc}") from None


def _file_head(style: CsvStyle) -> str:
    """The header line of a new response.csv."""
    return style.join(list(CSV_COLUMNS)) + "\n"


def _write_csv(directory: Path, style: CsvStyle, rows: list[str]) -> None:
    """response.csv (its header and ``rows``) and its description, response.csv-metadata.json, atomically."""
    atomic_write_text(directory / CSV_NAME, _file_head(style) + "".join(row + "\n" for row in rows))
    metadata = csv_metadata(CSV_NAME, FORMAT_VERSION, CONFIDENCE, style, CSV_COLUMNS)
    atomic_write_text(directory / CSV_METADATA_NAME, json.dumps(metadata, indent=2) + "\n")


def _header_index(lines: list[str]) -> int:
    """Index of the header line: the first that is not a comment (len(lines) when there is none)."""
    for index, line in enumerate(lines):
        if not line.startswith("#"):
            return index
    return len(lines)


def _agree(stored: float, computed: float) -> bool:
    if math.isnan(stored) or math.isnan(computed):
        return math.isnan(stored) and math.isnan(computed)
    if math.isinf(stored) or math.isinf(computed):
        return stored == computed
    return abs(stored - computed) <= _DERIVED_RTOL * max(abs(stored), abs(computed))


def _parse_csv(path: Path, drop_torn_row: bool = False) -> list[ResponsePoint]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ResultsError(f"{path}: results file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ResultsError(f"{path}: cannot read results file: {exc}") from None
    lines = text.split("\n")
    h = _header_index(lines)
    header_line = lines[h] if h < len(lines) else ""
    style = style_of_header(header_line)
    torn = len(lines) > h + 2 and lines[-1] != "" and _torn(path, len(lines), lines[-1], header_line)
    if torn and not drop_torn_row:
        raise ResultsError(f"{path}: line {len(lines)}: unterminated row, cut short by an interrupted write "
                           "(resuming the sweep drops it and measures that frequency again)")
    if torn or (lines and lines[-1] == ""):
        lines.pop()  # the final newline, or a row an interrupted append left unterminated (never written)
    if h >= len(lines):
        raise ResultsError(f"{path}: line {h + 1}: empty file, expected header {','.join(CSV_COLUMNS)!r}")
    header = lines[h].rstrip("\r").split(style.delimiter)
    columns = _columns_of(lines[h])
    if tuple(header) != columns:
        for index, (got, want) in enumerate(zip(header, CSV_COLUMNS, strict=False)):
            if got != want:
                raise ResultsError(
                    f"{path}: line {h + 1}: bad header, column {index + 1} is {got!r}, expected {want!r}"
                )
        raise ResultsError(
            f"{path}: line {h + 1}: bad header, {len(header)} columns, expected {len(CSV_COLUMNS)}: "
            f"{','.join(CSV_COLUMNS)!r}"
        )
    return [_parse_line(path, lineno, line, columns, style)
            for lineno, line in enumerate(lines[h + 1:], start=h + 2)]


def _parse_line(path: Path, lineno: int, line: str, columns: tuple[str, ...],
                style: CsvStyle = _DEFAULT_STYLE) -> ResponsePoint:
    cells = line.rstrip("\r").split(style.delimiter)
    if len(cells) != len(columns):
        raise ResultsError(f"{path}: line {lineno}: {len(cells)} columns, expected {len(columns)}")
    return _parse_row(path, lineno, dict(zip(columns, cells, strict=True)), decimal_comma=style.decimal == ",")


def _columns_of(header: str) -> tuple[str, ...]:
    """The columns of a file with this header line: an older version's, else the current ones."""
    names = tuple(header.rstrip("\r").split(style_of_header(header).delimiter))
    return names if names in _OLDER_COLUMNS else CSV_COLUMNS


def _torn(path: Path, lineno: int, line: str, header: str) -> bool:
    """Whether an unterminated last row is the remains of an interrupted append (it does not parse)."""
    columns = _columns_of(header)
    try:
        _parse_line(path, lineno, line, columns, style_of_header(header))
    except ResultsError:
        return True
    return False


def _parse_row(path: Path, lineno: int, row: dict[str, str], decimal_comma: bool = False) -> ResponsePoint:
    where = f"{path}: line {lineno}"

    def number(name: str) -> float:
        cell = row[name].replace(",", ".") if decimal_comma else row[name]
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
            thd=number("thd") if "thd" in row else math.nan,
            coherence=number("coherence") if "coherence" in row else math.nan,
            periods_discarded=integer("periods_discarded") if "periods_discarded" in row else 0,
            drift_per_s=number("drift_per_s") if "drift_per_s" in row else math.nan,
            tolerance_percent=number("tolerance_percent") if "tolerance_percent" in row else math.nan,
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
    if not _is_int(data["version"]) or data["version"] not in range(1, FORMAT_VERSION + 1):
        raise ResultsError(
            f"{path}: key 'version': unsupported version {data['version']!r}, expected {FORMAT_VERSION}"
        )
    if not isinstance(data["case"], str):
        raise ResultsError(f"{path}: key 'case': expected a string, got {data['case']!r}")
    if not isinstance(data["config"], dict):
        raise ResultsError(f"{path}: key 'config': expected a JSON object, got {type(data['config']).__name__}")
    return data["case"], data["config"]


def _sidecar_text(case: str, config: Mapping[str, Any]) -> str:
    sidecar = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "case": case,
        "config": _normalise_config(config),
        "software": {"name": "bodebench", "version": _software_version()},
    }
    return json.dumps(sidecar, indent=2) + "\n"


def save_response(response: FrequencyResponse, directory: str | Path) -> None:
    """Write ``directory/response.csv`` and ``directory/response.json`` atomically (creates the directory), the
    sidecar with the checksums of the rows and of the samples files present."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    style = style_of_config(response.config)
    rows = [_point_row(point, style) for point in response.points]
    sidecar = json.loads(_sidecar_text(response.case, response.config))
    sidecar[CHECKSUMS] = {"rows": [_digest(row.encode()) for row in rows],
                          "samples": _samples_digests(directory, {p.frequency_hz for p in response.points})}
    atomic_write_text(directory / SIDECAR_NAME, json.dumps(sidecar, indent=2) + "\n")
    _write_csv(directory, style, rows)


CHECKSUMS = "checksums"
"""The sidecar's key holding a SHA-256 of every row of response.csv, in order (``rows``), and of every samples file
(``samples``, by file name), recorded as each is written: what was edited, added or deleted afterwards shows."""


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _samples_digests(directory: Path, frequencies: set[float] | list[float]) -> dict[str, str]:
    """The SHA-256 of each samples file of ``frequencies`` present in ``directory``, by file name."""
    from bodebench.io.samples import SAMPLES_DIR, samples_path  # samples imports this module

    out: dict[str, str] = {}
    if not (directory / SAMPLES_DIR).is_dir():
        return out
    for f in sorted(frequencies):
        path = samples_path(directory, f)
        if path.is_file():
            out[path.name] = _digest(path.read_bytes())
    return out


def verify_results(directory: str | Path) -> tuple[bool, list[str]]:
    """Check a results directory against the checksums its sidecar recorded as it was written: (whether it had
    checksums to check, one line for each row or samples file changed, missing or added since). A row after the last
    one recorded, of the frequency written last, is the append a stopped run left without its checksum: not a
    problem. ResultsError when the directory's files cannot be read."""
    directory = Path(directory)
    data = read_json_file(directory / SIDECAR_NAME, ResultsError, "sidecar file")
    sums = data.get(CHECKSUMS) if isinstance(data, dict) else None
    if not isinstance(sums, dict) or not isinstance(sums.get("rows"), list):
        return False, []
    path = directory / CSV_NAME
    try:
        lines = path.read_text(encoding="utf-8").split("\n")
    except (OSError, UnicodeDecodeError) as exc:
        raise ResultsError(f"{path}: cannot read results file: {exc}") from None
    h = _header_index(lines)
    delimiter = style_of_header(lines[h] if h < len(lines) else "").delimiter
    rows = [line for line in lines[h + 1:] if line]
    recorded = sums["rows"]
    problems = []

    def where(i: int) -> str:
        cells = rows[i].split(delimiter)
        return f"{path.name} line {h + 2 + i} ({' '.join(cells[:3])})"

    for i, row in enumerate(rows[: len(recorded)]):
        if _digest(row.encode()) != recorded[i]:
            problems.append(f"{where(i)}: changed since it was written")
    if len(rows) < len(recorded):
        problems.append(f"{path.name}: {len(recorded) - len(rows)} of the {len(recorded)} rows written are gone")
    extra = rows[len(recorded):]
    if extra:
        last = {row.split(delimiter)[0] for row in extra}
        before = rows[len(recorded) - 1].split(delimiter)[0] if recorded and len(rows) >= len(recorded) else None
        if len(last) > 1 or (before is not None and before in last):
            problems += [f"{where(i)}: added since the rows were written" for i in range(len(recorded), len(rows))]
    samples = sums.get("samples")
    if not isinstance(samples, dict):
        samples = {}
    from bodebench.io.samples import SAMPLES_DIR

    for name, digest in sorted(samples.items()):
        file = directory / SAMPLES_DIR / name
        if not file.is_file():
            problems.append(f"{SAMPLES_DIR}/{name}: gone since it was written")
        elif _digest(file.read_bytes()) != digest:
            problems.append(f"{SAMPLES_DIR}/{name}: changed since it was written")
    return True, problems


def update_sidecar(directory: str | Path, values: Mapping[str, Any]) -> None:
    """Add (or replace) keys of ``directory``'s sidecar atomically, e.g. ``summary`` (the figures read off the
    response) and ``runs`` (the record of each run), written when a case is finished."""
    path = Path(directory) / SIDECAR_NAME
    data = read_json_file(path, ResultsError, "sidecar file")
    if not isinstance(data, dict):
        raise ResultsError(f"{path}: sidecar must hold a JSON object, got {type(data).__name__}")
    data.update(values)
    atomic_write_text(path, json.dumps(data, indent=2, allow_nan=False) + "\n")


def write_summary(directory: str | Path, summary: list[dict[str, Any]]) -> None:
    """The ``summary`` key of the sidecar (:func:`bodebench.core.summary.summarize_response`, as JSON)."""
    update_sidecar(directory, {"summary": summary})


def sidecar_runs(directory: str | Path) -> list[dict[str, Any]]:
    """The ``runs`` records of ``directory``'s sidecar ([] when there is no sidecar or no such key)."""
    path = Path(directory) / SIDECAR_NAME
    try:
        data = read_json_file(path, ResultsError, "sidecar file")
    except ResultsError:
        return []
    runs = data.get("runs") if isinstance(data, dict) else None
    return [r for r in runs if isinstance(r, dict)] if isinstance(runs, list) else []


def load_response(directory: str | Path, *, drop_torn_row: bool = False) -> FrequencyResponse:
    """Read the response in ``directory``; raises ResultsError for missing, malformed or tampered files.

    drop_torn_row: leave out a last row cut short by an interrupted append (as a resumed sweep does, which
    measures its frequency again) instead of refusing the file."""
    directory = Path(directory)
    case, config = _parse_sidecar(directory / SIDECAR_NAME)
    points = _parse_csv(directory / CSV_NAME, drop_torn_row)
    return FrequencyResponse(points, config=config, case=case)


class ResultsWriter:
    """Appends the points of a sweep to ``directory/response.csv`` as they are measured.

    Opening writes the sidecar (atomically) and, for a new file, the header; ``resume=True`` continues an existing
    file instead (an unterminated last row, left by a crash mid-append, is cut off first; a file of an older
    format is rewritten in the current one, its new columns NaN). Each :meth:`append`
    writes whole rows and syncs the file before it returns.
    """

    def __init__(self, directory: str | Path, case: str, config: Mapping[str, Any], *, resume: bool = False) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.path = self.directory / CSV_NAME
        self.style = style_of_config(config)
        self._sidecar = json.loads(_sidecar_text(case, config))
        atomic_write_text(self.directory / SIDECAR_NAME, json.dumps(self._sidecar, indent=2) + "\n")
        if resume and self.path.exists():
            _end_last_row(self.path)
            with open(self.path, encoding="utf-8") as handle:
                first = handle.readline()
                header = first
                while header.startswith("#"):
                    header = handle.readline()
            if _columns_of(header.rstrip("\n")) != CSV_COLUMNS or first.startswith("#") \
                    or not (self.directory / CSV_METADATA_NAME).exists():
                points = _parse_csv(self.path)  # an older format: its rows rewritten in the current one
                _write_csv(self.directory, self.style, [_point_row(p, self.style) for p in points])
        else:
            _write_csv(self.directory, self.style, [])
        # the checksums of what is on disk now (a resumed file was checked against its own before it was continued)
        lines = self.path.read_text(encoding="utf-8").split("\n")
        rows = [line for line in lines[_header_index(lines) + 1:] if line]
        self._rows = [_digest(row.encode()) for row in rows]
        frequencies = {float(row.split(self.style.delimiter)[0].replace(",", ".")) for row in rows}
        self._samples = _samples_digests(self.directory, frequencies)
        self._record()

    def _record(self) -> None:
        """The checksums into the sidecar (its other keys as they are on disk)."""
        update_sidecar(self.directory, {CHECKSUMS: {"rows": self._rows, "samples": self._samples}})

    def append(self, points: list[ResponsePoint] | tuple[ResponsePoint, ...]) -> None:
        """Append ``points`` (one frequency's, typically) and sync them to disk. A write that fails (a full disk,
        a file size limit) is undone before the error propagates: the file keeps its whole rows only. A stop signal
        waits until the rows are on disk (an interrupt half-way would have undone measured points)."""
        if not points:
            return
        with signals_held():
            rows = [_point_row(point, self.style) for point in points]
            data = "".join(row + "\n" for row in rows).encode("utf-8")
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
            try:
                start = os.lseek(fd, 0, os.SEEK_END)
                try:
                    view = memoryview(data)
                    while view:
                        view = view[os.write(fd, view):]
                    os.fsync(fd)
                except BaseException:
                    os.ftruncate(fd, start)
                    raise
            finally:
                os.close(fd)
            # then their checksums, and those of their samples files (saved before the rows): a stop between the
            # two leaves rows of one frequency after the last checksum, which verify_results takes as that
            self._rows += [_digest(row.encode()) for row in rows]
            self._samples.update(_samples_digests(self.directory, {p.frequency_hz for p in points}))
            try:
                self._record()
            except OSError as exc:
                raise RowsOnDiskError(exc.errno, f"{exc.strerror or exc} (the rows are on disk; their checksums "
                                                 "could not be recorded in the sidecar)") from None


class RowsOnDiskError(OSError):
    """An append whose rows are on disk, synced, but whose checksums could not be written to the sidecar (a full
    disk, a file size limit): the points are kept, and a resumed sweep takes those rows as the last append."""


def _end_last_row(path: Path) -> None:
    """Make appends start on a fresh line: a last row without its newline is ended if it is whole, cut off if it
    is the remains of an interrupted append."""
    with open(path, "rb+") as handle:
        data = handle.read()
        if not data or data.endswith(b"\n"):
            return
        start = data.rfind(b"\n") + 1
        header = next((line for line in data.split(b"\n") if not line.startswith(b"#")), b"").decode(
            "utf-8", "replace")
        lineno = data.count(b"\n") + 1
        if start and not _torn(path, lineno, data[start:].decode("utf-8", "replace"), header):
            handle.write(b"\n")
        else:
            handle.truncate(start)
        handle.flush()
        os.fsync(handle.fileno())
