"""The live view: the point being measured, its convergence against the tolerance, and a scope of its last periods."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import Static

from bodebench.apps.tui.braille import Axis, HLine, Trace, auto_axis
from bodebench.apps.tui.model import SeriesTrace, SweepModel
from bodebench.apps.tui.widgets import PALETTE, PlotView, number_cell
from bodebench.bench.events import PointProgress


class LivePanel(Vertical):
    """The current point: rule and per-series figures, relative error per period against the tolerance
    (log scale), and a scope of the last periods of setpoint and feedback.

    ``stale`` says the point's figures changed since they were last drawn (:meth:`redraw`).
    """

    DEFAULT_CSS = """
    LivePanel { height: 1fr; }
    LivePanel #live-stats { height: auto; max-height: 5; }
    LivePanel #convergence { min-height: 6; }
    LivePanel #scope { min-height: 5; }
    """

    def __init__(self, *, id: str | None = None, classes: str | None = None) -> None:
        super().__init__(id=id, classes=classes)
        self.stale = False
        self._stats_lines = -1
        self._scope_index: int | None = None  # the point whose samples the scope shows or waits for

    def compose(self) -> ComposeResult:
        yield Static("no point measured yet", id="live-stats")
        yield PlotView("relative error %", "waiting for the first periods", id="convergence")
        yield PlotView("scope", "no samples yet", id="scope")

    def redraw(self, model: SweepModel, latest: PointProgress | None, output: str) -> None:
        """Draw the current point of ``model``; ``latest``: the latest progress of the session (its scope samples,
        of the channel ``output``)."""
        self.stale = False
        f = model.frequencies_hz[model.current] if model.current is not None else None
        to_go = [model.series_to_go(t.channel, t.harmonic) for t in model.traces]
        gaps = latest.gaps() if latest is not None and latest.index == model.current_index else ""
        self.show_convergence(f, model.periods, model.traces, to_go, model.tolerance_percent, model.criterion, gaps)
        # between points and at the end the latest samples stay, also those of a point that began and ended
        # between two refreshes
        if latest is not None and (model.current_index is None or latest.index == model.current_index):
            self.show_scope(latest.scope, output)
        elif model.current_index is not None and self._scope_index != model.current_index:
            self.show_scope(None, "")  # a new point: its samples are yet to come (at the end the last stays)
        self._scope_index = model.current_index

    def show_convergence(self, frequency_hz: float | None, periods: int, traces: Sequence[SeriesTrace],
                         to_go: Sequence[float | None], tolerance_percent: float, criterion: str,
                         gaps: str = "") -> None:
        """The current point's figures; ``to_go``: per trace, the periods its rule still needs (None: unknown);
        ``gaps``: the periods it discarded for gaps in the feedback and the most allowed ("" for none)."""
        stats = Text()
        if frequency_hz is None:
            stats.append("no point being measured", style="bright_black")
        else:
            stats.append(f"{frequency_hz:g} Hz", style="bold")
            stats.append(f"  period {periods}  rule {criterion or '--'}  tolerance {tolerance_percent:g} %")
            if gaps:
                stats.append(f"  {gaps}", style="yellow")
        plot_traces: list[Trace] = []
        values: list[np.ndarray] = []
        xs: list[np.ndarray] = []
        for i, (tr, left) in enumerate(zip(traces, to_go, strict=True)):
            colour = PALETTE[i % len(PALETTE)]
            rel = tr.rel_error[-1] if tr.rel_error else math.nan
            stats.append("\n● ", style=colour)
            stats.append(f"k={tr.harmonic} {tr.channel}  n {tr.periods[-1] if tr.periods else 0}  "
                         f"u {number_cell(tr.uncertainty, '.3g')}  rel {number_cell(rel, '.3g')} %  "
                         f"to go {'done' if tr.done else ('--' if left is None else f'~{left:.0f}')}")
            if tr.periods:
                x, y = np.array(tr.periods, dtype=float), np.array(tr.rel_error, dtype=float)
                plot_traces.append(Trace(x, y, colour))
                values.append(y)
                xs.append(x)
        stats_view = self.query_one("#live-stats", Static)
        lines = stats.plain.count("\n")
        stats_view.update(stats, layout=lines != self._stats_lines)
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
        """Setpoint and ``output`` of the last periods, each scaled to its peak (None: no samples)."""
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
