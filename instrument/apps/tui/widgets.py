"""Widgets of the terminal UI: braille plots, the live convergence view, the sweep table, the Bode plot, bus health.

Widgets only draw what the app hands them (plain values from :mod:`bodebench.apps.tui.model`); none of them
touches the session.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.strip import Strip
from textual.widget import Widget
from textual.widgets import DataTable, Footer, Static
from textual.widgets._footer import FooterKey

from bodebench.apps.tui.braille import Axis, HLine, PlotError, Trace, auto_axis, render_plot
from bodebench.apps.tui.model import (
    ALIASED,
    CAPPED,
    CONVERGED,
    DISTURBED,
    DIVISOR_NOISY,
    FAILED,
    INTEGRATING,
    NOISE_LIMITED,
    PENDING,
    SETTLING,
    SKIPPED,
    UNTIED,
    Row,
    SeriesTrace,
)
from bodebench.bench.events import Health
from bodebench.core.response import FrequencyResponse
from bodebench.core.summary import ResponseSummary, summarize_response

#: trace colours, in order of use
PALETTE = ("cyan", "yellow", "magenta", "green", "bright_blue", "bright_red", "white", "bright_green")

STATE_STYLES = {PENDING: "bright_black", SETTLING: "yellow", INTEGRATING: "bold cyan", CONVERGED: "green",
                CAPPED: "magenta", NOISE_LIMITED: "yellow", DISTURBED: "yellow", ALIASED: "yellow",
                DIVISOR_NOISY: "yellow", UNTIED: "yellow", FAILED: "bold red",
                SKIPPED: "bright_black"}

#: sweep table columns: (key, label, width in cells); with a cell of padding each side 76 cells, within the
#: sweep panel's 78 at 160 x 48 (no horizontal scroll bar)
COLUMNS = (("f", "f Hz", 7), ("k", "k", 2), ("ch", "channel", 8), ("state", "state", 11), ("gain", "gain dB", 7),
           ("phase", "phase °", 7), ("periods", "periods", 7), ("thd", "THD %", 5), ("coh", "coh", 4))


def _number(value: float, fmt: str) -> str:
    return format(value, fmt) if math.isfinite(value) else "--"


def percent_cell(ratio: float) -> str:
    """A ratio as a percentage in at most 5 cells: ``--`` (not stated), ``<0.01``, or 3 significant digits."""
    if not math.isfinite(ratio):
        return "--"
    value = 100.0 * ratio
    return "<0.01" if value < 0.01 else f"{value:.3g}"


def _si_time(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "--"
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} µs"
    if seconds < 1.0:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.2f} s"


def _rate(value: float) -> str:
    if not math.isfinite(value):
        return "--"
    return f"{value / 1000:.1f}k/s" if value >= 1000 else f"{value:.0f}/s"


class PlotView(Widget):
    """A titled braille plot; ``set_plot`` replaces its content. Drawn line by line from strips cached per size
    and content, so a repaint without new data costs nothing."""

    DEFAULT_CSS = """
    PlotView { height: 1fr; min-height: 4; }
    """

    def __init__(self, title: str = "", empty: str = "no data yet", *, id: str | None = None,
                 classes: str | None = None) -> None:
        super().__init__(id=id, classes=classes)
        self.title = title
        self.empty = empty
        self.legend = Text()
        self.traces: tuple[Trace, ...] = ()
        self.x_axis: Axis | None = None
        self.y_axis: Axis | None = None
        self.hlines: tuple[HLine, ...] = ()
        self._cache: tuple[tuple[int, int], list[Strip]] | None = None

    def set_plot(self, traces: Sequence[Trace], x_axis: Axis | None, y_axis: Axis | None,
                 hlines: Sequence[HLine] = (), legend: Text | None = None) -> None:
        self.traces, self.x_axis, self.y_axis = tuple(traces), x_axis, y_axis
        self.hlines = tuple(hlines)
        self.legend = legend if legend is not None else Text()
        self._cache = None
        self.refresh()

    def clear(self) -> None:
        self.set_plot((), None, None)

    def lines(self, width: int, height: int) -> list[Text]:
        """The plot as ``height`` text lines of at most ``width`` cells: title and legend, then the axes."""
        head = Text(self.title, style="bold")
        if self.legend.plain:
            head.append("  ")
            head.append_text(self.legend)
        head.truncate(max(width, 1))
        lines = [head]
        if not self.traces or self.x_axis is None or self.y_axis is None:
            lines.append(Text(self.empty, style="bright_black"))
        else:
            try:
                lines += render_plot(self.traces, width, max(1, height - 1), self.x_axis, self.y_axis, self.hlines)
            except PlotError as exc:
                lines.append(Text(f"cannot plot: {exc}", style="red"))
        return lines[:height]

    def render_line(self, y: int) -> Strip:
        width, height = self.size.width, self.size.height
        if self._cache is None or self._cache[0] != (width, height):
            console = self.app.console
            strips = [Strip(list(line.render(console)), line.cell_len).adjust_cell_length(width)
                      for line in self.lines(width, height)]
            self._cache = ((width, height), strips)
        strips = self._cache[1]
        return strips[y] if y < len(strips) else Strip.blank(width)


class LivePanel(Vertical):
    """The current point: rule and per-series figures, relative error per period against the tolerance
    (log scale), and a scope of the last periods of setpoint and feedback."""

    DEFAULT_CSS = """
    LivePanel { height: 1fr; }
    LivePanel #live-stats { height: auto; max-height: 5; }
    LivePanel #convergence { min-height: 6; }
    LivePanel #scope { min-height: 5; }
    """

    def compose(self) -> ComposeResult:
        yield Static("no point measured yet", id="live-stats")
        yield PlotView("relative error %", "waiting for the first periods", id="convergence")
        yield PlotView("scope", "no samples yet", id="scope")

    def show_convergence(self, frequency_hz: float | None, periods: int, traces: Sequence[SeriesTrace],
                         to_go: Sequence[float | None], tolerance_percent: float, criterion: str) -> None:
        """The current point's figures; ``to_go``: per trace, the periods its rule still needs (None: unknown)."""
        stats = Text()
        if frequency_hz is None:
            stats.append("no point being measured", style="bright_black")
        else:
            stats.append(f"{frequency_hz:g} Hz", style="bold")
            stats.append(f"  period {periods}  rule {criterion or '--'}  tolerance {tolerance_percent:g} %")
        plot_traces: list[Trace] = []
        values: list[np.ndarray] = []
        xs: list[np.ndarray] = []
        for i, (tr, left) in enumerate(zip(traces, to_go, strict=True)):
            colour = PALETTE[i % len(PALETTE)]
            rel = tr.rel_error[-1] if tr.rel_error else math.nan
            stats.append("\n● ", style=colour)
            stats.append(f"k={tr.harmonic} {tr.channel}  n {tr.periods[-1] if tr.periods else 0}  "
                         f"u {_number(tr.uncertainty, '.3g')}  rel {_number(rel, '.3g')} %  "
                         f"to go {'done' if tr.done else ('--' if left is None else f'~{left:.0f}')}")
            if tr.periods:
                x, y = np.array(tr.periods, dtype=float), np.array(tr.rel_error, dtype=float)
                plot_traces.append(Trace(x, y, colour))
                values.append(y)
                xs.append(x)
        stats_view = self.query_one("#live-stats", Static)
        lines = stats.plain.count("\n")
        stats_view.update(stats, layout=lines != getattr(self, "_stats_lines", -1))
        self._stats_lines = lines
        conv = self.query_one("#convergence", PlotView)
        if not plot_traces:
            conv.clear()
            return
        tol = [tolerance_percent] if math.isfinite(tolerance_percent) and tolerance_percent > 0 else []
        y_axis = auto_axis(values, log=True, include=tol)
        x_max = max(float(np.max(x)) for x in xs)
        x_axis = Axis(0.0, max(x_max, 4.0))
        conv.set_plot(plot_traces, x_axis, y_axis, [HLine(t, "red") for t in tol],
                      Text(f"-- tolerance {tolerance_percent:g} %", style="red") if tol else None)

    def show_scope(self, scope: tuple[np.ndarray, np.ndarray, np.ndarray] | None, output: str) -> None:
        view = self.query_one("#scope", PlotView)
        if scope is None or len(scope[0]) < 2:
            view.clear()
            return
        t, u, y = (np.asarray(a, dtype=float) for a in scope)
        t = t - t[0]
        peaks = [float(np.max(np.abs(a))) if a.size else 0.0 for a in (u, y)]
        traces = [Trace(t, a / p if p > 0 else a, colour)
                  for a, p, colour in ((u, peaks[0], "bright_blue"), (y, peaks[1], "yellow"))]
        legend = Text()
        legend.append(f"setpoint ±{peaks[0]:.3g}", style="bright_blue")
        legend.append("  ")
        legend.append(f"{output} ±{peaks[1]:.3g}", style="yellow")
        legend.append("  (each / its peak; t in s)", style="bright_black")
        view.set_plot(traces, Axis(0.0, max(float(t[-1]), 1e-9)), Axis(-1.1, 1.1), (), legend)


