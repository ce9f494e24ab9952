"""The bus view: frame rates, errors, lost samples, round trip, pacing and the watchdog of the running session."""

from __future__ import annotations

import math

from rich.text import Text
from textual.widgets import Static

from bodebench.apps.tui.model import BusRates
from bodebench.bench.events import Health, SessionEnded, SessionFault, SessionStarted
from bodebench.status import FaultKind

TRIPPED = "TRIPPED"


def si_time(seconds: float) -> str:
    """A duration in µs, ms or s; ``--`` when unknown."""
    if not math.isfinite(seconds):
        return "--"
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} µs"
    if seconds < 1.0:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.2f} s"


def frame_rate(value: float) -> str:
    """Frames per second (``1.2k/s`` from a thousand); ``--`` when unknown."""
    if not math.isfinite(value):
        return "--"
    return f"{value / 1000:.1f}k/s" if value >= 1000 else f"{value:.0f}/s"


def bus_summary(health: Health | None, rates: tuple[float, float]) -> Text:
    """One line of bus health for narrow layouts."""
    if health is None:
        return Text("bus: --", style="bright_black")
    bus = health.bus
    bad = bus.errors or bus.lost_samples
    p99 = "--" if health.pacing is None else si_time(health.pacing.p99)
    return Text(f"in {frame_rate(rates[0])} out {frame_rate(rates[1])} err {bus.errors} lost {bus.lost_samples} "
                f"rt {si_time(health.round_trip_s)} p99 {p99}", style="bold red" if bad else "")


class BusPanel(Static):
    """Bus health: the link, frame rates, errors, lost samples, round trip, pacing and the watchdog's state.

    It follows the session's events (the link and the watchdog) and its bus readings (:meth:`take`); the frame
    rates are counter differences between readings.
    """

    DEFAULT_CSS = """
    BusPanel { padding: 0 1; }
    """

    def __init__(self, *, id: str | None = None, classes: str | None = None) -> None:
        super().__init__("", id=id, classes=classes)
        self.where = ""                                   # the link, as the session names it
        self.health: Health | None = None                 # the latest reading
        self.rates: tuple[float, float] = (math.nan, math.nan)  # frames in and out per second
        self.watchdog = "off"                             # off, armed or TRIPPED
        self._counters = BusRates()
        self._seen: float | None = None                   # when the latest reading came (monotonic s)

    def new_sweep(self) -> None:
        """A sweep starts: rates are measured afresh (its sessions' counters start at zero)."""
        self._counters.reset()

    def apply(self, event: object) -> None:
        """Follow a session event: a session armed the watchdog, or it tripped, or the session ended."""
        if isinstance(event, SessionStarted):
            self.where = event.where
            self.watchdog = "armed"
        elif isinstance(event, SessionFault):
            if event.kind == FaultKind.WATCHDOG:
                self.watchdog = TRIPPED
        elif isinstance(event, SessionEnded):
            self.sweep_ended()

    def sweep_ended(self) -> None:
        """No session runs: the watchdog is off, unless it tripped (that stays shown)."""
        if self.watchdog != TRIPPED:
            self.watchdog = "off"

    def take(self, latest: tuple[float, Health] | None) -> bool:
        """Take the session's latest bus reading (when it came, monotonic s; the health); True when it is new."""
        if latest is None or latest[0] == self._seen:
            return False
        self._seen, self.health = latest
        bus = self.health.bus
        self.rates = self._counters.update(latest[0], bus.frames_in, bus.frames_out)
        return True

    def summary(self) -> Text:
        """The bus health on one line (:func:`bus_summary`)."""
        return bus_summary(self.health, self.rates)

    def show(self, watchdog_s: float) -> None:
        """Draw the panel; ``watchdog_s``: the current case's watchdog timeout."""
        text = Text()

        def line(label: str, value: str, style: str = "") -> None:
            text.append(f"{label:<12}", style="bold")
            text.append(value + "\n", style=style)

        health, rates = self.health, self.rates
        line("link", self.where or "--")
        if health is None:
            line("frames", "no bus reading yet", "bright_black")
        else:
            bus = health.bus
            line("frames", f"in {frame_rate(rates[0])}  out {frame_rate(rates[1])}  (total in {bus.frames_in}, "
                           f"out {bus.frames_out})")
            line("errors", f"{bus.errors}  lost samples {bus.lost_samples}  duplicates {bus.duplicates}  "
                           f"incomplete {bus.incomplete_samples}  time conflicts {health.time_conflicts}"
                           + (f"  rejected {bus.rejected_total} ("
                              + ", ".join(f"{cause} {n}" for cause, n in bus.rejected.items() if n) + ")"
                              if bus.rejected_total else ""),
                 "bold red" if bus.errors or bus.lost_samples else "")
            line("bus state", bus.bus_state + (f"  last error: {bus.last_error}" if bus.last_error else ""))
            line("round trip", si_time(health.round_trip_s))
            if health.pacing is None:
                line("pacing", "lockstep clock (no pacing)")
            else:
                p = health.pacing
                line("pacing", f"p50 {si_time(p.p50)}  p99 {si_time(p.p99)}  max {si_time(p.max)}  "
                               f"overruns {p.overruns}  ({p.scheduling})", "bold red" if p.overruns else "")
        style = {TRIPPED: "bold white on red", "armed": "green"}.get(self.watchdog.split(" ")[0], "bright_black")
        line("watchdog", f"{self.watchdog}  (trips after {watchdog_s:g} s without feedback)", style)
        self.update(text, layout=False)
