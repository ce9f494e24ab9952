"""The terminal UI of a bench session (``bodebench tui CONFIG``).

The sweep runs in a Textual thread worker; its listener (:class:`~bodebench.apps.tui.bridge.SessionBridge`)
queues rare events as messages and leaves the frequent ones for a refresh timer, so the measurement never
waits on the screen. Every way out of the app (q, Ctrl+Q, an error) aborts a running sweep and joins its
thread first: the session leaves the drive at setpoint zero, disabled. When the last sweep did not complete,
:func:`run_tui` prints one line on exit saying why, how many points are kept where, and how the drive was left.
Exit status: 0 after a quit with no sweep running, 1 when the quit aborted a running sweep, 128 + N after signal
N (SIGTERM, SIGHUP).
"""

from __future__ import annotations

import asyncio
import math
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from rich.text import Text
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen, Screen
from textual.widget import Widget
from textual.widgets import Static

from bodebench.apps.tui.bridge import SessionBridge, SessionEvent, WorkerReport
from bodebench.apps.tui.dialogs import ChoiceDialog, ConfirmDialog, InputDialog, MessageDialog
from bodebench.apps.tui.model import BusRates, SweepModel, format_duration
from bodebench.apps.tui.widgets import (
    STATE_STYLES,
    AbortLabel,
    BenchFooter,
    BodePanel,
    BusPanel,
    LivePanel,
    SweepPanel,
    SweepTable,
    bus_summary,
)
from bodebench.bench.events import (
    CaseBegins,
    CaseSaved,
    Health,
    OverviewProgress,
    PlanGrew,
    PointFinished,
    PointStarted,
    SessionEnded,
    SessionError,
    SessionFault,
    SessionStarted,
)
from bodebench.bench.procedure import CaseOutcome, SweepProcedure, case_directory, previous_run
from bodebench.bench.session import completed_frequencies
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.core.summary import summarize_response
from bodebench.io.config import AnalysisConfig, CaseConfig, ExperimentConfig
from bodebench.io.results import (
    CSV_NAME,
    ResultsError,
    load_response,
    save_response,
    sidecar_runs,
    update_sidecar,
)
from bodebench.io.schema import check_value
from bodebench.status import FaultKind

VIEWS = ("live", "sweep", "bode", "bus")
VIEW_TITLES = {"live": "Live", "sweep": "Sweep", "bode": "Bode", "bus": "Bus"}
JOIN_TIMEOUT_S = 30.0
ROW_PERIODS_EVERY = 3  # refresh ticks between redraws of the table for period counts alone


def load_results(path: Path) -> list[tuple[str, FrequencyResponse]]:
    """Responses in ``path`` (a results directory, or a directory of them): [(label, response)].
    Raises ResultsError naming the path when there is none or a file is bad."""
    if not path.is_dir():
        raise ResultsError(f"{path}: not a directory")
    if (path / CSV_NAME).exists():
        response = load_response(path)
        return [(response.case or path.name, response)]
    found = []
    for sub in sorted(p for p in path.iterdir() if p.is_dir() and (p / CSV_NAME).exists()):
        response = load_response(sub)
        found.append((f"{path.name}/{sub.name}", response))
    if not found:
        raise ResultsError(f"{path}: no {CSV_NAME} here or in its sub-directories")
    return found


@dataclass
class RunControl:
    """Shared between the UI and one sweep thread: the sweep procedure takes the user's requests (its
    ``controls``, which every session of the sweep reads, those made before a session exists too). Plain
    attributes, each written by one side."""

    run: int
    procedure: SweepProcedure
    done: threading.Event = field(default_factory=threading.Event)
    session_s: float = math.nan          # wall time of the last session.run(), s
    health: Health | None = None         # its last bus health

    @property
    def paused(self) -> bool:
        """Whether the user paused the sweep."""
        return self.procedure.controls.pause.is_set()


