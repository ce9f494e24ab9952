"""The main screen: the status line, the view bar and the four views (live, sweep, Bode, bus); the keys that steer
a sweep; the messages of the sweep's thread.

The screen follows the sweep through a :class:`~bodebench.apps.tui.record.SweepRecord` and draws it through its
panels; the app starts the sweep's thread and ends it (:class:`~bodebench.apps.tui.app.BodeBenchApp`).
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, cast

from textual.app import ComposeResult
from textual.binding import Binding
from textual.screen import Screen

from bodebench.apps.tui.bridge import SessionEvent, WorkerReport
from bodebench.apps.tui.dialogs import EarlierResultsDialog, MessageDialog, OverlayDialog, ToleranceDialog
from bodebench.apps.tui.files import earlier_results, load_cases, save_case
from bodebench.apps.tui.record import SweepRecord
from bodebench.apps.tui.status import StatusLine, ViewBar
from bodebench.apps.tui.table import SweepTable
from bodebench.apps.tui.views import VIEW_TITLES, VIEWS, Views
from bodebench.apps.tui.widgets import BenchFooter
from bodebench.bench.events import (
    CaseBegins,
    CaseSaved,
    PlanGrew,
    PointFinished,
    PointStarted,
    SessionEnded,
    SessionFault,
    SessionStarted,
)
from bodebench.bench.procedure import case_directory
from bodebench.core.response import FrequencyResponse
from bodebench.io.config import CaseConfig, ExperimentConfig

if TYPE_CHECKING:
    from bodebench.apps.tui.app import BodeBenchApp

#: the screen's actions (keys), as :meth:`SweepScreen.check_action` judges them
SWEEP_ACTIONS = frozenset({"start", "pause", "resume", "skip", "remeasure", "tolerance", "save", "open", "view"})


class SweepScreen(Screen[None]):
    """Sweep the cases of ``config`` into ``out`` and watch it: the views redraw ``refresh_hz`` times a second.

    At 120 x 34 cells and more the four views show at once, in a grid; below, one at a time (1 to 4 choose).
    """

    HORIZONTAL_BREAKPOINTS = [(0, "-narrow"), (120, "-wide")]
    VERTICAL_BREAKPOINTS = [(0, "-short"), (34, "-tall")]
    DEFAULT_CSS = """
    SweepScreen #panels { height: 1fr; }
    SweepScreen .view { display: none; height: 1fr; }
    SweepScreen .view.-current { display: block; }
    SweepScreen.-wide.-tall #viewbar { display: none; }
    SweepScreen.-wide.-tall #panels { layout: grid; grid-size: 2 2; grid-columns: 1fr 1fr; grid-rows: 3fr 2fr; }
    SweepScreen.-wide.-tall .view { display: block; border: round $primary-darken-2; }
    """
    BINDINGS = [
        Binding("a", "app.abort", "ABORT"),
        Binding("s", "start", "start"),
        Binding("p", "pause", "pause"),
        Binding("p", "resume", "resume"),  # the same key: shown instead of "pause" while paused
        Binding("n", "skip", "skip"),
        Binding("r", "remeasure", "redo"),
        Binding("t", "tolerance", "tol"),
        Binding("w", "save", "save"),
        Binding("o", "open", "open"),
        Binding("1", "view('live')", "live", show=False),
        Binding("2", "view('sweep')", "sweep", show=False),
        Binding("3", "view('bode')", "bode", show=False),
        Binding("4", "view('bus')", "bus", show=False),
    ]

    def __init__(self, config: ExperimentConfig, out: Path, refresh_hz: float) -> None:
        super().__init__()
        self.config = config
        self.out = out
        self.refresh_hz = refresh_hz
        self.record = SweepRecord(config)
        self.tolerance_percent: float | None = None  # the user's, for the points not yet started (None: as configured)
        self.status = StatusLine(id="status")
        self.viewbar = ViewBar(id="viewbar")
        self.views = Views(id="panels")
        self.live = self.views.live
        self.sweep_panel = self.views.sweep
        self.bode = self.views.bode
        self.bus = self.views.bus
        self._bindings_state: tuple[bool, ...] = ()

    @property
    def bench(self) -> BodeBenchApp:
        """The app this screen runs in (it runs the sweep's thread)."""
        return cast("BodeBenchApp", self.app)

    @property
    def table(self) -> SweepTable:
        """The sweep table (in the sweep view)."""
        return self.sweep_panel.table

    @property
    def case(self) -> CaseConfig:
        """The case being shown."""
        return self.record.case

    def compose(self) -> ComposeResult:
        yield self.status
        yield self.viewbar
        yield self.views
        yield BenchFooter()

    def on_mount(self) -> None:
        results, problems = load_cases(self.config, self.out)
        for problem in problems:
            self.notify(f"previous results not shown: {problem}", severity="warning", timeout=8)
        if self.record.load(results):
            self.status.state = "loaded"
        self.sweep_panel.fill(self.record.model)
        self._show_view(self.views.current)
        self.refresh_status()
        self.refresh_bus(force=True)
        self.refresh_bode()
        self.set_interval(1.0 / self.refresh_hz, self._tick)

    # ------------------------------------------------------------------------------------------------ keys
    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """Whether a key works now: one that would do nothing is not shown. Under a dialog, and while the app
        quits, none of the screen's keys work."""
        if action not in SWEEP_ACTIONS:
            return True
        bench = self.bench
        if bench.modal_open() or bench.quitting:
            return False
        running = bench.running
        if action == "pause":
            return running and not bench.paused
        if action == "resume":
            return running and bench.paused
        if action == "skip":
            return running
        if action == "start":
            return not running
        if action == "remeasure":
            return running or self.record.case_index in self.record.results
        if action == "save":
            return bool(self.record.points)
        return True

    def sync_bindings(self) -> None:
        """Refresh the footer's keys when what they can do has changed (a footer rebuild is not free)."""
        bench = self.bench
        state = (bench.running, bench.paused, bool(self.record.points), self.record.case_index in self.record.results,
                 bench.modal_open(), bench.quitting)
        if state != self._bindings_state:
            self._bindings_state = state
            for screen in self.app.screen_stack:  # the footer is on this screen, under any dialog
                screen.refresh_bindings()

    def action_view(self, view: str) -> None:
        if view in VIEWS:
            self._show_view(view)
            if view == "sweep":
                self.table.focus()

    def _show_view(self, view: str) -> None:
        self.views.show(view)
        self.viewbar.show_views([VIEW_TITLES[name] for name in VIEWS], VIEWS.index(view))

    def action_start(self) -> None:
        if self.bench.running:
            self.notify("a sweep is already running", severity="warning")
            return
        earlier = earlier_results(self.config, self.out)
        if not earlier.found:
            self._launch(None)
            return

        def answered(answer: str | None) -> None:
            if answer == "resume":
                self._launch(None, resume=earlier.resumable)
            elif answer == "replace":
                self._launch(None)

        self.app.push_screen(EarlierResultsDialog("; ".join(earlier.found), earlier.refused), answered)

    def action_pause(self) -> None:
        control = self.bench.control
        if not self.bench.running or control is None:
            return
        paused = not control.paused
        control.procedure.set_paused(paused)
        model = self.record.model
        (model.pause if paused else model.unpause)(time.monotonic())
        self.status.state = "paused" if paused else "running"
        self.refresh_status()
        self.sync_bindings()

    def action_resume(self) -> None:
        """The pause key while paused: the sweep goes on."""
        self.action_pause()

    def action_skip(self) -> None:
        control = self.bench.control
        if not self.bench.running or control is None:
            return
        control.procedure.request_skip()
        self.notify("skipping the current point")

    def action_remeasure(self) -> None:
        key = self.table.selected_key()
        if key is None:
            return
        row = self.record.model.rows[key]
        control = self.bench.control
        if self.bench.running and control is not None:
            if not control.procedure.request_remeasure(row.frequency_hz):
                self.notify("the session is still starting", severity="warning")
                return
            self.notify(f"{row.frequency_hz:g} Hz will be measured again next")
            return
        if self.record.case_index not in self.record.results:
            self.notify("nothing measured yet to re-measure into: start a sweep (s)", severity="warning")
            return
        self._launch(row.frequency_hz)

    def action_tolerance(self) -> None:
        def done(text: str | None) -> None:
            if text is None:
                return
            self.tolerance_percent = float(text)
            control = self.bench.control
            if self.bench.running and control is not None:
                control.procedure.set_tolerance(self.tolerance_percent)
            self.notify(f"tolerance {self.tolerance_percent:g} % for the points not yet started")
            self.refresh_status()

        self.app.push_screen(ToleranceDialog(self._tolerance()), done)

    def _tolerance(self) -> float:
        """The tolerance of the points not yet started (%): the user's, or the current case's."""
        return self.tolerance_percent if self.tolerance_percent is not None else self.case.analysis.tolerance_percent

    def action_save(self) -> None:
        response = self.record.current_response()
        if response is None or not len(response):
            self.notify("no points to save yet", severity="warning")
            return
        case = self.case
        directory = case_directory(self.config, self.out, case)
        self.run_worker(partial(self._save_thread, case, response, directory), thread=True, exit_on_error=False,
                        group="save")

    def _save_thread(self, case: CaseConfig, response: FrequencyResponse, directory: Path) -> None:
        try:
            files = save_case(self.config, case, response, directory)
        except Exception as exc:  # noqa: BLE001 - reported to the user, never fatal
            self.app.call_from_thread(self.notify, f"saving failed: {type(exc).__name__}: {exc}", severity="error",
                                      timeout=10)
            return
        self.app.call_from_thread(self.notify, f"saved {len(response)} points and "
                                               f"{', '.join(f.name for f in files)} to {directory}")

    def action_open(self) -> None:
        dialog = OverlayDialog(str(self.out.parent))

        def done(text: str | None) -> None:
            if text is None:
                return
            self.bode.overlay(dialog.loaded)
            self.notify(f"overlaid {', '.join(label for label, _ in dialog.loaded)}")
            self.refresh_bode()
            if self.views.current != "bode":
                self.action_view("bode")

        self.app.push_screen(dialog, done)

    def _launch(self, frequency_hz: float | None, resume: dict[int, FrequencyResponse] | None = None) -> None:
        """Start a sweep of every case (``frequency_hz``: re-measure that frequency of the current case; ``resume``:
        continue the interrupted sweeps whose points these are, measuring only what they lack)."""
        record = self.record
        whole_sweep = frequency_hz is None
        cases = list(range(len(self.config.cases))) if whole_sweep else [record.case_index]
        base = None if whole_sweep else record.results.get(record.case_index)
        self.bench.start_sweep(cases, frequency_hz, base, self.tolerance_percent, resume=resume is not None)
        record.new_run(whole_sweep, resume)
        self.status.state = "starting"
        self.bus.new_sweep()
        self.sync_bindings()
        self.refresh_status()

    def show_aborting(self) -> None:
        """The user asked the running sweep to abort."""
        self.status.state = "aborting"
        self.refresh_status()

    # ------------------------------------------------------------------------------------- session messages
    def on_session_event(self, message: SessionEvent) -> None:
        if not self.bench.is_current(message.run):
            return
        try:
            self._apply(message.event)
        except Exception:  # noqa: BLE001 - see BodeBenchApp.display_error
            self.bench.display_error("a session event")

    def _apply(self, event: object) -> None:
        record = self.record
        if record.drain(self.bench.bridge):
            self.live.stale = True
        now = time.monotonic()
        self.status.apply(event)
        self.bus.apply(event)
        if isinstance(event, CaseBegins):
            if record.begin_case(event):
                self.sweep_panel.fill(record.model)
            self.bode.stale = True
        elif isinstance(event, CaseSaved):
            record.case_saved(event)
            self.bode.stale = True
        elif isinstance(event, SessionStarted):
            record.model.session_started(now, event.timer())
            control = self.bench.control
            self.status.state = "paused" if control is not None and control.paused else "running"
        elif isinstance(event, PlanGrew):
            record.model.extend(event.frequencies_hz, event.extra_periods, event.max_periods)
            self.sweep_panel.fill(record.model)
            self.notify(f"the plan adds {len(event.frequencies_hz)} frequencies: "
                        + ", ".join(f"{f:.4g} Hz" for f in event.frequencies_hz), timeout=4)
        elif isinstance(event, PointStarted):
            record.point_started(event, now)
            self.live.stale = True
        elif isinstance(event, PointFinished):
            if record.point_finished(event, now):
                self.bode.stale = True
            self.live.stale = True
        elif isinstance(event, SessionFault):
            record.fault(event)
        elif isinstance(event, SessionEnded):
            record.session_ended(event, now)
        self._show_all()

    def on_worker_report(self, message: WorkerReport) -> None:
        """The sweep's thread has ended: say how, then let the app know (a quit may be waiting for it)."""
        if not self.bench.is_current(message.run):
            return
        stop_line = ""
        try:
            if not message.completed:
                stop_line = self.record.stop_line(message, self.bench.stopped_by, self.bench.quitting)
            self._show_end(message)
        except Exception:  # noqa: BLE001 - see BodeBenchApp.display_error
            self.bench.display_error("the end of the sweep")
        self.bench.sweep_ended(message.completed, stop_line)

    def _show_end(self, message: WorkerReport) -> None:
        record = self.record
        if record.drain(self.bench.bridge):
            self.live.stale = True
        self.bus.sweep_ended()
        record.model.session_ended(time.monotonic())
        self.status.state = record.outcome(message)
        if self.status.state == "done":
            self.notify(f"sweep complete: results in {message.saved}", timeout=8)
        elif self.status.state == "aborted":
            self.notify(record.abort_notice(message), severity="warning", timeout=10)
        else:
            self.app.push_screen(MessageDialog("Sweep stopped", record.failure_text(message), error=True))
        self._show_all()

    # ---------------------------------------------------------------------------------------- refreshing
    def _show_all(self) -> None:
        """After a session event: every panel as the record now stands, and the footer's keys."""
        self.sweep_panel.show_rows(self.record.model)
        self.refresh_status()
        self.refresh_bus(force=True)
        self.refresh_bode()
        self.sync_bindings()

    def _tick(self) -> None:
        try:
            self._refresh()
        except Exception:  # noqa: BLE001 - see BodeBenchApp.display_error
            self.bench.display_error("the periodic refresh")

    def _refresh(self) -> None:
        """The periodic refresh: the progress the session queued, then what it changed."""
        record = self.record
        bridge = self.bench.bridge
        if record.drain(bridge):
            self.live.stale = True
        if self.live.stale:
            latest = bridge.latest_progress if bridge is not None else None
            self.live.redraw(record.model, latest, self.case.formed().raw[0])  # the channel the scope holds
        self.sweep_panel.tick(record.model)
        self.refresh_bus()
        self.refresh_bode()
        self.refresh_status()

    def refresh_status(self) -> None:
        """The status line, and the sweep view's progress line when it changed."""
        now = time.monotonic()
        model = self.record.model
        if self.status.show(self.case.name, model, self._tolerance(), self.bench.running, now):
            self.sweep_panel.show_progress(model, now)

    def refresh_bus(self, force: bool = False) -> None:
        """The bus view and the view bar's bus line, when a new reading came (or ``force``)."""
        bridge = self.bench.bridge
        if self.bus.take(bridge.latest_health if bridge is not None else None) or force:
            self.bus.show(self.case.on_bench.safety.watchdog_s)
            self.viewbar.show_bus(self.bus.summary())

    def refresh_bode(self) -> None:
        """The Bode view, when the responses changed."""
        if self.bode.stale:
            self.bode.redraw(self.record.responses())
