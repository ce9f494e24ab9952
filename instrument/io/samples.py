"""Raw samples of each measured frequency, kept next to the results so that a sweep can be analysed again.

One compressed numpy file per frequency, ``samples/<frequency_hz>Hz.npz`` in the results directory (the frequency
as Python's ``repr`` of the float, so each name is unique and exact), written atomically before the frequency's
rows are appended to ``response.csv``. Its arrays:

=================  ===============  ===============================================================================
``format``         str              ``"bodebench-samples"``
``version``        int64            1
``source``         str              ``"offline"`` (the simulated plant, step h) or ``"bench"`` (a drive's feedback)
``frequency_hz``   float64          excitation frequency f, Hz
``amplitude``      float64          input amplitude A_i, input units
``t0``             float64          instant at which the excitation sine has phase zero, s
``channels``       str (c,)         the output channels, in column order
``reference``      str              the two-channel mode's reference channel (its column follows the outputs; ``""``:
                                    none)
``t``              float64 (n,)     sample times, s (increasing), exactly as the sampler took them
``y``              float64 (n, m)   the samples: one column per channel, then the reference's; output units
``chunks``         int64 (k,)       the sizes of the successive batches the sampler was fed (they sum to n)
``reference_phase`` float64         the phase the reference's fundamental has on an ideal bench, rad (0 where the
                                    file has none: a two-channel measurement's reference is phase zero)
``untied``         bool             realtime samples of a drive that gave no way to date the sine on its clock (False
                                    where the file has none)
``setpoint_ratios`` complex128 (p,) bench, single-channel: element n - 1 the fundamental of the setpoints as their
                                    frames carried them over periods 1..n, over the sine's, each whole period of the
                                    record (empty where the file has none, or two-channel)
=================  ===============  ===============================================================================

The samples are those the sampler integrated: on a bench, from the end of the amplitude ramp (the last sample
before it, which the first period edge interpolates from, included) to the batch in which the rule stopped.
"""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bodebench.io.results import atomic_write_bytes

__all__ = ["FORMAT", "SAMPLES_DIR", "PointSamples", "SamplesError", "load_samples", "samples_path"]

FORMAT = "bodebench-samples"
VERSION = 1
SAMPLES_DIR = "samples"


class SamplesError(ValueError):
    """A samples file is missing or malformed; the message names the file."""


def samples_path(directory: str | Path, frequency_hz: float) -> Path:
    """Where the samples of ``frequency_hz`` go in the results directory ``directory``."""
    return Path(directory) / SAMPLES_DIR / f"{float(frequency_hz)!r}Hz.npz"


@dataclass
class PointSamples:
    """The samples of one frequency, batch by batch, as the sampler was fed them (see the module docstring)."""

    frequency_hz: float
    amplitude: float
    channels: tuple[str, ...]
    t0: float = 0.0
    reference: str = ""
    source: str = "bench"
    reference_phase: float = 0.0
    untied: bool = False
    batches: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    setpoint_ratios: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.complex128))
    """Bench, single-channel: element n - 1 is the fundamental of the setpoints as their frames carried them over
    periods 1..n after ``t0``, over the sine's (``core.setpoint_rounding``), for every whole period of the record;
    empty where the points were not taken against it (a reference channel, the offline experiment)."""

    def add(self, t: np.ndarray, y: np.ndarray) -> None:
        """One batch: times ``t`` (s, shape (n,)) and samples ``y`` (shape (n, columns)); copied."""
        self.batches.append((np.array(t, dtype=np.float64), np.array(y, dtype=np.float64).reshape(len(t), -1)))

    @property
    def columns(self) -> int:
        return len(self.channels) + bool(self.reference)

    @property
    def t(self) -> np.ndarray:
        """Every sample time, s."""
        return np.concatenate([b[0] for b in self.batches]) if self.batches else np.zeros(0)

    @property
    def y(self) -> np.ndarray:
        """Every sample, shape (n, columns)."""
        return np.vstack([b[1] for b in self.batches]) if self.batches else np.zeros((0, self.columns))

    def save(self, directory: str | Path) -> Path:
        """Write ``samples/<f>Hz.npz`` in the results directory atomically (a synced temporary file renamed over
        any earlier one); returns its path. OSError when the file system refuses it."""
        path = samples_path(directory, self.frequency_hz)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {
            "format": np.array(FORMAT), "version": np.int64(VERSION), "source": np.array(self.source),
            "frequency_hz": np.float64(self.frequency_hz), "amplitude": np.float64(self.amplitude),
            "t0": np.float64(self.t0), "channels": np.array(self.channels, dtype=str),
            "reference": np.array(self.reference), "t": self.t, "y": self.y,
            "chunks": np.array([len(b[0]) for b in self.batches], dtype=np.int64),
            "reference_phase": np.float64(self.reference_phase), "untied": np.bool_(self.untied),
            "setpoint_ratios": np.asarray(self.setpoint_ratios, dtype=np.complex128),
        }
        buffer = io.BytesIO()
        # an .npz as numpy.savez_compressed writes it, at deflate level 1: samples are mostly noise-like mantissas,
        # which higher levels compress hardly better, several times slower
        with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
            for name, value in arrays.items():
                with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
        atomic_write_bytes(path, buffer.getvalue())
        return path


def load_samples(path: str | Path) -> PointSamples:
    """Read a samples file; :class:`SamplesError` naming it when it is not one."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except FileNotFoundError:
        raise SamplesError(f"{path}: no such samples file") from None
    except (OSError, ValueError, EOFError) as exc:
        raise SamplesError(f"{path}: not a samples file: {exc}") from None
    need = ("format", "version", "source", "frequency_hz", "amplitude", "t0", "channels", "reference", "t", "y",
            "chunks")
    missing = [name for name in need if name not in arrays]
    if missing:
        raise SamplesError(f"{path}: not a samples file: missing {', '.join(missing)}")
    if str(arrays["format"]) != FORMAT or int(arrays["version"]) != VERSION:
        raise SamplesError(f"{path}: format {str(arrays['format'])!r} version {int(arrays['version'])}, expected "
                           f"{FORMAT!r} version {VERSION}")
    t, y, chunks = arrays["t"], arrays["y"], arrays["chunks"]
    channels = tuple(str(c) for c in arrays["channels"])
    reference = str(arrays["reference"])
    columns = len(channels) + bool(reference)
    if t.ndim != 1 or y.shape != (t.size, columns) or int(chunks.sum()) != t.size or np.any(chunks < 0):
        raise SamplesError(f"{path}: t {t.shape}, y {y.shape} and chunks (sum {int(chunks.sum())}) do not agree "
                           f"with {columns} columns")
    out = PointSamples(float(arrays["frequency_hz"]), float(arrays["amplitude"]), channels, float(arrays["t0"]),
                       reference, str(arrays["source"]), float(arrays.get("reference_phase", 0.0)),
                       bool(arrays.get("untied", False)))
    ratios = arrays.get("setpoint_ratios", np.zeros(0, dtype=np.complex128))
    if ratios.ndim != 1 or not np.issubdtype(ratios.dtype, np.complexfloating):
        raise SamplesError(f"{path}: setpoint_ratios {ratios.dtype} {ratios.shape}: not a complex vector")
    out.setpoint_ratios = ratios.astype(np.complex128)
    if chunks.size:
        edges = np.cumsum(chunks)[:-1]
        for tb, yb in zip(np.split(t, edges), np.split(y, edges), strict=True):
            out.batches.append((tb, yb))
    return out
