"""Plots of measured frequency responses (Bode diagram, periods needed per point).

Figures are drawn with matplotlib's Agg canvas (no pyplot, no GUI) and written as PNG (SVG or PDF on request,
``formats``).
matplotlib is imported inside the functions so that importing this module stays cheap.

What a figure shows is what was measured:

- every harmonic has one colour in every figure (k = 1 the first of :data:`HARMONIC_COLOURS`, and so on); several
  responses or channels in one figure differ by line style and marker;
- a point below the resolution (its 95 % disc holds zero) is not drawn as a value: a downward triangle marks the
  upper end of its gain interval, and it has no phase;
- the 95 % interval of every point is a shaded band around its curve, named in the legend;
- log axes are labelled in plain numbers (1, 2, 5, 10, 20, 50, ...).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bodebench.core.response import PHASE_UNDEFINED_STATUSES, FrequencyResponse
from bodebench.core.summary import CONFIDENCE, ResponseSummary, summarize_response
from bodebench.io.results import PLOT_FIGURES
from bodebench.status import PointStatus

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "DEFAULT_FORMATS",
    "DRAWING_MODULES",
    "FORMATS",
    "check_formats",
    "HARMONIC_COLOURS",
    "bode_figure",
    "harmonic_colour",
    "periods_figure",
    "plot_bode",
    "plot_periods",
    "plot_comparison",
    "plot_levels",
    "levels_figure",
    "write_plots",
]

#: Status of a point whose measurement stopped at the period cap.
_NOT_WITHIN_TOLERANCE = (PointStatus.CAPPED, PointStatus.NOISE_LIMITED, PointStatus.DISTURBED,
                         PointStatus.ALIAS_LIMITED, PointStatus.DIVISOR_LIMITED, PointStatus.UNTIED)

FORMATS = ("png", "svg", "pdf")
"""The file formats the plots can be written in (PNG raster at 120 dpi; SVG and PDF vector)."""

DEFAULT_FORMATS = ("png",)

DRAWING_MODULES = ("matplotlib.backends.backend_agg", "matplotlib.figure", "matplotlib.lines", "matplotlib.patches",
                   "matplotlib.ticker")
"""What drawing a figure imports (the drawing process of ``bodebench simulate`` loads them as it starts, see
bodebench.bench.drawing.drawing_executor)."""


def check_formats(formats: Sequence[str]) -> tuple[str, ...]:
    """``formats`` lower-cased and checked against :data:`FORMATS`; ValueError names an unknown one."""
    out = tuple(f.strip().lower() for f in formats)
    unknown = [f for f in out if f not in FORMATS]
    if unknown or not out:
        raise ValueError(f"plot format {', '.join(unknown) or '(none)'} unknown; choose from {', '.join(FORMATS)}")
    return out

HARMONIC_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2")
"""The colour of harmonic k is entry k - 1 (cycled)."""

_STYLES = ("-", "--", ":", "-.")
_MARKERS = ("o", "s", "^", "D", "v", "P")
_MARKER_SIZE = 4.0
_BAND_ALPHA = 0.25


def harmonic_colour(harmonic: int) -> str:
    """The colour harmonic ``harmonic`` has in every figure."""
    return HARMONIC_COLOURS[(harmonic - 1) % len(HARMONIC_COLOURS)]


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


_WIDTH_IN = 8.0
# A fixed layout (inches): room for five-digit tick labels and the axis label at the left, the frequency axis below,
# the title above. Fixed, the figure is drawn once (a layout engine draws it once more to measure it).
_LEFT_IN, _RIGHT_IN, _BOTTOM_IN, _TOP_IN, _TITLE_IN, _GAP_IN = 0.95, 0.2, 0.55, 0.2, 0.3, 0.25


def _new_figure(rows: int, height_in: float, titled: bool) -> tuple[Figure, Any]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(_WIDTH_IN, height_in))
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    _place_axes(fig, rows, titled)
    return fig, axes


def _place_axes(fig: Figure, rows: int, titled: bool) -> None:
    """The fixed layout: margins and the gap between rows, with room for a title above when ``titled``."""
    width, height = fig.get_size_inches()
    top = _TOP_IN + (_TITLE_IN if titled else 0.0)
    axes_height = (height - top - _BOTTOM_IN - (rows - 1) * _GAP_IN) / rows
    fig.subplots_adjust(left=_LEFT_IN / width, right=1.0 - _RIGHT_IN / width, bottom=_BOTTOM_IN / height,
                        top=1.0 - top / height, hspace=_GAP_IN / axes_height)


def _save(fig: Figure, path_stem: str | Path, formats: Sequence[str] = DEFAULT_FORMATS) -> list[Path]:
    stem = Path(path_stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = [Path(f"{stem}.{suffix}") for suffix in check_formats(formats)]
    for path in paths:
        fig.savefig(path, dpi=120)
    return paths


def _plain_log_axis(axis: Any) -> None:
    """Log-axis ticks at 1, 2 and 5 of every decade, labelled as plain numbers (no 2x10^0); the minor grid comes
    from :func:`_minor_log_grid`."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator

    axis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda value, _pos: f"{value:g}"))
    axis.set_minor_locator(NullLocator())


