"""The sweep's thread: the sweep procedure over the cases, steered through a :class:`RunControl`, reporting its end
as a :class:`~bodebench.apps.tui.bridge.WorkerReport`."""

from __future__ import annotations

import math
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field

from textual.message import Message

from bodebench.apps.tui.bridge import WorkerReport
from bodebench.bench.events import Health, SessionError
from bodebench.bench.procedure import CaseOutcome, SweepProcedure
from bodebench.core.response import FrequencyResponse
from bodebench.status import FaultKind


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


def run_sweep(control: RunControl, cases: list[int], frequency_hz: float | None, base: FrequencyResponse | None,
              post: Callable[[Message], object], errors: list[str]) -> None:
    """Run the sweep of ``control`` over ``cases`` (``frequency_hz``: measure that frequency of the one case again,
    into its response ``base``); on its own thread, talking to the UI only through ``post``. Ends by setting
    ``control.done`` and posting a WorkerReport; the traceback of an unexpected error is appended to ``errors``."""
    completed, error, saved, aborted = False, "", "", False
    procedure = control.procedure
    started = time.perf_counter()
    try:
        outcome: CaseOutcome | None
        if frequency_hz is not None:
            outcome = procedure.remeasure(cases[0], frequency_hz, base)
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
        errors.append(traceback.format_exc())
    finally:
        session = procedure.current.session if procedure.current is not None else None
        control.session_s = time.perf_counter() - started
        control.health = session.last_health if session is not None else None
        control.done.set()
        post(WorkerReport(control.run, completed, error, saved, aborted))