class SweepTable(DataTable):
    """One row per (frequency, harmonic, channel); rows and columns are addressed by key."""

    DEFAULT_CSS = """
    SweepTable { height: 1fr; }
    """

    def on_mount(self) -> None:
        self.cursor_type = "row"
        self.zebra_stripes = True
        for key, label, width in COLUMNS:
            self.add_column(label, key=key, width=width)

    def fill(self, rows: dict[str, Row]) -> None:
        """Replace every row."""
        self.clear()
        for key, row in rows.items():
            self.add_row(*self._cells(row), key=key)

    def update_row(self, key: str, row: Row) -> None:
        for (column, _, _), cell in zip(COLUMNS, self._cells(row), strict=True):
            self.update_cell(key, column, cell)

    @staticmethod
    def _cells(row: Row) -> list[object]:
        style = STATE_STYLES.get(row.state, "")
        return [Text(f"{row.frequency_hz:g}", justify="right"), str(row.harmonic), row.channel,
                Text(row.state, style=style),
                Text(_number(row.gain_db, "+.2f"), justify="right"),
                Text(_number(row.phase_deg, ".1f"), justify="right"),
                Text(str(row.periods) if row.periods else "", justify="right"),
                Text(percent_cell(row.thd), justify="right"),
                Text(_number(row.coherence, ".3f"), justify="right")]

    def selected_key(self) -> str | None:
        """Key of the row under the cursor (None when the table is empty)."""
        if self.row_count == 0:
            return None
        return self.coordinate_to_cell_key(self.cursor_coordinate).row_key.value