_MINOR_SUBS = (3.0, 4.0, 6.0, 7.0, 8.0, 9.0)  # the 1 .. 9 of every decade less the major ticks
_MINOR_ALPHA = 0.2


def _minor_log_grid(ax: Any, which: str) -> None:
    """The minor grid of a log axis (``which`` "x" or "y") of ``ax``: a line at 3, 4, 6, 7, 8 and 9 of every decade
    within the axis' final limits, all in one collection (a minor tick each would cost most of the drawing).
    Call once everything is plotted."""
    from matplotlib.collections import LineCollection

    low, high = sorted(ax.get_xlim() if which == "x" else ax.get_ylim())
    if not (low > 0.0 and math.isfinite(high)):
        return
    at = [sub * 10.0 ** decade for decade in range(math.floor(math.log10(low)), math.ceil(math.log10(high)) + 1)
          for sub in _MINOR_SUBS]
    at = [v for v in at if low <= v <= high]
    if which == "x":
        segments, transform = [[(v, 0.0), (v, 1.0)] for v in at], ax.get_xaxis_transform()
    else:
        segments, transform = [[(0.0, v), (1.0, v)] for v in at], ax.get_yaxis_transform()
    grid = ax.xaxis.get_gridlines()[0] if which == "x" else ax.yaxis.get_gridlines()[0]
    ax.add_collection(LineCollection(segments, transform=transform, colors=[grid.get_color()],
                                     linewidths=grid.get_linewidth(), linestyles=grid.get_linestyle(),
                                     alpha=_MINOR_ALPHA, zorder=grid.get_zorder()), autolim=False)


def _series_groups(curves: Mapping[str, FrequencyResponse]) -> list[tuple[str, str]]:
    """(label, channel) pairs in order: each gets its own line style and marker."""
    out: list[tuple[str, str]] = []
    for label, response in curves.items():
        for channel in response.channels:
            out.append((label, channel))
    return out


