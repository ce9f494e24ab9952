"""The four views of the main screen: live, sweep, Bode and bus."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widget import Widget

from bodebench.apps.tui.bode import BodePanel
from bodebench.apps.tui.bus import BusPanel
from bodebench.apps.tui.live import LivePanel
from bodebench.apps.tui.table import SweepPanel

VIEWS = ("live", "sweep", "bode", "bus")
VIEW_TITLES = {"live": "Live", "sweep": "Sweep", "bode": "Bode", "bus": "Bus"}


class Views(Vertical):
    """The views, each titled; ``current`` is the one a narrow layout shows (its panel has the class ``-current``),
    a wide one shows all four."""

    def __init__(self, *, id: str | None = None) -> None:
        super().__init__(id=id)
        self.current = VIEWS[0]
        self.live = LivePanel(id="live", classes="view -current")
        self.bode = BodePanel(id="bode", classes="view")
        self.sweep = SweepPanel(id="sweep", classes="view")
        self.bus = BusPanel(id="bus", classes="view")

    def panels(self) -> dict[str, Widget]:
        """The views by name, in the order of :data:`VIEWS`."""
        return {"live": self.live, "sweep": self.sweep, "bode": self.bode, "bus": self.bus}

    def compose(self) -> ComposeResult:
        yield self.live
        yield self.bode
        yield self.sweep
        yield self.bus

    def on_mount(self) -> None:
        for view, panel in self.panels().items():
            panel.border_title = VIEW_TITLES[view]

    def show(self, view: str) -> None:
        """Make ``view`` the current one."""
        self.current = view
        for name, panel in self.panels().items():
            panel.set_class(name == view, "-current")