class BodeBenchApp(App[int]):
    """Sweep the cases of a bench config (``config``), writing results under ``out``."""

    TITLE = "bodebench"
    ENABLE_COMMAND_PALETTE = False
    HORIZONTAL_BREAKPOINTS = [(0, "-narrow"), (120, "-wide")]
    VERTICAL_BREAKPOINTS = [(0, "-short"), (34, "-tall")]
    CSS = """
    #status { height: 1; }
    #status-text { width: 1fr; height: 1; }
    #viewbar { height: 1; }
    #viewbar-views { width: auto; height: 1; }
    #viewbar-bus { width: 1fr; height: 1; text-align: right; }
    #panels { height: 1fr; }
    .view { display: none; height: 1fr; }
    .view.-current { display: block; }
    BusPanel { padding: 0 1; }
    Screen.-wide.-tall #viewbar { display: none; }
    Screen.-wide.-tall #panels { layout: grid; grid-size: 2 2; grid-columns: 1fr 1fr; grid-rows: 3fr 2fr; }
    Screen.-wide.-tall .view { display: block; border: round $primary-darken-2; }
    """
    BINDINGS = [
        Binding("a", "abort", "ABORT"),
        Binding("s", "start", "start"),
        Binding("p", "pause", "pause"),
        Binding("p", "resume", "resume"),  # the same key: shown instead of "pause" while paused
        Binding("n", "skip", "skip"),
        Binding("r", "remeasure", "redo"),
        Binding("t", "tolerance", "tol"),
        Binding("w", "save", "save"),
        Binding("o", "open", "open"),
        Binding("q", "request_quit", "quit"),
        Binding("1", "view('live')", "live", show=False),
        Binding("2", "view('sweep')", "sweep", show=False),
        Binding("3", "view('bode')", "bode", show=False),
        Binding("4", "view('bus')", "bus", show=False),
        Binding("tab", "next_view", "next view", show=False),
    ]

    def __init__(self, config: ExperimentConfig, out: Path, refresh_hz: float = 5.0, log_bus: Path | None = None
                 ) -> None:
        """log_bus: a log of the bus traffic of each sweep (the second sweep's as ``<stem>.run2<suffix>``, ...)."""
        super().__init__()
        if not config.cases or not config.on_bench:
            raise ValueError(f"{config.path}: not a bench config (no [bench] table)")
        if not refresh_hz > 0:
            raise ValueError(f"refresh_hz must be > 0, got {refresh_hz!r}")
        # processes are spawned from the session thread while the app has replaced sys.stderr with an object
        # whose fileno() is -1, which multiprocessing's resource tracker cannot pass on: start it now
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()
        self.config = config
        self.out = Path(out)
        self.log_bus = log_bus
        self.refresh_hz = refresh_hz
        self.case_index = 0
        self.tolerance_percent: float | None = None   # None: as configured
        self.view = "live"
        self.overlays: list[tuple[str, FrequencyResponse]] = []
        self.results: dict[int, FrequencyResponse] = {}  # per case: the latest finished or loaded response
        self.live_points: list[ResponsePoint] = []
        self.control: RunControl | None = None
        self._runs = 0
        self.bridge: SessionBridge | None = None
        self.model = self._new_model(self.case)
        self.rates = BusRates()
        self.health: Health | None = None
        self._health_seen: float | None = None
        self.bus_rates = (math.nan, math.nan)
        self.where = ""
        self.overview_periods: int | None = None  # periods of the overview an adaptive plan runs first, while it runs
        self.watchdog = "off"
        self.last_fault: SessionFault | None = None
        self.last_ended: SessionEnded | None = None
        self.state = "idle"
        self._bode_dirty = True
        self._live_dirty = False
        self._max_index = -1
        self._quitting = False
        self.stopped_by = ""  # the signal that ended the app, if one did
        self._scope_index: int | None = None
        self.worker_errors: list[str] = []
        self._status_text = Text()
        self._bindings_state: tuple[bool, ...] = ()
        self._resumed: dict[int, FrequencyResponse] = {}  # per case: the points the running sweep continues
        self._quit_dialog: ConfirmDialog | None = None
        self.exit_line = ""  # printed on exit: how the last sweep ended, when it did not complete
        self._display_error_shown = False
        self._ticks = 0

    # ------------------------------------------------------------------------------------------ structure
    @property
    def case(self) -> CaseConfig:
        return self.config.cases[self.case_index]

    @property
    def running(self) -> bool:
        return self.control is not None and not self.control.done.is_set()

    def _new_model(self, case: CaseConfig) -> SweepModel:
        return SweepModel(case.excitation.frequencies_hz, case.analysis.harmonics, case.analysed_channels)

    def _display_error(self, where: str) -> None:
        """A fault in drawing is reported, not fatal: the measurement goes on (traceback kept for diagnosis)."""
        self.worker_errors.append(traceback.format_exc())
        if not self._display_error_shown:
            self._display_error_shown = True
            self.notify(f"display error in {where}: {traceback.format_exc(limit=0).strip()}", severity="error",
                        timeout=10)

    def compose(self) -> ComposeResult:
        self.w_status = Static("", id="status-text")
        self.w_abort = AbortLabel(" ABORT  a ", id="abort-label", classes="-idle")
        self.w_views = Static("", id="viewbar-views")
        self.w_bus_line = Static("", id="viewbar-bus")
        self.w_live = LivePanel(id="live", classes="view -current")
        self.w_bode = BodePanel(id="bode", classes="view")
        self.w_sweep = SweepPanel(id="sweep", classes="view")
        self.w_bus = BusPanel(id="bus", classes="view")
        self.w_table = SweepTable(id="sweep-table")
        self.w_sweep.table = self.w_table
        with Horizontal(id="status"):
            yield self.w_status
            yield self.w_abort
        with Horizontal(id="viewbar"):
            yield self.w_views
            yield self.w_bus_line
        with Vertical(id="panels"):
            yield self.w_live
            yield self.w_bode
            yield self.w_sweep
            yield self.w_bus
        yield BenchFooter()

    def _sync_bindings(self) -> None:
        """Refresh the footer's keys when what they can do has changed (a footer rebuild is not free)."""
        state = (self.running, self._paused, bool(self.live_points), self.case_index in self.results,
                 self._modal_open(), self._quitting)
        if state != self._bindings_state:
            self._bindings_state = state
            for screen in self.screen_stack:  # the footer is on the first screen, under any dialog
                screen.refresh_bindings()

    def _modal_open(self) -> bool:
        try:
            return isinstance(self.screen, ModalScreen)
        except Exception:  # noqa: BLE001 - no screen yet (or any more)
            return False

    def _screen_changed(self, screen: Screen[Any]) -> None:
        """A dialog opened or closed: the footer shows the keys that work under it."""
        self._sync_bindings()

    def _panels(self) -> dict[str, Widget]:
        return {"live": self.w_live, "sweep": self.w_sweep, "bode": self.w_bode, "bus": self.w_bus}

    def on_mount(self) -> None:
        # SIGTERM (timeout, systemd) and SIGHUP (a closed terminal) quit as a confirmed quit does: the running
        # sweep is aborted (setpoint to zero, drive disabled) and joined before the app ends
        self._signals: list[int] = []
        loop = asyncio.get_running_loop()
        for signum in [getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)]:
            try:
                loop.add_signal_handler(signum, self._stop_signal, signum)
            except (NotImplementedError, RuntimeError, ValueError):  # not the main thread: the signal stays as it is
                continue
            self._signals.append(signum)
        self.screen_change_signal.subscribe(self, self._screen_changed)
        for view in VIEWS:
            self._panels()[view].border_title = VIEW_TITLES[view]
        self._load_previous()
        self.w_table.fill(self.model.rows)
        self.model.take_changed()
        self._show_views()
        self._refresh_status()
        self._refresh_bus(force=True)
        self._refresh_bode()
        self.set_interval(1.0 / self.refresh_hz, self._tick)

    def _load_previous(self) -> None:
        """Show the results already in the out directory (a finished sweep) for every case that has them."""
        for i, case in enumerate(self.config.cases):
            directory = case_directory(self.config, self.out, case)
            if not (directory / CSV_NAME).exists():
                continue
            try:
                self.results[i] = load_response(directory)
            except ResultsError as exc:
                self.notify(f"previous results not shown: {exc}", severity="warning", timeout=8)
        if 0 in self.results:
            self.model.load_points(self.results[0].points)
            self.live_points = list(self.results[0].points)
            self.state = "loaded"

    # --------------------------------------------------------------------------------------------- actions
    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """Whether a key works now: one that would do nothing is not shown. Under a dialog only the keys the
        dialog passes on to the app (its ``APP_KEYS``) and Ctrl+Q work, so the footer shows only those."""
        if self._modal_open() and action != "quit" and action not in getattr(self.screen, "APP_KEYS", ()):
            return False  # "quit" is Ctrl+Q (not in the footer), which works everywhere
        if self._quitting:  # the sweep is being aborted before the app ends: nothing else to do
            return action == "abort"
        running = self.running
        if action == "pause":
            return running and not self._paused
        if action == "resume":
            return running and self._paused
        if action in ("abort", "skip"):
            return running
        if action == "start":
            return not running
        if action == "remeasure":
            return running or self.case_index in self.results
        if action == "save":
            return bool(self.live_points)
        return True

    def action_view(self, view: str) -> None:
        if view in VIEWS:
            self.view = view
            self._show_views()
            if view == "sweep":
                self.w_table.focus()

    def action_next_view(self) -> None:
        self.action_view(VIEWS[(VIEWS.index(self.view) + 1) % len(VIEWS)])

    def action_start(self) -> None:
        if self.running:
            self.notify("a sweep is already running", severity="warning")
            return
        found: list[str] = []
        resumable: dict[int, FrequencyResponse] = {}
        refused = ""
        for i, case in enumerate(self.config.cases):
            directory = case_directory(self.config, self.out, case)
            if not (directory / CSV_NAME).exists():
                continue
            try:
                previous = previous_run(directory, case, "resume")
            except ResultsError as exc:  # another configuration's, or unreadable: to be replaced, not continued
                found.append(str(directory))
                refused = refused or str(exc)
                continue
            if previous is not None:
                resumable[i] = previous
                done = completed_frequencies(previous, case.analysed_channels, case.analysis.harmonics)
                found.append(f"{directory} ({len(done)} of {len(case.excitation.frequencies_hz)} frequencies "
                             "measured)")
        if not found:
            self._launch(None)
            return

        def answered(answer: str | None) -> None:
            if answer == "resume":
                self._launch(None, resume=resumable)
            elif answer == "replace":
                self._launch(None)

        where = "; ".join(found)
        if refused:
            self.push_screen(ChoiceDialog(f"Results are already in {where}, and cannot be resumed: {refused}. "
                                          "Replace them with a new sweep?",
                                          [("replace", "Replace", "x", "error"), (None, "Cancel", "c", "default")]),
                             answered)
            return
        self.push_screen(ChoiceDialog(f"Results are already in {where}. Resume measures only the missing "
                                      "frequencies and keeps the others; replace starts again and overwrites them.",
                                      [("resume", "Resume", "r", "primary"), ("replace", "Replace", "x", "error"),
                                       (None, "Cancel", "c", "default")]), answered)

    def action_abort(self) -> None:
        control = self.control
        if control is None or control.done.is_set():
            self.notify("no sweep running")
            return
        control.procedure.request_abort()
        self.state = "aborting"
        self._refresh_status()

    def action_pause(self) -> None:
        control = self.control
        if not self.running or control is None:
            return
        paused = not control.paused
        control.procedure.set_paused(paused)
        (self.model.pause if paused else self.model.unpause)(time.monotonic())
        self.state = "paused" if paused else "running"
        self._refresh_status()
        self._sync_bindings()

    def action_resume(self) -> None:
        """The pause key while paused: the sweep goes on."""
        self.action_pause()

    @property
    def _paused(self) -> bool:
        control = self.control
        return bool(self.running and control is not None and control.paused)

    def action_skip(self) -> None:
        control = self.control
        if not self.running or control is None:
            return
        control.procedure.request_skip()
        self.notify("skipping the current point")

    def action_remeasure(self) -> None:
        key = self.w_table.selected_key()
        if key is None:
            return
        row = self.model.rows[key]
        control = self.control
        if self.running and control is not None:
            if not control.procedure.request_remeasure(row.frequency_hz):
                self.notify("the session is still starting", severity="warning")
                return
            self.notify(f"{row.frequency_hz:g} Hz will be measured again next")
            return
        if self.case_index not in self.results:
            self.notify("nothing measured yet to re-measure into: start a sweep (s)", severity="warning")
            return
        self._launch(row.frequency_hz)

    def action_tolerance(self) -> None:
        current = self.tolerance_percent if self.tolerance_percent is not None else self.case.analysis.tolerance_percent

        def check(text: str) -> str | None:
            try:
                value = float(text)
            except ValueError:
                return f"not a number: {text!r}"
            problem = check_value(AnalysisConfig, "tolerance_percent", value)
            return f"the tolerance {problem}" if problem else None

        def done(text: str | None) -> None:
            if text is None:
                return
            self.tolerance_percent = float(text)
            control = self.control
            if self.running and control is not None:
                control.procedure.set_tolerance(self.tolerance_percent)
            self.notify(f"tolerance {self.tolerance_percent:g} % for the points not yet started")
            self._refresh_status()

        self.push_screen(InputDialog("Tolerance for the next points (%)", f"{current:g}", check), done)

    def action_save(self) -> None:
        response = self._current_response()
        if response is None or not len(response):
            self.notify("no points to save yet", severity="warning")
            return
        directory = case_directory(self.config, self.out, self.case)
        self.run_worker(partial(self._save_thread, response, directory), thread=True, exit_on_error=False,
                        group="save")

    def _save_thread(self, response: FrequencyResponse, directory: Path) -> None:
        from bodebench.apps.plots import write_plots

        try:
            runs = sidecar_runs(directory)  # the records of the runs that made these points stay
            save_response(response, directory)
            summary = summarize_response(response, self.case.analysis.response_kind)
            update_sidecar(directory, {"summary": [s.to_json() for s in summary], "runs": runs})
            title = f"{self.config.title}: {self.case.name}" if self.config.has_cases else self.config.title
            files = write_plots(response, directory, title, summary=summary)
        except Exception as exc:  # noqa: BLE001 - reported to the user, never fatal
            self.call_from_thread(self.notify, f"saving failed: {type(exc).__name__}: {exc}", severity="error",
                                  timeout=10)
            return
        self.call_from_thread(self.notify, f"saved {len(response)} points and "
                                           f"{', '.join(f.name for f in files)} to {directory}")

    def action_open(self) -> None:
        def check(text: str) -> str | None:
            if not text:
                return "enter a results directory"
            try:
                self._pending_open = load_results(Path(text).expanduser())
            except ResultsError as exc:
                return str(exc)
            return None

        def done(text: str | None) -> None:
            if text is None:
                return
            loaded = getattr(self, "_pending_open", [])
            labels = {label for label, _ in self.overlays}
            for label, response in loaded:
                unique, n = label, 2
                while unique in labels:
                    unique, n = f"{label} ({n})", n + 1
                labels.add(unique)
                self.overlays.append((unique, response))
            self.notify(f"overlaid {', '.join(label for label, _ in loaded)}")
            self._bode_dirty = True
            self._refresh_bode()
            if self.view not in ("bode",):
                self.action_view("bode")

        self.push_screen(InputDialog("Open a results directory to overlay on the Bode plot", str(self.out.parent),
                                     check, placeholder="path/to/results"), done)

    async def action_request_quit(self) -> None:
        """q (in the question and message dialogs too; the input dialog types it)."""
        await self.action_quit()

    async def action_quit(self) -> None:
        """q or Ctrl+Q: quit; while a sweep runs, ask first (q again answers yes)."""
        if self._quitting:
            return
        if not self.running:
            self._quitting = True
            self.exit(0)
            return
        if self._quit_dialog is not None and self.screen is self._quit_dialog:
            self._quit_dialog.dismiss(True)
            return

        def answered(yes: bool | None) -> None:
            self._quit_dialog = None
            if yes and not self._quitting:
                self._quitting = True
                self._sync_bindings()
                if self.running:
                    self.action_abort()
                    self.notify("aborting the sweep before quitting ...")
                    self.set_timer(JOIN_TIMEOUT_S, partial(self._exit_unjoined, 1))
                else:  # it ended while the question was open
                    self.exit(0)

        self._quit_dialog = ConfirmDialog("A sweep is running. Abort it (setpoint to zero, drive disabled) and "
                                          "quit? (y or q: yes)", "Abort and quit")
        self.push_screen(self._quit_dialog, answered)

    # ------------------------------------------------------------------------------------------ the session
    def _log_path(self) -> Path | None:
        """The bus log of the sweep about to start (``self._runs`` counts it)."""
        if self.log_bus is None or self._runs <= 1:
            return self.log_bus
        return self.log_bus.with_name(f"{self.log_bus.stem}.run{self._runs}{self.log_bus.suffix}")

    def _launch(self, frequency_hz: float | None, resume: dict[int, FrequencyResponse] | None = None) -> None:
        """Start a sweep of every case (``frequency_hz``: re-measure that frequency of the current case; ``resume``:
        continue the interrupted sweeps whose points these are, measuring only what they lack)."""
        from bodebench.apps.plots import write_plots  # matplotlib: only once a sweep starts

        self._runs += 1
        self._resumed = dict(resume or {})
        self.exit_line = ""
        bridge = SessionBridge(self.post_message, self._runs)
        procedure = SweepProcedure(self.config, self.out, listener=bridge,
                                   existing="resume" if resume is not None else "replace",
                                   worker_mode=self.config.cases[0].on_bench.bench.worker_mode(beside_a_ui=True),
                                   plots=write_plots, log_bus=self._log_path())
        if self.tolerance_percent is not None:
            procedure.set_tolerance(self.tolerance_percent)
        control = RunControl(self._runs, procedure)
        self.control, self.bridge = control, bridge
        self.last_fault = self.last_ended = None
        self.state = "starting"
        self.worker_errors = []
        self._max_index = -1
        self.rates.reset()
        if frequency_hz is None:
            self.case_index = 0
        cases = [self.case_index] if frequency_hz is not None else list(range(len(self.config.cases)))
        self.run_worker(partial(self._session_thread, control, bridge, cases, frequency_hz), thread=True,
                        exit_on_error=False, group="session", name=f"session {control.run}")
        self._sync_bindings()
        self._refresh_status()

    def _session_thread(self, control: RunControl, bridge: SessionBridge, cases: list[int],
                        frequency_hz: float | None) -> None:
        """The worker: the sweep procedure over the cases (own thread; talks to the UI only through messages)."""
        completed, error, saved, aborted = False, "", "", False
        procedure = control.procedure
        started = time.perf_counter()
        try:
            outcome: CaseOutcome | None
            if frequency_hz is not None:
                outcome = procedure.remeasure(cases[0], frequency_hz, self.results.get(cases[0]))
            else:
                procedure.run(cases)
                outcome = procedure.current
            completed, aborted = not procedure.aborted, procedure.aborted
            if aborted:
                error = "abort: aborted by the user"
            saved = str(outcome.directory) if outcome is not None else ""
        except SessionError as exc:
            error, aborted = str(exc), exc.kind == FaultKind.ABORT
            current = procedure.current
            if current is not None and current.response.points and frequency_hz is None:
                saved = str(current.directory)
        except Exception as exc:  # noqa: BLE001 - whatever happens is shown, never a traceback on screen
            error = f"{type(exc).__name__}: {exc}"
            self.worker_errors.append(traceback.format_exc())
        finally:
            session = procedure.current.session if procedure.current is not None else None
            control.session_s = time.perf_counter() - started
            control.health = session.last_health if session is not None else None
            control.done.set()
            self.post_message(WorkerReport(control.run, completed, error, saved, aborted))

    # ------------------------------------------------------------------------------------- session messages
    def on_session_event(self, message: SessionEvent) -> None:
        if self.control is None or message.run != self.control.run:
            return
        try:
            self._session_event(message.event)
        except Exception:  # noqa: BLE001 - see _display_error
            self._display_error("a session event")

    def _session_event(self, event: object) -> None:
        self._drain()
        now = time.monotonic()
        if not isinstance(event, OverviewProgress):
            self.overview_periods = None
        if isinstance(event, CaseBegins):
            self.case_index = event.index
            if event.frequency_hz is None:
                self.model = self._new_model(self.case)
                resumed = self._resumed.get(event.index)
                if resumed is not None:  # a resumed sweep: the points it keeps are finished rows
                    added = sorted({p.frequency_hz for p in resumed.points} - set(self.model.frequencies_hz))
                    if added:  # an adaptive plan's, from the earlier run (timed from the session's start)
                        self.model.extend(added, [0.0] * len(added), [0] * len(added))
                    self.model.load_points(resumed.points)
                self.w_table.fill(self.model.rows)
                self.model.take_changed()
                self.live_points = list(resumed.points) if resumed is not None else []
            self._bode_dirty = True
        elif isinstance(event, CaseSaved):
            assert isinstance(event.response, FrequencyResponse)
            self.results[event.index] = event.response
            if event.index == self.case_index:
                self.live_points = list(event.response.points)
            self._bode_dirty = True
        elif isinstance(event, SessionStarted):
            self.where = event.where
            self.watchdog = "armed"
            self.model.session_started(now, event.timer())
            self.state = "paused" if self.control is not None and self.control.paused else "running"
        elif isinstance(event, OverviewProgress):
            self.overview_periods = event.periods
        elif isinstance(event, PlanGrew):
            self.model.extend(event.frequencies_hz, event.extra_periods, event.max_periods)
            self.w_table.fill(self.model.rows)
            self.model.take_changed()
            self.notify(f"the plan adds {len(event.frequencies_hz)} frequencies: "
                        + ", ".join(f"{f:.4g} Hz" for f in event.frequencies_hz), timeout=4)
        elif isinstance(event, PointStarted):
            self.model.point_started(event.index, event.frequency_hz, now, event.tolerance_percent, event.criterion)
            self._max_index = max(self._max_index, event.index)
            self._live_dirty = True
        elif isinstance(event, PointFinished):
            self.model.point_finished(event.index, event.points, event.skipped, now)
            if event.points:
                f = event.points[0].frequency_hz
                self.live_points = [p for p in self.live_points if not math.isclose(p.frequency_hz, f)]
                self.live_points.extend(event.points)
                self._bode_dirty = True
            self._live_dirty = True
        elif isinstance(event, SessionFault):
            self.last_fault = event
            if event.kind == FaultKind.WATCHDOG:
                self.watchdog = "TRIPPED"
            self.model.fail_current()
        elif isinstance(event, SessionEnded):
            self.last_ended = event
            self.model.session_ended(now)
            if self.watchdog != "TRIPPED":
                self.watchdog = "off"
        self._refresh_rows()
        self._refresh_status()
        self._refresh_bus(force=True)
        self._refresh_bode()
        self._sync_bindings()

    def on_worker_report(self, message: WorkerReport) -> None:
        if self.control is None or message.run != self.control.run:
            return
        try:
            self._worker_report(message)
        except Exception:  # noqa: BLE001 - see _display_error
            self._display_error("the end of the sweep")
        if self._quitting:
            self.exit(128 + signal.Signals[self.stopped_by] if self.stopped_by else 0 if message.completed else 1)

    def _stop_line(self, message: WorkerReport) -> str:
        """One line on a sweep that did not complete, as the command line's run gives it: why it stopped, the
        points kept and where, and how the drive was left."""
        fault, ended = self.last_fault, self.last_ended
        if self.stopped_by:
            cause = f"interrupted ({self.stopped_by})"
        elif message.aborted or (fault is not None and fault.kind == FaultKind.ABORT):
            cause = "aborted by the user" + (" (quit)" if self._quitting else "")
        else:
            cause = message.error or "the sweep stopped"
        kept = fault.kept if fault is not None else len(self.live_points)
        where = (f"{kept} points kept in {message.saved}" if kept and message.saved else
                 "no point measured" if not kept else f"{kept} points measured, none written")
        drive = ended.drive_state() if ended is not None else "nothing was sent to the drive"
        return f"bodebench: {self.case.name}: stopped: {cause}; {where}; {drive}"

    def _exit_unjoined(self, status: int) -> None:
        """The sweep's thread has not ended in time: exit all the same, saying the drive's state is not known."""
        control = self.control
        if control is not None and not control.done.is_set():
            self.exit_line = (f"bodebench: {self.case.name}: stopped: the sweep did not end within "
                              f"{JOIN_TIMEOUT_S:g} s of the abort; the drive's state is unknown (points measured are "
                              f"in {case_directory(self.config, self.out, self.case)})")
        self.exit(status)

    def _worker_report(self, message: WorkerReport) -> None:
        self._drain()
        if self.watchdog != "TRIPPED":
            self.watchdog = "off"
        self.model.session_ended(time.monotonic())
        fault, ended = self.last_fault, self.last_ended
        self.exit_line = "" if message.completed else self._stop_line(message)
        if message.completed:
            self.state = "done"
            self.notify(f"sweep complete: results in {message.saved}", timeout=8)
        elif (fault is not None and fault.kind == FaultKind.ABORT) or message.aborted:
            self.state = "aborted"
            kept = fault.kept if fault is not None else 0
            drive = "" if ended is None else f"{ended.drive_state()}; "
            where = f" in {message.saved}" if message.saved else ""
            self.notify(f"aborted: {drive}{kept} points kept{where}", severity="warning", timeout=10)
        else:
            self.state = "failed"
            lines = [message.error or "the sweep stopped"]
            kept = fault.kept if fault is not None else len(self.live_points)
            lines.append(f"{kept} measured points kept" + (f" in {message.saved}" if message.saved else
                                                           " (nothing written)"))
            if ended is not None:
                state = ended.drive_state()
                lines.append(f"{state[0].upper()}{state[1:]} ({ended.reason}).")
            self.push_screen(MessageDialog("Sweep stopped", "\n".join(lines), error=True))
        self._refresh_rows()
        self._refresh_status()
        self._refresh_bus(force=True)
        self._refresh_bode()
        self._sync_bindings()

    # ---------------------------------------------------------------------------------------- refreshing
    def _drain(self) -> None:
        """Apply queued progress in order: the current point's, dropping older points' (O(queued))."""
        bridge = self.bridge
        if bridge is None:
            return
        queue = bridge.progress
        model = self.model
        applied = False
        while queue:
            item = queue[0]
            if item.index > self._max_index:
                break  # its PointStarted is not handled yet
            queue.popleft()
            if item.index == model.current_index:
                model.progress(item.index, item.periods, item.states, item.at)
                applied = True
        if applied:
            self._live_dirty = True

    def _tick(self) -> None:
        try:
            self._refresh_all()
        except Exception:  # noqa: BLE001 - see _display_error
            self._display_error("the periodic refresh")

    def _refresh_all(self) -> None:
        self._drain()
        if self._live_dirty:
            self._live_dirty = False
            self._refresh_live()
        self._ticks += 1
        self._refresh_rows(periods_too=self._ticks % ROW_PERIODS_EVERY == 0)
        self._refresh_bus()
        self._refresh_bode()
        self._refresh_status()

    def _refresh_live(self) -> None:
        model = self.model
        panel = self.w_live
        f = model.frequencies_hz[model.current] if model.current is not None else None
        to_go = [model.series_to_go(t.channel, t.harmonic) for t in model.traces]
        panel.show_convergence(f, model.periods, model.traces, to_go, model.tolerance_percent, model.criterion)
        bridge = self.bridge
        latest = bridge.latest_progress if bridge is not None else None
        # between points and at the end the latest samples stay, also those of a point that began and ended
        # between two refreshes
        if latest is not None and (model.current_index is None or latest.index == model.current_index):
            panel.show_scope(latest.scope, self.case.formed().raw[0])  # the channel the session's scope holds
        elif model.current_index is not None and self._scope_index != model.current_index:
            panel.show_scope(None, "")  # a new point: its samples are yet to come (at the end the last stays)
        self._scope_index = model.current_index

    def _refresh_rows(self, periods_too: bool = True) -> None:
        """Redraw changed rows: at once when a state changed, else (period counts only) when ``periods_too``
        (redrawing the table is one of the UI's dearest operations)."""
        if not (self.model.state_changed or periods_too):
            return
        keys = self.model.take_changed()
        if not keys:
            return
        table = self.w_table
        for key in keys:
            table.update_row(key, self.model.rows[key])

    def _refresh_bus(self, force: bool = False) -> None:
        bridge = self.bridge
        latest = bridge.latest_health if bridge is not None else None
        if latest is not None and latest[0] != self._health_seen:
            self._health_seen, self.health = latest
            bus = self.health.bus
            self.bus_rates = self.rates.update(latest[0], bus.frames_in, bus.frames_out)
        elif not force:
            return
        watchdog_s = self.case.on_bench.safety.watchdog_s
        self.w_bus.show(self.where, self.health, self.bus_rates, self.watchdog, watchdog_s)
        self.w_bus_line.update(bus_summary(self.health, self.bus_rates), layout=False)

    def _current_response(self) -> FrequencyResponse | None:
        """The current case's points: this sweep's so far (or the loaded ones, re-measured points replaced)."""
        if not self.live_points:
            return None
        return FrequencyResponse(self.live_points, config=self.case.raw, case=self.case.name)

    def _refresh_bode(self) -> None:
        if not self._bode_dirty:
            return
        self._bode_dirty = False
        responses: list[tuple[str, FrequencyResponse]] = []
        current = self._current_response()
        if current is not None and len(current):
            responses.append((self.case.name, current))
        for i, response in self.results.items():
            if i != self.case_index and len(response):
                responses.append((self.config.cases[i].name, response))
        responses.extend(self.overlays)
        self.w_bode.show(responses)

    def _show_views(self) -> None:
        for view in VIEWS:
            self._panels()[view].set_class(view == self.view, "-current")
        bar = Text()
        for i, view in enumerate(VIEWS, start=1):
            style = "reverse bold" if view == self.view else ""
            bar.append(f" {i} {VIEW_TITLES[view]} ", style=style)
        self.w_views.update(bar)

    def _refresh_status(self) -> None:
        now = time.monotonic()
        model = self.model
        state = self.state
        colours = {"running": "bold green", "paused": "bold yellow", "aborting": "bold red", "aborted": "bold red",
                   "failed": "bold red", "done": "bold green", "starting": "bold yellow"}
        text = Text()
        text.append(f" {state.upper()} ", style=f"reverse {colours.get(state, 'bold')}")
        text.append(f" {self.case.name}")
        done, total = model.done, model.total
        width = 10
        filled = round(width * done / total) if total else 0
        text.append(f"  {done}/{total} ")
        text.append("█" * filled, style="green")
        text.append("░" * (width - filled), style="bright_black")
        elapsed = model.elapsed(now)
        text.append(f" {format_duration(elapsed)}")
        text.append(f" ETA {format_duration(model.eta(now))}")
        tol = self.tolerance_percent if self.tolerance_percent is not None else self.case.analysis.tolerance_percent
        text.append(f"  tol {tol:g} %")
        if self.overview_periods is not None:
            text.append(f"  overview first: {self.overview_periods} periods", style="bold cyan")
        if text != self._status_text:
            self._status_text = text
            self.w_status.update(text, layout=False)
            counts: dict[str, int] = {}
            for row in model.rows.values():
                counts[row.state] = counts.get(row.state, 0) + 1
            summary = Text(f"{done}/{total} frequencies  elapsed {format_duration(elapsed)}  "
                           f"to finish {format_duration(model.eta(now))}  ")
            for name, count in counts.items():
                summary.append(f" {name} {count}", style=STATE_STYLES.get(name, ""))
            self.w_sweep.progress.update(summary, layout=False)
        self.w_abort.set_class(not self.running, "-idle")

    # -------------------------------------------------------------------------------------------- exit
    def _stop_signal(self, signum: int) -> None:
        self.stopped_by = signal.Signals(signum).name
        self._quitting = True
        if self.running:
            self.action_abort()
            self.set_timer(JOIN_TIMEOUT_S, partial(self._exit_unjoined, 128 + signum))
        else:
            self.exit(128 + signum)

    def on_unmount(self) -> None:
        """Whatever ends the app: abort a running sweep and join its thread (the drive is left at zero)."""
        self.stop_session(JOIN_TIMEOUT_S)
        loop = asyncio.get_running_loop()
        for signum in getattr(self, "_signals", []):
            loop.remove_signal_handler(signum)

    def stop_session(self, timeout_s: float) -> bool:
        """Abort a running sweep and wait up to ``timeout_s`` for its thread; True when it has ended."""
        control = self.control
        if control is None:
            return True
        if not control.done.is_set():
            control.procedure.request_abort()
        return control.done.wait(timeout_s)


def run_tui(config: ExperimentConfig, out: Path, **options: Any) -> int:
    """Open the UI on a bench config; returns the exit status (0: quit normally)."""
    app = BodeBenchApp(config, out, **options)
    status = app.run()
    if app.exit_line:
        print(app.exit_line, file=sys.stderr)
    return int(status or 0)