def _mark_summary(ax_gain: Any, ax_phase: Any, summary: Sequence[ResponseSummary]) -> None:
    """The summary's figures on the Bode plot: each found one a labelled marker, with its 95 % frequency
    interval as a horizontal bar where it has one."""
    for item in summary:
        ref = item.reference_db
        for fig in item.figures:
            if not fig.found:
                continue
            if fig.name.startswith("bandwidth"):
                ax, x, y, text = ax_gain, fig.value, ref - 10.0 * math.log10(2.0), f"BW {fig.value:.3g} Hz"
                span = (fig.low, fig.high)
            elif fig.name.startswith("resonance"):
                ax, x, y, text = ax_gain, fig.at_hz, ref + fig.value, f"peak {fig.value:+.3g} dB"
                span = (fig.at_low_hz, fig.at_high_hz)
            elif fig.name.startswith("phase -"):
                level = float(fig.name.split()[1])
                ax, x, y, text = ax_phase, fig.value, level, f"{level:g} deg at {fig.value:.3g} Hz"
                span = (fig.low, fig.high)
            elif fig.name == "phase margin":
                ax, x, y, text = ax_phase, fig.at_hz, fig.value - 180.0, f"PM {fig.value:.3g} deg"
                span = (fig.at_low_hz, fig.at_high_hz)
            elif fig.name == "gain margin":
                ax, x, y, text = ax_gain, fig.at_hz, -fig.value, f"GM {fig.value:.3g} dB"
                span = (fig.at_low_hz, fig.at_high_hz)
            else:
                continue
            ax.plot([x], [y], marker="D", ms=5.0, mfc="none", mec="k", linestyle="none", zorder=5)
            if all(np.isfinite(span)):
                ax.plot(list(span), [y, y], "-", color="k", lw=1.5, zorder=5)
            ax.annotate(text, (x, y), xytext=(5, 5), textcoords="offset points", fontsize="x-small")


