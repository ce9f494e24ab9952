"""Plots of measured frequency responses (Bode diagram, periods needed per point).

Figures are drawn with matplotlib's Agg canvas (no pyplot, no GUI) and written as PNG (SVG or PDF on request).
matplotlib is imported inside the functions so that importing this module stays cheap.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bodebench.core.response import FrequencyResponse
from bodebench.status import PointStatus

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["DEFAULT_FORMATS", "FORMATS", "check_formats", "plot_bode", "plot_periods", "write_plots"]

#: Status of a point whose measurement stopped at the period cap.
_NOT_WITHIN_TOLERANCE = (PointStatus.CAPPED, PointStatus.NOISE_LIMITED)

_MARKER = "o"
_MARKER_SIZE = 4.0


def _as_mapping(responses: Mapping[str, FrequencyResponse] | FrequencyResponse) -> dict[str, FrequencyResponse]:
    if isinstance(responses, FrequencyResponse):
        responses = {responses.case: responses}
    if not isinstance(responses, Mapping):
        raise ValueError(
            f"responses must be a FrequencyResponse or a mapping of labels to them, got {type(responses).__name__}"
        )
    out: dict[str, FrequencyResponse] = {}
    for label, response in responses.items():
        if not isinstance(response, FrequencyResponse):
            raise ValueError(f"responses[{label!r}] is a {type(response).__name__}, not a FrequencyResponse")
        out[str(label)] = response
    if not any(len(response) for response in out.values()):
        raise ValueError("nothing to plot: the responses hold no points")
    return out


def _label(*parts: str) -> str:
    return " ".join(part for part in parts if part)


def _new_figure(rows: int, height_in: float) -> tuple[Figure, Any]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, axes


FORMATS = ("png", "svg", "pdf")
"""The file formats the plots can be written in (PNG raster at 120 dpi; SVG and PDF vector)."""

DEFAULT_FORMATS = ("png",)


def check_formats(formats: Sequence[str]) -> tuple[str, ...]:
    """``formats`` lower-cased and checked against :data:`FORMATS`; ValueError names an unknown one."""
    out = tuple(f.strip().lower() for f in formats)
    unknown = [f for f in out if f not in FORMATS]
    if unknown or not out:
        raise ValueError(f"plot format {', '.join(unknown) or '(none)'} unknown; choose from {', '.join(FORMATS)}")
    return out


def _save(fig: Figure, path_stem: str | Path, formats: Sequence[str]) -> list[Path]:
    stem = Path(path_stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = [Path(f"{stem}.{fmt}") for fmt in check_formats(formats)]
    for path in paths:
        fig.savefig(path, dpi=120)
    return paths


def _finite_or_nan(values: np.ndarray) -> np.ndarray:
    out = np.asarray(values, dtype=float).copy()
    out[~np.isfinite(out)] = np.nan
    return out


def _draw_series(
    ax: Any, freq: np.ndarray, y: np.ndarray, ci: np.ndarray, filled: np.ndarray, color: Any
) -> None:
    """Markers (filled where ``filled``, hollow elsewhere) and error bars where ``ci`` is finite."""
    ax.plot(freq[filled], y[filled], _MARKER, ms=_MARKER_SIZE, color=color, linestyle="none")
    ax.plot(
        freq[~filled], y[~filled], _MARKER, ms=_MARKER_SIZE, mfc="none", mec=color, linestyle="none"
    )
    bars = np.isfinite(ci) & np.isfinite(y)
    if bars.any():
        ax.errorbar(freq[bars], y[bars], yerr=ci[bars], fmt="none", ecolor=color, elinewidth=0.8, capsize=2.0)


def plot_bode(
    responses: Mapping[str, FrequencyResponse] | FrequencyResponse,
    path_stem: str | Path,
    title: str = "",
    formats: Sequence[str] = DEFAULT_FORMATS,
) -> list[Path]:
    """Bode diagram: gain (dB) over phase (degrees, unwrapped per curve) against log frequency (Hz).

    One curve per (case label, harmonic, channel); hollow markers for points that did not converge; error bars
    from ``gain_db_ci`` and ``phase_ci_deg`` where finite. Writes ``<path_stem>.<format>`` for each of
    ``formats``
    and returns both paths.
    """
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    curves = _as_mapping(responses)
    fig, (ax_gain, ax_phase) = _new_figure(2, 6.5)
    any_hollow = False
    for case_label, response in curves.items():
        for harmonic in response.harmonics:
            for channel in response.select(harmonic=harmonic).channels:
                sel = response.select(harmonic=harmonic, channel=channel)
                freq = sel.frequency_hz
                filled = sel.converged
                any_hollow |= bool((~filled).any())
                gain_db = _finite_or_nan(sel.gain_db)
                phase = sel.phase_unwrapped_deg()
                (line,) = ax_gain.plot(
                    freq, gain_db, "-", lw=1.0, label=_label(case_label, f"k={harmonic}", channel)
                )
                color = line.get_color()
                ax_phase.plot(freq, phase, "-", lw=1.0, color=color)
                _draw_series(ax_gain, freq, gain_db, sel.gain_db_ci, filled, color)
                _draw_series(ax_phase, freq, phase, sel.phase_ci_deg, filled, color)
    ax_gain.set_xscale("log")
    ax_gain.set_ylabel("Gain (dB)")
    ax_phase.set_ylabel("Phase (deg)")
    ax_phase.set_xlabel("Frequency (Hz)")
    ax_phase.yaxis.set_major_locator(MaxNLocator(nbins=8, steps=[1, 1.5, 3, 4.5, 9, 10]))
    for ax in (ax_gain, ax_phase):
        ax.grid(True, which="major", alpha=0.5)
        ax.grid(True, which="minor", alpha=0.2)
    handles, labels = ax_gain.get_legend_handles_labels()
    if any_hollow:
        handles += [
            Line2D([], [], marker=_MARKER, color="0.3", linestyle="none", ms=_MARKER_SIZE),
            Line2D([], [], marker=_MARKER, mfc="none", mec="0.3", linestyle="none", ms=_MARKER_SIZE),
        ]
        labels += ["converged", "not converged"]
    ax_gain.legend(handles, labels, fontsize="small")
    if title:
        fig.suptitle(title)
    return _save(fig, path_stem, formats)


def plot_periods(
    responses: Mapping[str, FrequencyResponse] | FrequencyResponse,
    path_stem: str | Path,
    title: str = "",
    formats: Sequence[str] = DEFAULT_FORMATS,
) -> list[Path]:
    """Periods integrated per point against log frequency (Hz), log y axis; one curve per (case label, harmonic).

    Where several channels share a frequency the largest period count is shown. Points with status ``capped``
    or ``noise_limited`` are marked with a cross. Writes ``<path_stem>.<format>`` for each of
    ``formats`` and returns
    both paths.
    """
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter

    curves = _as_mapping(responses)
    fig, (ax,) = _new_figure(1, 4.5)
    any_capped = False
    for case_label, response in curves.items():
        for harmonic in response.harmonics:
            sel = response.select(harmonic=harmonic)
            freq_all = sel.frequency_hz
            freq = np.unique(freq_all)
            index = np.searchsorted(freq, freq_all)
            periods = np.zeros(freq.size, dtype=float)
            np.maximum.at(periods, index, sel.periods.astype(float))
            capped = np.zeros(freq.size, dtype=bool)
            np.logical_or.at(capped, index, np.array([pt.status in _NOT_WITHIN_TOLERANCE for pt in sel]))
            (line,) = ax.plot(
                freq, periods, "-", marker=_MARKER, ms=_MARKER_SIZE, lw=1.0, label=_label(case_label, f"k={harmonic}")
            )
            if capped.any():
                any_capped = True
                ax.plot(freq[capped], periods[capped], "x", ms=9.0, mew=2.0, color=line.get_color(), linestyle="none")
    ax.set_xscale("log")
    ax.set_yscale("log")
    plain = FuncFormatter(lambda value, _pos: f"{value:g}")
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(plain)
    ax.set_xlabel("Frequency (Hz)")
    ax.set_ylabel("Periods")
    ax.grid(True, which="major", alpha=0.5)
    ax.grid(True, which="minor", alpha=0.2)
    handles, labels = ax.get_legend_handles_labels()
    if any_capped:
        handles.append(Line2D([], [], marker="x", color="0.3", linestyle="none", ms=9.0, mew=2.0))
        labels.append("capped or noise-limited")
    ax.legend(handles, labels, fontsize="small")
    if title:
        ax.set_title(title)
    return _save(fig, path_stem, formats)


def write_plots(response: FrequencyResponse, directory: Path, title: str,
                formats: Sequence[str] = DEFAULT_FORMATS) -> list[Path]:
    """The plots of a finished case in ``directory``: the Bode plot and the periods each point took, in each of
    ``formats``."""
    return (plot_bode(response, directory / "bode", title, formats)
            + plot_periods(response, directory / "periods", title, formats))
