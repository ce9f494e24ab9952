"""The terminal UI's building blocks: braille plots, the cell formats and colours the panels share, the abort
label and the footer."""

from __future__ import annotations

import math
from collections.abc import Sequence

from rich.text import Text
from textual.app import ComposeResult
from textual.strip import Strip
from textual.widget import Widget
from textual.widgets import Footer, Static
from textual.widgets._footer import FooterKey

from bodebench.apps.tui.braille import Axis, HLine, PlotError, Trace, render_plot
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
)

#: trace colours, in order of use
PALETTE = ("cyan", "yellow", "magenta", "green", "bright_blue", "bright_red", "white", "bright_green")

STATE_STYLES = {PENDING: "bright_black", SETTLING: "yellow", INTEGRATING: "bold cyan", CONVERGED: "green",
                CAPPED: "magenta", NOISE_LIMITED: "yellow", DISTURBED: "yellow", ALIASED: "yellow",
                DIVISOR_NOISY: "yellow", UNTIED: "yellow", FAILED: "bold red",
                SKIPPED: "bright_black"}


def number_cell(value: float, fmt: str) -> str:
    """``value`` formatted with ``fmt``; ``--`` when it is not finite."""
    return format(value, fmt) if math.isfinite(value) else "--"


def percent_cell(ratio: float) -> str:
    """A ratio as a percentage in at most 5 cells: ``--`` (not stated), ``<0.01``, or 3 significant digits."""
    if not math.isfinite(ratio):
        return "--"
    value = 100.0 * ratio
    return "<0.01" if value < 0.01 else f"{value:.3g}"


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


class AbortLabel(Static):
    """The always-visible abort control (clicking it aborts too); dimmed while no sweep runs."""

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
            if isinstance(widget, FooterKey) and widget.action in ("abort", "app.abort"):
                widget.add_class("-abort")
            yield widget