class SweepPanel(Vertical):
    """Overall progress above the table of points."""

    DEFAULT_CSS = """
    SweepPanel { height: 1fr; }
    SweepPanel #sweep-progress { height: 1; }
    """

    table: SweepTable | None = None

    def compose(self) -> ComposeResult:
        self.progress = Static("", id="sweep-progress")
        yield self.progress
        yield self.table if self.table is not None else SweepTable(id="sweep-table")


_SHORT_NAMES = {"bandwidth (-3 dB)": "BW", "resonance peak": "peak", "phase -90 deg": "-90°",
                "phase -180 deg": "-180°", "phase margin": "PM", "gain margin": "GM"}


def summary_line(summary: ResponseSummary) -> Text:
    """The figures of one summary on one line: ``BW 9.95 Hz  peak +11.3 dB @ 8.52 Hz  -90° 9.13 Hz  -180° --``
    (``--``: not found in the measured range)."""
    text = Text()
    for figure in summary.figures:
        if text.plain:
            text.append("  ")
        text.append(_SHORT_NAMES.get(figure.name, figure.name) + " ", style="bold")
        if not figure.found:
            text.append("--", style="bright_black")
        elif figure.unit == "Hz":
            text.append(f"{figure.value:.3g} Hz")
        else:
            sign = "+" if figure.name == "resonance peak" else ""
            text.append(f"{figure.value:{sign}.3g} {figure.unit.replace('deg', '°')} @ {figure.at_hz:.3g} Hz")
    return text


class BodePanel(Vertical):
    """Gain (dB) and phase (deg) against log frequency, first harmonic, one colour per response and channel;
    under them the summary figures of the first response (its first channel), read off the points so far."""

    DEFAULT_CSS = """
    BodePanel { height: 1fr; }
    BodePanel #bode-summary { height: 1; }
    """

    def compose(self) -> ComposeResult:
        yield PlotView("gain dB", "no converged points yet", id="bode-gain")
        yield PlotView("phase °", "", id="bode-phase")
        yield Static("", id="bode-summary")

    def show_summary(self, responses: Sequence[tuple[str, FrequencyResponse]]) -> None:
        text = Text()
        for label, response in responses[:1]:
            kind = response.config.get("analysis", {}).get("response") or "system"
            summaries = summarize_response(response, kind)
            if summaries:
                text = summary_line(summaries[0])
                if len(responses) > 1 or len(summaries) > 1:
                    text = Text(f"{label} {summaries[0].channel}: ", style="bold") + text
        self.query_one("#bode-summary", Static).update(text, layout=False)

    def show(self, responses: Sequence[tuple[str, FrequencyResponse]]) -> None:
        gain_traces, phase_traces, legend = [], [], Text()
        freqs, gains, phases = [], [], []
        colour_index = 0
        for label, response in responses:
            first = response.select(harmonic=1)
            for channel in first.channels:
                sel = first.select(channel=channel)
                if not len(sel):
                    continue
                colour = PALETTE[colour_index % len(PALETTE)]
                colour_index += 1
                f, g = sel.frequency_hz, sel.gain_db
                ph = sel.phase_unwrapped_deg()
                gain_traces.append(Trace(f, g, colour))
                phase_traces.append(Trace(f, ph, colour))
                freqs.append(f)
                gains.append(g)
                phases.append(ph)
                if legend.plain:
                    legend.append("  ")
                legend.append(f"● {label}" + (f" {channel}" if len(first.channels) > 1 else ""), style=colour)
        gain_view = self.query_one("#bode-gain", PlotView)
        phase_view = self.query_one("#bode-phase", PlotView)
        self.show_summary(responses)
        if not gain_traces:
            gain_view.clear()
            phase_view.clear()
            return
        x_axis = auto_axis(freqs, log=True)
        gain_view.set_plot(gain_traces, x_axis, auto_axis(gains), (), legend)
        phase_view.set_plot(phase_traces, x_axis, auto_axis(phases))


