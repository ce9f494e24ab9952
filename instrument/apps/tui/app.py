"""The terminal UI of a bench session (``bodebench tui CONFIG``).

The sweep runs in a Textual thread worker; its listener (:class:`~bodebench.apps.tui.bridge.SessionBridge`)
queues rare events as messages to the main screen (:class:`~bodebench.apps.tui.screen.SweepScreen`) and leaves
the frequent ones for its refresh timer, so the measurement never waits on the screen. Every way out of the app
(q, Ctrl+Q, an error) aborts a running sweep and joins its thread first: the session leaves the drive at setpoint
zero, disabled. When the last sweep did not complete, :func:`run_tui` prints one line on exit saying why, how many
points are kept where, and how the drive was left.
Exit status: 0 after a quit with no sweep running, 1 when the quit aborted a running sweep, 128 + N after signal
N (SIGTERM, SIGHUP).
"""

from __future__ import annotations

import asyncio
import signal
import sys
import traceback
from functools import partial
from pathlib import Path
from typing import Any

from textual.app import App
from textual.binding import Binding
from textual.screen import ModalScreen, Screen

from bodebench.apps.tui.bridge import SessionBridge
from bodebench.apps.tui.dialogs import ConfirmDialog
from bodebench.apps.tui.screen import SweepScreen
from bodebench.apps.tui.worker import RunControl, run_sweep
from bodebench.bench.procedure import SweepProcedure, case_directory
from bodebench.core.response import FrequencyResponse
from bodebench.io.config import ExperimentConfig

JOIN_TIMEOUT_S = 30.0