def _gain_bounds(sel: FrequencyResponse) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper ends of each point's 95 % gain interval, dB (lower NaN where the interval holds zero)."""
    width = np.array([p.gain_ci for p in sel.points])
    gain = sel.gain
    width = np.where(np.isfinite(width), width, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        low = np.where(gain > width, 20.0 * np.log10(gain - width), np.nan)
        high = 20.0 * np.log10(gain + width)
    high[~np.isfinite(high)] = np.nan
    return low, high


def plot_bode(
    responses: Mapping[str, FrequencyResponse] | FrequencyResponse,
    path_stem: str | Path,
    title: str = "",
    formats: Sequence[str] = DEFAULT_FORMATS,
    summary: Sequence[ResponseSummary] = (),
) -> list[Path]:
    """The Bode diagram of :func:`bode_figure`, written as ``<path_stem>.<format>`` for each of ``formats``;
    returns the paths."""
    return _save(bode_figure(responses, title, summary), path_stem, formats)


def bode_figure(
    responses: Mapping[str, FrequencyResponse] | FrequencyResponse,
    title: str = "",
    summary: Sequence[ResponseSummary] = (),
) -> Figure:
    """Bode diagram: gain (dB) over phase (degrees, unwrapped per curve) of harmonic 1 against log frequency (Hz),
    and, where harmonics above the first were measured, a third panel of their distortion: each harmonic's
    amplitude relative to harmonic 1's at the same frequency (dB), not a transfer function.

    One curve per (case label, harmonic, channel), coloured by harmonic; hollow markers for points that did not
    converge; the 95 % interval of every point as a band; points below the resolution as the upper end of their
    gain interval (downward triangles), left out of the curves; the figures of ``summary`` marked (diamonds, with
    their 95 % frequency intervals); the excitation amplitude and the tolerance in the legend.
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator

    curves = _as_mapping(responses)
    groups = _series_groups(curves)
    distortion = any(k > 1 for response in curves.values() for k in response.harmonics)
    fig, axes = _new_figure(3 if distortion else 2, 8.5 if distortion else 6.5, titled=bool(title))
    ax_gain, ax_phase = axes[0], axes[1]
    ax_dist = axes[2] if distortion else None
    any_hollow = any_band = any_bound = False
    for case_label, response in curves.items():
        for harmonic in response.harmonics:
            for channel in response.select(harmonic=harmonic).channels:
                sel = response.select(harmonic=harmonic, channel=channel)
                if not len(sel):
                    continue
                group = groups.index((case_label, channel))
                style, marker = _STYLES[group % len(_STYLES)], _MARKERS[group % len(_MARKERS)]
                color = harmonic_colour(harmonic)
                freq = sel.frequency_hz
                unresolved = np.array([p.status in PHASE_UNDEFINED_STATUSES for p in sel.points])
                filled = sel.converged & ~unresolved
                low, high = _gain_bounds(sel)
                gain_db = sel.gain_db.copy()
                label = _label(case_label if len(curves) > 1 else "", f"k={harmonic}",
                               channel if len(response.channels) > 1 or len(curves) > 1 else "")
                if harmonic == 1:
                    panels = [(ax_gain, gain_db), (ax_phase, sel.phase_unwrapped_deg())]
                else:
                    assert ax_dist is not None
                    # relative to harmonic 1 of the same channel at the same frequency (dB)
                    first = {p.frequency_hz: p.gain_db for p in response.select(harmonic=1, channel=channel).points}
                    base = np.array([first.get(float(fr), np.nan) for fr in freq])
                    gain_db, low, high = gain_db - base, low - base, high - base
                    panels = [(ax_dist, gain_db)]
                gain_db[unresolved | ~np.isfinite(gain_db)] = np.nan
                for ax, y in panels:
                    y[unresolved] = np.nan
                    ax.plot(freq, y, style, lw=1.0, color=color, label=label)
                    ax.plot(freq[filled], y[filled], marker, ms=_MARKER_SIZE, color=color, linestyle="none")
                    ax.plot(freq[~filled], y[~filled], marker, ms=_MARKER_SIZE, mfc="none", mec=color,
                            linestyle="none")
                any_hollow |= bool((~filled & ~unresolved).any())
                ax_level = panels[0][0]
                band_low = np.where(unresolved, np.nan, np.where(np.isfinite(low), low, np.nanmin(
                    np.concatenate([low[np.isfinite(low)], gain_db[np.isfinite(gain_db)], [0.0]])) - 20.0))
                band_high = np.where(unresolved, np.nan, high)
                if np.isfinite(band_high).any():
                    ax_level.fill_between(freq, band_low, band_high, color=color, alpha=_BAND_ALPHA, lw=0)
                    any_band = True
                if harmonic == 1:
                    phase = panels[1][1]
                    ci = sel.phase_ci_deg
                    ci = np.where(np.isfinite(ci), ci, np.nan)
                    if np.isfinite(phase + ci).any():
                        ax_phase.fill_between(freq, phase - ci, phase + ci, color=color, alpha=_BAND_ALPHA, lw=0)
                if unresolved.any():
                    any_bound = True
                    bound = np.where(np.isfinite(high), high, np.nan)[unresolved]
                    ax_level.plot(freq[unresolved], bound, "v", ms=6.0, mfc="none", mec=color, linestyle="none")
    _mark_summary(ax_gain, ax_phase, summary)
    ax_gain.set_xscale("log")
    _plain_log_axis(axes[-1].xaxis)
    ax_gain.set_ylabel("Gain (dB)")
    ax_phase.set_ylabel("Phase (deg)")
    axes[-1].set_xlabel("Frequency (Hz)")
    ax_phase.yaxis.set_major_locator(MaxNLocator(nbins=8, steps=[1, 1.5, 3, 4.5, 9, 10]))
    if ax_dist is not None:
        ax_dist.set_ylabel("Distortion (dB re k=1)")
    for ax in axes:
        ax.grid(True, which="major", alpha=0.5)
    extras: list[tuple[Any, str]] = []
    if any_band:
        extras.append((Patch(color="0.3", alpha=_BAND_ALPHA, lw=0), f"{CONFIDENCE:.0%} confidence band"))
    if any_hollow:
        extras += [(Line2D([], [], marker="o", color="0.3", linestyle="none", ms=_MARKER_SIZE), "converged"),
                   (Line2D([], [], marker="o", mfc="none", mec="0.3", linestyle="none", ms=_MARKER_SIZE),
                    "not converged")]
    if any_bound:
        extras.append((Line2D([], [], marker="v", mfc="none", mec="0.3", linestyle="none", ms=6.0),
                       "below resolution: upper bound"))
    conditions = _conditions(curves)
    if conditions:
        extras.append((Line2D([], [], linestyle="none"), conditions))
    handles, labels = ax_gain.get_legend_handles_labels()
    ax_gain.legend(handles + [h for h, _ in extras], labels + [text for _, text in extras], fontsize="small")
    if ax_dist is not None:
        ax_dist.legend(fontsize="small")
    if title:
        fig.suptitle(title)
    for ax in axes:
        _minor_log_grid(ax, "x")
    return fig


def _conditions(curves: Mapping[str, FrequencyResponse]) -> str:
    """The excitation amplitude (harmonic-1 points, input units) and the tolerance the curves were measured with,
    in words; empty where the curves differ in them."""
    amplitudes = sorted({p.amplitude for r in curves.values() for p in r.select(harmonic=1).points})
    tolerances = {(r.config.get("analysis") or {}).get("tolerance_percent") for r in curves.values()}
    parts = []
    if amplitudes:
        shown = f"{amplitudes[0]:.4g}" if len(amplitudes) == 1 else f"{amplitudes[0]:.4g} to {amplitudes[-1]:.4g}"
        parts.append(f"amplitude {shown}")
    if len(tolerances) == 1 and isinstance(tol := next(iter(tolerances)), (int, float)):
        parts.append(f"tolerance {tol:g} %")
    return ", ".join(parts)


def plot_periods(
    responses: Mapping[str, FrequencyResponse] | FrequencyResponse,
    path_stem: str | Path,
    title: str = "",
    formats: Sequence[str] = DEFAULT_FORMATS,
) -> list[Path]:
    """The chart of :func:`periods_figure`, written as ``<path_stem>.<format>`` for each of ``formats``; returns
    the paths."""
    return _save(periods_figure(responses, title), path_stem, formats)


def periods_figure(responses: Mapping[str, FrequencyResponse] | FrequencyResponse, title: str = "") -> Figure:
    """Periods integrated per point against log frequency (Hz), log y axis; one curve per (case label, harmonic),
    coloured by harmonic as in the Bode plot.

    Where several channels share a frequency the largest period count is shown. Points with status ``capped``
    or ``noise_limited`` are marked with a cross.
    """
    from matplotlib.lines import Line2D

    curves = _as_mapping(responses)
    fig, (ax,) = _new_figure(1, 4.5, titled=bool(title))
    any_capped = False
    for index, (case_label, response) in enumerate(curves.items()):
        style, marker = _STYLES[index % len(_STYLES)], _MARKERS[index % len(_MARKERS)]
        for harmonic in response.harmonics:
            sel = response.select(harmonic=harmonic)
            freq_all = sel.frequency_hz
            freq = np.unique(freq_all)
            at = np.searchsorted(freq, freq_all)
            periods = np.zeros(freq.size, dtype=float)
            np.maximum.at(periods, at, sel.periods.astype(float))
            capped = np.zeros(freq.size, dtype=bool)
            np.logical_or.at(capped, at, np.array([pt.status in _NOT_WITHIN_TOLERANCE for pt in sel]))
            color = harmonic_colour(harmonic)
            ax.plot(freq, periods, style, marker=marker, ms=_MARKER_SIZE, lw=1.0, color=color,
                    label=_label(case_label if len(curves) > 1 else "", f"k={harmonic}"))
            if capped.any():
                any_capped = True
                ax.plot(freq[capped], periods[capped], "x", ms=9.0, mew=2.0, color=color, linestyle="none")
    ax.set_xscale("log")
    ax.set_yscale("log")
    _plain_log_axis(ax.xaxis)
    _plain_log_axis(ax.yaxis)
    ax.set_xlabel("Frequency (Hz)")
    ax.set_ylabel("Periods")
    ax.grid(True, which="major", alpha=0.5)
    handles, labels = ax.get_legend_handles_labels()
    if any_capped:
        handles.append(Line2D([], [], marker="x", color="0.3", linestyle="none", ms=9.0, mew=2.0))
        labels.append("capped or noise-limited")
    ax.legend(handles, labels, fontsize="small")
    if title:
        ax.set_title(title)
    _minor_log_grid(ax, "x")
    _minor_log_grid(ax, "y")
    return fig


def write_plots(response: FrequencyResponse, directory: Path, title: str,
                formats: Sequence[str] = DEFAULT_FORMATS,
                summary: Sequence[ResponseSummary] | None = None,
                figures: Sequence[str] = PLOT_FIGURES) -> list[Path]:
    """The plots of a finished case in ``directory``, each in ``formats``: of ``figures``, "bode" (the Bode plot
    with the summary's figures marked; ``summary`` None: read off ``response`` as its configuration's
    ``analysis.response`` says) and "periods" (the periods each point took); none for no formats (``--plots
    none``)."""
    unknown = [f for f in figures if f not in PLOT_FIGURES]
    if unknown:
        raise ValueError(f"unknown figure {unknown[0]!r}; one of {', '.join(PLOT_FIGURES)}")
    files: list[Path] = []
    if not formats:
        return files
    if "bode" in figures:
        if summary is None:
            kind = response.config.get("analysis", {}).get("response") or "system"
            summary = summarize_response(response, kind)
        files += plot_bode(response, directory / "bode", title, formats, summary)
    if "periods" in figures:
        files += plot_periods(response, directory / "periods", title, formats)
    return files


def plot_levels(frequency_hz: np.ndarray, output: np.ndarray, distortion: np.ndarray, noise: np.ndarray,
                path_stem: str | Path, title: str = "", formats: Sequence[str] = DEFAULT_FORMATS) -> list[Path]:
    """The chart of :func:`levels_figure`, written as ``<path_stem>.<format>`` for each of ``formats``; returns
    the paths."""
    return _save(levels_figure(frequency_hz, output, distortion, noise, title), path_stem, formats)


def levels_figure(frequency_hz: np.ndarray, output: np.ndarray, distortion: np.ndarray, noise: np.ndarray,
                  title: str = "") -> Figure:
    """An overview's levels against log frequency (Hz), dB of output units: the output at each excited line, the
    distortion at its detection lines and the noise that distortion is read against. Where the distortion marks
    sit on the noise line, the plant looks linear at that frequency; where they stand above it, they show its
    nonlinear distortion."""
    fig, (ax,) = _new_figure(1, 4.5, titled=bool(title))

    def db(values: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            out = 20.0 * np.log10(np.asarray(values, dtype=float))
        out[~np.isfinite(out)] = np.nan
        return out

    ax.plot(frequency_hz, db(output), "o", ms=_MARKER_SIZE, color=HARMONIC_COLOURS[0], linestyle="none",
            label="output at the excited line")
    ax.plot(frequency_hz, db(distortion), "x", ms=6.0, color=HARMONIC_COLOURS[1], linestyle="none",
            label="distortion at its detection lines")
    ax.plot(frequency_hz, db(noise), "-", lw=1.0, color="0.4", label="noise (standard error of those lines)")
    ax.set_xscale("log")
    _plain_log_axis(ax.xaxis)
    ax.set_xlabel("Frequency (Hz)")
    ax.set_ylabel("Level (dB of output units)")
    ax.grid(True, which="major", alpha=0.5)
    ax.legend(fontsize="small")
    if title:
        ax.set_title(title)
    _minor_log_grid(ax, "x")
    return fig


def plot_comparison(responses: Mapping[str, FrequencyResponse], path: str | Path, title: str = "") -> Path:
    """One Bode diagram of several responses (labels: where they came from), written to ``path`` in the format
    its suffix names (png, svg, pdf, ...); returns the path."""
    target = Path(path)
    suffix = target.suffix.lstrip(".").lower()
    if not suffix:
        raise ValueError(f"{target}: no file suffix to take the image format from (e.g. .png or .svg)")
    summaries = [s for response in responses.values()
                 for s in summarize_response(response, response.config.get("analysis", {}).get("response")
                                             or "system")] if len(responses) == 1 else []
    try:
        formats = check_formats((suffix,))
    except ValueError as exc:
        raise ValueError(f"{target}: {exc}") from None
    return _save(bode_figure(responses, title, summaries), target.with_suffix(""), formats)[0]