class BusPanel(Static):
    """Bus health: frame rates, errors, lost samples, watchdog, round trip, pacing."""

    def show(self, where: str, health: Health | None, rates: tuple[float, float], watchdog: str,
             watchdog_s: float) -> None:
        text = Text()

        def line(label: str, value: str, style: str = "") -> None:
            text.append(f"{label:<12}", style="bold")
            text.append(value + "\n", style=style)

        line("link", where or "--")
        if health is None:
            line("frames", "no bus reading yet", "bright_black")
        else:
            bus = health.bus
            line("frames", f"in {_rate(rates[0])}  out {_rate(rates[1])}  (total in {bus.frames_in}, "
                           f"out {bus.frames_out})")
            line("errors", f"{bus.errors}  lost samples {bus.lost_samples}  duplicates {bus.duplicates}  "
                           f"incomplete {bus.incomplete_samples}  time conflicts {health.time_conflicts}"
                           + (f"  rejected {bus.rejected_total} ("
                              + ", ".join(f"{cause} {n}" for cause, n in bus.rejected.items() if n) + ")"
                              if bus.rejected_total else ""),
                 "bold red" if bus.errors or bus.lost_samples else "")
            line("bus state", bus.bus_state + (f"  last error: {bus.last_error}" if bus.last_error else ""))
            line("round trip", _si_time(health.round_trip_s))
            if health.pacing is None:
                line("pacing", "lockstep clock (no pacing)")
            else:
                p = health.pacing
                line("pacing", f"p50 {_si_time(p.p50)}  p99 {_si_time(p.p99)}  max {_si_time(p.max)}  "
                               f"overruns {p.overruns}  ({p.scheduling})", "bold red" if p.overruns else "")
        style = {"TRIPPED": "bold white on red", "armed": "green"}.get(watchdog.split(" ")[0], "bright_black")
        line("watchdog", f"{watchdog}  (trips after {watchdog_s:g} s without feedback)", style)
        self.update(text, layout=False)


def bus_summary(health: Health | None, rates: tuple[float, float]) -> Text:
    """One line of bus health for narrow layouts."""
    if health is None:
        return Text("bus: --", style="bright_black")
    bus = health.bus
    bad = bus.errors or bus.lost_samples
    p99 = "--" if health.pacing is None else _si_time(health.pacing.p99)
    return Text(f"in {_rate(rates[0])} out {_rate(rates[1])} err {bus.errors} lost {bus.lost_samples} "
                f"rt {_si_time(health.round_trip_s)} p99 {p99}", style="bold red" if bad else "")


class AbortLabel(Static):
    """The always-visible abort control (clicking it aborts too)."""

    DEFAULT_CSS = """
    AbortLabel { width: auto; height: 1; padding: 0 1; background: $error; color: $text; text-style: bold; }
    AbortLabel.-idle { background: $panel; color: $text-muted; text-style: none; }
    """

    async def on_click(self) -> None:
        await self.app.run_action("abort")


class BenchFooter(Footer):
    """The footer with the abort key drawn in red."""

    DEFAULT_CSS = """
    BenchFooter FooterKey.-abort { background: $error; }
    BenchFooter FooterKey.-abort .footer-key--key { background: $error; color: $text; text-style: bold; }
    BenchFooter FooterKey.-abort .footer-key--description { background: $error; color: $text; text-style: bold; }
    """

    def compose(self) -> ComposeResult:
        for widget in super().compose():
            if isinstance(widget, FooterKey) and widget.action == "abort":
                widget.add_class("-abort")
            yield widget
