"""The two lines above the panels: the sweep's status (with the abort label) and the view bar."""

from __future__ import annotations

from collections.abc import Sequence

from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Horizontal
from textual.widgets import Static

from bodebench.apps.tui.model import SweepModel, format_duration
from bodebench.apps.tui.widgets import AbortLabel
from bodebench.bench.events import OverviewProgress

#: the style of each state's label (others: bold)
STATE_COLOURS = {"running": "bold green", "paused": "bold yellow", "aborting": "bold red", "aborted": "bold red",
                 "failed": "bold red", "done": "bold green", "starting": "bold yellow"}

#: cells of the progress bar
BAR_WIDTH = 10


class StatusLine(Horizontal):
    """The sweep's state, its case, a progress bar, the elapsed time, the time to finish, the tolerance and, while
    the overview an adaptive plan runs first is running, its periods; the abort label at the right.

    ``state`` is the sweep's: idle, loaded (results read from disk), starting, running, paused, aborting, aborted,
    failed or done.
    """

    DEFAULT_CSS = """
    StatusLine { height: 1; }
    StatusLine #status-text { width: 1fr; height: 1; }
    """

    def __init__(self, *, id: str | None = None) -> None:
        super().__init__(id=id)
        self.state = "idle"
        self.overview_periods: int | None = None  # periods of the overview an adaptive plan runs first, while it runs
        self.text_view = Static("", id="status-text")
        self.abort_label = AbortLabel(" ABORT  a ", id="abort-label", classes="-idle")
        self._shown = Text()

    def compose(self) -> ComposeResult:
        yield self.text_view
        yield self.abort_label

    def apply(self, event: object) -> None:
        """Follow a session event: the overview's periods are shown while its progress comes, until the next
        event of another kind."""
        self.overview_periods = event.periods if isinstance(event, OverviewProgress) else None

    def show(self, case_name: str, model: SweepModel, tolerance_percent: float, running: bool, now: float) -> bool:
        """Draw the line for the sweep of ``model`` at ``now`` (monotonic s); True when its text changed."""
        text = Text()
        text.append(f" {self.state.upper()} ", style=f"reverse {STATE_COLOURS.get(self.state, 'bold')}")
        text.append(f" {case_name}")
        done, total = model.done, model.total
        filled = round(BAR_WIDTH * done / total) if total else 0
        text.append(f"  {done}/{total} ")
        text.append("█" * filled, style="green")
        text.append("░" * (BAR_WIDTH - filled), style="bright_black")
        text.append(f" {format_duration(model.elapsed(now))}")
        text.append(f" ETA {format_duration(model.eta(now))}")
        text.append(f"  tol {tolerance_percent:g} %")
        if self.overview_periods is not None:
            text.append(f"  overview first: {self.overview_periods} periods", style="bold cyan")
        changed = text != self._shown
        if changed:
            self._shown = text
            self.text_view.update(text, layout=False)
        self.abort_label.set_class(not running, "-idle")
        return changed


class ViewBar(Horizontal):
    """The views by number, the current one highlighted, and the bus health on one line (narrow layouts, where
    one view shows at a time)."""

    DEFAULT_CSS = """
    ViewBar { height: 1; }
    ViewBar #viewbar-views { width: auto; height: 1; }
    ViewBar #viewbar-bus { width: 1fr; height: 1; text-align: right; }
    """

    def __init__(self, *, id: str | None = None) -> None:
        super().__init__(id=id)
        self.views = Static("", id="viewbar-views")
        self.bus = Static("", id="viewbar-bus")

    def compose(self) -> ComposeResult:
        yield self.views
        yield self.bus

    def show_views(self, titles: Sequence[str], current: int) -> None:
        """The views' ``titles``, numbered from 1; the one at index ``current`` highlighted."""
        bar = Text()
        for i, title in enumerate(titles):
            bar.append(f" {i + 1} {title} ", style="reverse bold" if i == current else "")
        self.views.update(bar)

    def show_bus(self, summary: Text) -> None:
        self.bus.update(summary, layout=False)
