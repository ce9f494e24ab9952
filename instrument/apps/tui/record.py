"""What the main screen knows of a sweep: the current case and its rows, the latest response of every case, the
current case's points, how the last session ended."""

from __future__ import annotations

import math

from bodebench.apps.tui.bridge import SessionBridge, WorkerReport
from bodebench.apps.tui.model import SweepModel
from bodebench.bench.events import CaseBegins, CaseSaved, PointFinished, PointStarted, SessionEnded, SessionFault
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.io.config import CaseConfig, ExperimentConfig
from bodebench.status import FaultKind


def sweep_model(case: CaseConfig) -> SweepModel:
    """The rows of a sweep of ``case``, none measured."""
    return SweepModel(case.excitation.frequencies_hz, case.analysis.harmonics, case.analysed_channels)


class SweepRecord:
    """The sweep of the cases of ``config`` as the UI follows it.

    ``model`` holds the rows of the current case (``case_index``); ``results`` the latest finished or loaded
    response of each case; ``points`` the current case's points so far (loaded ones, re-measured points
    replaced); ``resumed`` the points each case of a resumed sweep continues from.
    """

    def __init__(self, config: ExperimentConfig) -> None:
        self.config = config
        self.case_index = 0
        self.model = sweep_model(self.case)
        self.results: dict[int, FrequencyResponse] = {}
        self.points: list[ResponsePoint] = []
        self.resumed: dict[int, FrequencyResponse] = {}
        self.last_fault: SessionFault | None = None
        self.last_ended: SessionEnded | None = None
        self.last_started = -1  # event index of the latest point started in this run

    @property
    def case(self) -> CaseConfig:
        return self.config.cases[self.case_index]

    def load(self, results: dict[int, FrequencyResponse]) -> bool:
        """Show the results read from disk ({case index: response}); True when the first case has some."""
        self.results.update(results)
        if 0 not in self.results:
            return False
        self.model.load_points(self.results[0].points)
        self.points = list(self.results[0].points)
        return True

    def new_run(self, whole_sweep: bool, resume: dict[int, FrequencyResponse] | None) -> None:
        """A sweep starts: of every case from the first (``whole_sweep``), or a point of the current case again;
        ``resume``: the points of the interrupted sweeps it continues."""
        self.resumed = dict(resume or {})
        self.last_fault = self.last_ended = None
        self.last_started = -1
        if whole_sweep:
            self.case_index = 0

    def begin_case(self, event: CaseBegins) -> bool:
        """A case begins; True when its rows are new (a sweep of the case, not a point measured again)."""
        self.case_index = event.index
        if event.frequency_hz is not None:
            return False
        self.model = sweep_model(self.case)
        resumed = self.resumed.get(event.index)
        if resumed is not None:  # a resumed sweep: the points it keeps are finished rows
            added = sorted({p.frequency_hz for p in resumed.points} - set(self.model.frequencies_hz))
            if added:  # an adaptive plan's, from the earlier run (timed from the session's start)
                self.model.extend(added, [0.0] * len(added), [0] * len(added))
            self.model.load_points(resumed.points)
        self.points = list(resumed.points) if resumed is not None else []
        return True

    def case_saved(self, event: CaseSaved) -> None:
        assert isinstance(event.response, FrequencyResponse)
        self.results[event.index] = event.response
        if event.index == self.case_index:
            self.points = list(event.response.points)

    def point_started(self, event: PointStarted, now: float) -> None:
        self.model.point_started(event.index, event.frequency_hz, now, event.tolerance_percent, event.criterion)
        self.last_started = max(self.last_started, event.index)

    def point_finished(self, event: PointFinished, now: float) -> bool:
        """A point ended; True when it brought points (they replace those of its frequency)."""
        self.model.point_finished(event.index, event.points, event.skipped, now)
        if not event.points:
            return False
        f = event.points[0].frequency_hz
        self.points = [p for p in self.points if not math.isclose(p.frequency_hz, f)]
        self.points.extend(event.points)
        return True

    def fault(self, event: SessionFault) -> None:
        self.last_fault = event
        self.model.fail_current()

    def session_ended(self, event: SessionEnded, now: float) -> None:
        self.last_ended = event
        self.model.session_ended(now)

    def drain(self, bridge: SessionBridge | None) -> bool:
        """Apply the progress ``bridge`` queued, in order: the current point's, dropping older points'
        (O(queued)); True when some was applied."""
        if bridge is None:
            return False
        queue = bridge.progress
        model = self.model
        applied = False
        while queue:
            item = queue[0]
            if item.index > self.last_started:
                break  # its PointStarted is not handled yet
            queue.popleft()
            if item.index == model.current_index:
                model.progress(item.index, item.periods, item.states, item.at)
                applied = True
        return applied

    def current_response(self) -> FrequencyResponse | None:
        """The current case's points as a response (None: no points)."""
        if not self.points:
            return None
        return FrequencyResponse(self.points, config=self.case.raw, case=self.case.name)

    def responses(self) -> list[tuple[str, FrequencyResponse]]:
        """(case name, response) of every case with points: the current case's first."""
        responses: list[tuple[str, FrequencyResponse]] = []
        current = self.current_response()
        if current is not None and len(current):
            responses.append((self.case.name, current))
        for i, response in self.results.items():
            if i != self.case_index and len(response):
                responses.append((self.config.cases[i].name, response))
        return responses

    def outcome(self, report: WorkerReport) -> str:
        """How the sweep whose thread ended with ``report`` went: done, aborted (by the user) or failed."""
        fault = self.last_fault
        if report.completed:
            return "done"
        if (fault is not None and fault.kind == FaultKind.ABORT) or report.aborted:
            return "aborted"
        return "failed"

    def abort_notice(self, report: WorkerReport) -> str:
        """What an aborted sweep left: the drive's state, the points kept and where."""
        fault, ended = self.last_fault, self.last_ended
        kept = fault.kept if fault is not None else 0
        drive = "" if ended is None else f"{ended.drive_state()}; "
        where = f" in {report.saved}" if report.saved else ""
        return f"aborted: {drive}{kept} points kept{where}"

    def failure_text(self, report: WorkerReport) -> str:
        """Why a failed sweep stopped, the points it kept and where, and how the drive was left (lines)."""
        fault, ended = self.last_fault, self.last_ended
        lines = [report.error or "the sweep stopped"]
        kept = fault.kept if fault is not None else len(self.points)
        lines.append(f"{kept} measured points kept" + (f" in {report.saved}" if report.saved else " (nothing written)"))
        if ended is not None:
            state = ended.drive_state()
            lines.append(f"{state[0].upper()}{state[1:]} ({ended.reason}).")
        return "\n".join(lines)

    def stop_line(self, report: WorkerReport, stopped_by: str, quitting: bool) -> str:
        """One line on a sweep that did not complete, as the command line's run gives it: why it stopped (the
        signal ``stopped_by``, the user's abort, on quitting or not, an error), the points kept and where, and
        how the drive was left."""
        fault, ended = self.last_fault, self.last_ended
        if stopped_by:
            cause = f"interrupted ({stopped_by})"
        elif report.aborted or (fault is not None and fault.kind == FaultKind.ABORT):
            cause = "aborted by the user" + (" (quit)" if quitting else "")
        else:
            cause = report.error or "the sweep stopped"
        kept = fault.kept if fault is not None else len(self.points)
        where = (f"{kept} points kept in {report.saved}" if kept and report.saved else
                 "no point measured" if not kept else f"{kept} points measured, none written")
        drive = ended.drive_state() if ended is not None else "nothing was sent to the drive"
        return f"bodebench: {self.case.name}: stopped: {cause}; {where}; {drive}"