class BodeBenchApp(App[int]):
    """Sweep the cases of a bench config (``config``), writing results under ``out``.

    The app runs the sweep's thread (:meth:`start_sweep`, steered through ``control``) and ends it on every way
    out; what the sweep shows, and the keys that steer it, are the main screen's (``sweep_screen``).
    """

    TITLE = "bodebench"
    ENABLE_COMMAND_PALETTE = False
    BINDINGS = [Binding("q", "request_quit", "quit")]

    def __init__(self, config: ExperimentConfig, out: Path, refresh_hz: float = 5.0, log_bus: Path | None = None
                 ) -> None:
        """refresh_hz: redraws of the views per second; log_bus: a log of the bus traffic of each sweep (the second
        sweep's as ``<stem>.run2<suffix>``, ...)."""
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
        self.control: RunControl | None = None
        self.bridge: SessionBridge | None = None
        self.worker_errors: list[str] = []  # tracebacks of the last sweep's thread and of faults in drawing
        self.quitting = False  # a quit is under way (a running sweep is being aborted first)
        self.stopped_by = ""  # the signal that ended the app, if one did
        self.exit_line = ""  # printed on exit: how the last sweep ended, when it did not complete
        self.sweep_screen = SweepScreen(config, self.out, refresh_hz)
        self._runs = 0
        self._signals: list[int] = []
        self._quit_dialog: ConfirmDialog | None = None
        self._display_error_shown = False

    def get_default_screen(self) -> SweepScreen:
        return self.sweep_screen

    @property
    def running(self) -> bool:
        """Whether a sweep's thread runs."""
        return self.control is not None and not self.control.done.is_set()

    @property
    def paused(self) -> bool:
        """Whether the running sweep is paused."""
        control = self.control
        return bool(self.running and control is not None and control.paused)

    def is_current(self, run: int) -> bool:
        """Whether ``run`` is the last sweep started (the messages of earlier ones are stale)."""
        return self.control is not None and run == self.control.run

    def modal_open(self) -> bool:
        """Whether a dialog is open."""
        try:
            return isinstance(self.screen, ModalScreen)
        except Exception:  # noqa: BLE001 - no screen yet (or any more)
            return False

    def display_error(self, where: str) -> None:
        """A fault in drawing is reported, not fatal: the measurement goes on (traceback kept for diagnosis)."""
        self.worker_errors.append(traceback.format_exc())
        if not self._display_error_shown:
            self._display_error_shown = True
            self.notify(f"display error in {where}: {traceback.format_exc(limit=0).strip()}", severity="error",
                        timeout=10)

    def on_mount(self) -> None:
        # SIGTERM (timeout, systemd) and SIGHUP (a closed terminal) quit as a confirmed quit does: the running
        # sweep is aborted (setpoint to zero, drive disabled) and joined before the app ends
        loop = asyncio.get_running_loop()
        for signum in [getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)]:
            try:
                loop.add_signal_handler(signum, self._stop_signal, signum)
            except (NotImplementedError, RuntimeError, ValueError):  # not the main thread: the signal stays as it is
                continue
            self._signals.append(signum)
        self.screen_change_signal.subscribe(self, self._screen_changed)

    def _screen_changed(self, screen: Screen[Any]) -> None:
        """A dialog opened or closed: the footer shows the keys that work under it."""
        self.sweep_screen.sync_bindings()

    # ------------------------------------------------------------------------------------------------ keys
    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """Whether one of the app's keys works now. Under a dialog only the keys the dialog passes on to the app
        (its ``APP_KEYS``) and Ctrl+Q work, so the footer shows only those; while the app quits, only abort."""
        if self.modal_open() and action != "quit" and action not in getattr(self.screen, "APP_KEYS", ()):
            return False  # "quit" is Ctrl+Q (not in the footer), which works everywhere
        if self.quitting:  # the sweep is being aborted before the app ends: nothing else to do
            return action == "abort"
        if action == "abort":
            return self.running
        return True

    def action_abort(self) -> None:
        """Abort the running sweep (the session leaves the drive at setpoint zero, disabled)."""
        control = self.control
        if control is None or control.done.is_set():
            self.notify("no sweep running")
            return
        control.procedure.request_abort()
        self.sweep_screen.show_aborting()

    async def action_request_quit(self) -> None:
        """q (in the question and message dialogs too; the input dialog types it)."""
        await self.action_quit()

    async def action_quit(self) -> None:
        """q or Ctrl+Q: quit; while a sweep runs, ask first (q again answers yes)."""
        if self.quitting:
            return
        if not self.running:
            self.quitting = True
            self.exit(0)
            return
        if self._quit_dialog is not None and self.screen is self._quit_dialog:
            self._quit_dialog.dismiss(True)
            return

        def answered(yes: bool | None) -> None:
            self._quit_dialog = None
            if yes and not self.quitting:
                self.quitting = True
                self.sweep_screen.sync_bindings()
                if self.running:
                    self.action_abort()
                    self.notify("aborting the sweep before quitting ...")
                    self.set_timer(JOIN_TIMEOUT_S, partial(self._exit_unjoined, 1))
                else:  # it ended while the question was open
                    self.exit(0)

        self._quit_dialog = ConfirmDialog("A sweep is running. Abort it (setpoint to zero, drive disabled) and "
                                          "quit? (y or q: yes)", "Abort and quit")
        self.push_screen(self._quit_dialog, answered)

    # ------------------------------------------------------------------------------------- the sweep's thread
    def _log_path(self) -> Path | None:
        """The bus log of the sweep about to start (``self._runs`` counts it)."""
        if self.log_bus is None or self._runs <= 1:
            return self.log_bus
        return self.log_bus.with_name(f"{self.log_bus.stem}.run{self._runs}{self.log_bus.suffix}")

    def start_sweep(self, cases: list[int], frequency_hz: float | None, base: FrequencyResponse | None,
                    tolerance_percent: float | None, resume: bool = False) -> None:
        """Start the sweep's thread over ``cases`` (``frequency_hz``: measure that frequency of the one case again,
        into its response ``base``; ``tolerance_percent``: for every point, None: as configured; ``resume``:
        continue the interrupted sweeps in the out directory). Its messages go to the main screen."""
        from bodebench.apps.plots import write_plots  # matplotlib: only once a sweep starts

        self._runs += 1
        self.exit_line = ""
        post = self.sweep_screen.post_message
        bridge = SessionBridge(post, self._runs)
        procedure = SweepProcedure(self.config, self.out, listener=bridge, existing="resume" if resume else "replace",
                                   worker_mode=self.config.cases[0].on_bench.bench.worker_mode(beside_a_ui=True),
                                   plots=write_plots, log_bus=self._log_path())
        if tolerance_percent is not None:
            procedure.set_tolerance(tolerance_percent)
        control = RunControl(self._runs, procedure)
        self.control, self.bridge = control, bridge
        self.worker_errors = []
        self.run_worker(partial(run_sweep, control, cases, frequency_hz, base, post, self.worker_errors), thread=True,
                        exit_on_error=False, group="session", name=f"session {control.run}")

    def sweep_ended(self, completed: bool, stop_line: str) -> None:
        """The sweep's thread has ended and the screen has shown how: ``stop_line`` is printed on exit (empty when
        the sweep completed); a quit waiting for the sweep ends the app."""
        self.exit_line = stop_line
        if self.quitting:
            self.exit(128 + signal.Signals[self.stopped_by] if self.stopped_by else 0 if completed else 1)

    def _stop_signal(self, signum: int) -> None:
        self.stopped_by = signal.Signals(signum).name
        self.quitting = True
        if self.running:
            self.action_abort()
            self.set_timer(JOIN_TIMEOUT_S, partial(self._exit_unjoined, 128 + signum))
        else:
            self.exit(128 + signum)

    def _exit_unjoined(self, status: int) -> None:
        """The sweep's thread has not ended in time: exit all the same, saying the drive's state is not known."""
        control = self.control
        if control is not None and not control.done.is_set():
            case = self.sweep_screen.case
            self.exit_line = (f"bodebench: {case.name}: stopped: the sweep did not end within "
                              f"{JOIN_TIMEOUT_S:g} s of the abort; the drive's state is unknown (points measured are "
                              f"in {case_directory(self.config, self.out, case)})")
        self.exit(status)

    def on_unmount(self) -> None:
        """Whatever ends the app: abort a running sweep and join its thread (the drive is left at zero)."""
        self.stop_session(JOIN_TIMEOUT_S)
        loop = asyncio.get_running_loop()
        for signum in self._signals:
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
