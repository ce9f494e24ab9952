"""The sweep procedure: every case of a configuration, in turn, from resume to the files on disk.

One procedure serves the command line and the terminal UI, on a bench (a :class:`BenchSession` per case, over a
bus or with the simulated drive in-process) and offline (the simulated plant, frequencies on an executor). It owns
the case loop: it refuses a results directory that already holds another sweep before anything is measured,
continues an interrupted sweep on request, appends each point to ``response.csv`` as it is measured (the session,
or the offline sweep through a :class:`ResultsWriter`), and writes the plots of each case at its end through the
``plots`` callable the application gives (this floor draws nothing). Listeners receive the events of
:mod:`bodebench.bench.events`, :class:`CaseBegins` and :class:`CaseSaved` around each case's own.
"""

from __future__ import annotations

import functools
import json
import logging
import math
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bodebench.bench.adaptive import GrowingPlan
from bodebench.bench.controls import SweepControls
from bodebench.bench.events import (
    CaseBegins,
    CaseSaved,
    Listener,
    OverviewProgress,
    PlanGrew,
    PointFinished,
    PointStarted,
    SessionEnded,
    SessionError,
    point_not_written,
)
from bodebench.bench.runinfo import RunClock, run_record
from bodebench.bench.session import BenchSession, SessionResult, completed_frequencies
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.core.summary import ResponseSummary, summarize_response
from bodebench.io.config import CaseConfig, ExperimentConfig
from bodebench.io.results import (
    CSV_NAME,
    PLOT_FIGURES,
    SIDECAR_NAME,
    ResultsError,
    ResultsWriter,
    check_output,
    load_response,
    save_response,
    sidecar_runs,
    update_sidecar,
    verify_results,
)
from bodebench.io.samples import SAMPLES_DIR, samples_path
from bodebench.status import FaultKind

if TYPE_CHECKING:
    from bodebench.bench.overview import OverviewResult

log = logging.getLogger("bodebench.sweep")

OVERVIEW_DIR = "overview"
"""Where an adaptive case's overview, run before its grid (``adaptive.from_overview``), keeps its files."""

PlotWriter = Callable[..., list[Path]]
"""Draws a finished case: (response, directory, title, summary=..., figures=...) -> the files written; figures: those
of PLOT_FIGURES to draw (all by default)."""


def case_directory(config: ExperimentConfig, out: Path, case: CaseConfig) -> Path:
    """Where a case's results go: ``out`` itself for a file without [cases], else ``out/<case name>``."""
    return out / case.name if config.has_cases else out


def bus_log_path(path: Path, config: ExperimentConfig, case: CaseConfig) -> Path:
    """Where a case's bus log goes: ``path`` itself for a file without [cases], else ``path`` with the case's name
    before its suffix (``bus.asc`` -> ``bus.<case>.asc``)."""
    return path.with_name(f"{path.stem}.{case.name}{path.suffix}") if config.has_cases else path


EXISTING = ("refuse", "resume", "resume_changed", "replace")
"""What to do with results already in a case's directory: refuse to start, continue that sweep, or replace it
(the user said so)."""


def previous_run(directory: Path, case: CaseConfig, existing: str = "refuse") -> FrequencyResponse | None:
    """The interrupted sweep of ``case`` in ``directory`` to continue, or None when there is none (or when
    ``existing`` is "replace").

    Raises ResultsError when the directory holds results and ``existing`` is "refuse" (nothing is overwritten),
    when they are to be resumed but were made with another configuration, or when a row or samples file changed,
    vanished or appeared since it was written (its checksum in the sidecar) and ``existing`` is not
    "resume_changed"."""
    if existing not in EXISTING:
        raise ValueError(f"existing must be one of {', '.join(EXISTING)}, got {existing!r}")
    if existing == "replace" or not (directory / CSV_NAME).exists():
        return None
    if existing == "refuse":
        raise ResultsError(f"{directory / CSV_NAME}: results already here; --resume continues that sweep, "
                           "or choose another --out")
    checked, changed = verify_results(directory)
    if changed and existing != "resume_changed":
        raise ResultsError(f"{directory}: changed since it was written: {'; '.join(changed)}; cannot resume "
                           "(--accept-changes resumes with the files as they are)")
    for line in changed:
        log.warning("%s: %s (resumed as it is, --accept-changes)", directory, line)
    if not checked:
        log.warning("%s: made without checksums: what was edited since cannot be told", directory / SIDECAR_NAME)
    previous = load_response(directory, drop_torn_row=True)
    frequencies = sorted({p.frequency_hz for p in previous.points})
    missing = [f for f in frequencies if not samples_path(directory, f).exists()]
    if missing and not checked and (directory / SAMPLES_DIR).exists():  # with checksums, a vanished file is above
        log.warning("%s: %d of the %d frequencies already measured have no samples file (%s Hz): deleted, or measured "
                    "without them; analyse cannot recompute those points", directory / SAMPLES_DIR, len(missing),
                    len(frequencies), ", ".join(f"{f:g}" for f in missing))
    before, wanted = _what_is_measured(previous.config), _what_is_measured(FrequencyResponse(config=case.raw).config)
    if before != wanted:
        changed = _differences(before, wanted)
        shown = "; ".join(changed[:5]) + (f"; and {len(changed) - 5} more" if len(changed) > 5 else "")
        raise ResultsError(f"{directory / SIDECAR_NAME}: made with another configuration ({shown}); cannot resume")
    return previous


def _differences(before: Any, now: Any, key: str = "") -> list[str]:
    """Each key whose value differs between two configurations (dicts), in words: ``analysis.tolerance_percent:
    0.01 in the results, 0.1 now``."""
    if isinstance(before, dict) and isinstance(now, dict):
        out: list[str] = []
        for name in sorted(set(before) | set(now), key=str):
            out += _differences(before.get(name, _ABSENT), now.get(name, _ABSENT), f"{key}.{name}" if key else
                                str(name))
        return out
    if before == now:
        return []

    def show(value: Any) -> str:
        return "absent" if value is _ABSENT else json.dumps(value, default=str)

    return [f"{key}: {show(before)} in the results, {show(now)} now"]


_ABSENT = object()


WHERE_THE_DRIVE_IS = {"serial": ("port",), "can": ("interface", "channel")}
"""Keys that say only how the drive is reached (a pseudo-terminal's number changes every run, an adapter may be
swapped): a sweep resumed with others is the same measurement."""


def _what_is_measured(config: dict) -> dict:
    """``config`` (a sidecar's) without the keys of :data:`WHERE_THE_DRIVE_IS`."""
    out = dict(config)
    for table, keys in WHERE_THE_DRIVE_IS.items():
        if isinstance(out.get(table), dict):
            out[table] = {k: v for k, v in out[table].items() if k not in keys}
    return out


@dataclass
class CaseOutcome:
    """One case as the procedure left it: where, what was measured, and the session that measured it (bench)."""

    index: int
    case: CaseConfig
    directory: Path
    response: FrequencyResponse
    files: tuple[Path, ...] = ()
    session: BenchSession | None = None
    result: SessionResult | None = None
    summary: tuple[ResponseSummary, ...] = ()
    clock: RunClock = field(default_factory=RunClock)
    earlier_runs: list[dict[str, Any]] = field(default_factory=list)
    resumed: bool = False
    plan: GrowingPlan | None = None
    """An adaptive case's plan as it grew (None: the planned frequencies only)."""
    overview_ended: SessionEnded | None = None
    """How the overview an adaptive plan ran first on the bench ended (None: none ran)."""

    @property
    def ended(self) -> SessionEnded | None:
        """How the case's last run on the drive ended: its session's, else its overview's (None: nothing ran)."""
        if self.session is not None and self.session.ended is not None:
            return self.session.ended
        return self.overview_ended


LEAST_ANALYSED_PERIODS = 8
"""Periods the default rule analyses at the least before it can stop."""


def least_setpoints(case: CaseConfig) -> int:
    """Setpoints a bench sweep of ``case`` takes at the least: at ``rate_hz``, each frequency's settle periods, the
    periods the rule skips and the least it analyses."""
    bench = case.on_bench.bench
    skip = case.analysis.skip_periods + LEAST_ANALYSED_PERIODS
    return int(bench.rate_hz * sum((case.excitation.settle_at(f) + skip) / f for f in case.excitation.frequencies_hz))


class SweepProcedure:
    """Runs the cases of ``config`` into ``out`` (see the module docstring).

    direct: a bench config's simulated drive called in-process, without a bus (``bodebench simulate``);
    existing: what to do with results already in a case's directory (:data:`EXISTING`); worker_mode: where the
    bus worker runs (None: as the config says); executor: where offline frequencies run (None: in this thread,
    in order); plots: draws each finished case (None: no plots); log_bus: a log of each bench case's traffic on the
    bus (:func:`bus_log_path`; None: none); keep_samples: save each frequency's raw samples in ``samples/``
    (:mod:`bodebench.io.samples`); drawer: where an offline sweep's plots are drawn (None: on ``executor``).

    Requests from other threads (:meth:`request_abort`, :meth:`set_paused`, :meth:`request_skip`,
    :meth:`set_tolerance`) reach the running session and every case after it.
    """

    def __init__(self, config: ExperimentConfig, out: Path, *, listener: Listener | None = None,
                 direct: bool = False, existing: str = "refuse", worker_mode: str | None = None,
                 executor: Executor | None = None, plots: PlotWriter | None = None, log_bus: Path | None = None,
                 keep_samples: bool = True, drawer: Executor | None = None) -> None:
        self.config = config
        self.out = Path(out)
        self.listener: Listener = listener or (lambda event: None)
        self.direct = direct
        self.existing = existing
        self.worker_mode = worker_mode
        self.executor = executor
        self.drawer = drawer
        self.plots = plots
        self.log_bus = log_bus
        self.keep_samples = keep_samples
        self.outcomes: list[CaseOutcome] = []
        self.measuring: list[CaseOutcome] = []
        """Offline: every case measured at once, begun or not (each point on disk as it comes)."""
        self.current: CaseOutcome | None = None
        self.controls = SweepControls()
        """The user's requests, shared with every bench session of the sweep."""

    # --- requests (any thread)
    def request_abort(self) -> None:
        """Stop the sweep, every case of it."""
        self.controls.request_abort()

    def set_paused(self, paused: bool) -> None:
        """Pause or resume the analysis."""
        self.controls.set_paused(paused)

    def request_skip(self) -> None:
        """End the point being measured, without a result (nothing while no session runs)."""
        if self.current is not None and self.current.session is not None:
            self.controls.request_skip()

    def request_remeasure(self, frequency_hz: float) -> bool:
        """Measure ``frequency_hz`` again, next, in the running session; False when no session runs yet."""
        if self.current is None or self.current.session is None:
            return False
        self.controls.request_remeasure(frequency_hz)
        return True

    def set_tolerance(self, tolerance_percent: float) -> None:
        """The stopping tolerance (percent) of every point not yet started."""
        self.controls.set_tolerance(tolerance_percent)

    @property
    def aborted(self) -> bool:
        return self.controls.aborted

    # --- the procedure
    def run(self, cases: Sequence[int] | None = None) -> list[CaseOutcome]:
        """Sweep the cases (indices into ``config.cases``; None: all) and return their outcomes.

        Every results directory is checked before the first setpoint. A case that stops early raises what
        stopped it (SessionError, KeyboardInterrupt, ...) after its kept points' plots are drawn; ``current`` is
        that case's outcome."""
        indices = list(range(len(self.config.cases))) if cases is None else list(cases)
        previous = {i: previous_run(self._directory(i), self.config.cases[i], self.existing) for i in indices}
        if all(self.config.cases[i].bench is None for i in indices):
            self._offline_cases(indices, previous)
            return self.outcomes
        for i in indices:
            if self.controls.aborted:
                break
            self._run_case(i, previous[i])
        return self.outcomes

    def remeasure(self, index: int, frequency_hz: float, base: FrequencyResponse | None) -> CaseOutcome:
        """Measure one frequency of bench case ``index`` again and save ``base`` (the case's points so far) with
        that frequency's points replaced."""
        case = replace(self._case(index), excitation=self._case(index).excitation.only(frequency_hz))
        directory = self._directory(index)
        self.listener(CaseBegins(index, case.name, directory, frequency_hz))
        outcome = CaseOutcome(index, case, directory, FrequencyResponse(config=case.raw, case=case.name),
                              earlier_runs=sidecar_runs(directory))
        self.current = outcome
        result = self._bench_case(outcome, None, write=False)
        merged = merge_frequency(base or FrequencyResponse(config=case.raw, case=case.name),
                                 result.response.points, frequency_hz)
        outcome.response = merged
        if (self.keep_samples and outcome.session is not None and outcome.session.last_samples is not None
                and result.response.points):
            outcome.session.last_samples.save(directory)
        save_response(merged, directory)
        self._finish(outcome)
        return outcome

    # --- inside
    def _case(self, index: int) -> CaseConfig:
        """Case ``index`` with the tolerance the user set since the start, if any (config and saved copy alike)."""
        case = self.config.cases[index]
        tolerance = self.controls.tolerance_percent
        if tolerance is None:
            return case
        raw = {**case.raw, "analysis": {**case.raw.get("analysis", {}), "tolerance_percent": tolerance}}
        return replace(case, analysis=replace(case.analysis, tolerance_percent=tolerance), raw=raw)

    def _directory(self, index: int) -> Path:
        return case_directory(self.config, self.out, self.config.cases[index])

    def _run_case(self, index: int, previous: FrequencyResponse | None) -> None:
        if self.config.cases[index].bench is None:
            self._offline_cases([index], {index: previous})
            return
        case = self._case(index)
        directory = self._directory(index)
        log.info("case %s: %d frequencies -> %s%s", case.name, len(case.excitation.frequencies_hz), directory,
                 f" (resuming after {len(previous.points)} points)" if previous else "")
        for note in case.plan_notes:
            log.warning("case %s: %s", case.name, note)
        self.listener(CaseBegins(index, case.name, directory))
        outcome = CaseOutcome(index, case, directory, FrequencyResponse(config=case.raw, case=case.name),
                              earlier_runs=sidecar_runs(directory) if previous is not None else [],
                              resumed=previous is not None)
        self.current = outcome
        self.outcomes.append(outcome)
        try:
            result = self._bench_case(outcome, previous, write=True)
        except BaseException:
            outcome.response = outcome.session.response if outcome.session else outcome.response
            ended = outcome.session.ended if outcome.session is not None else None
            # every run that sent the drive a frame leaves its record, point or none
            if outcome.response.points or (ended is not None and ended.frames_out):
                try:
                    self._summarize(outcome, completed=False)
                    if outcome.response.points:
                        self._draw(outcome)
                except (SessionError, ResultsError):
                    pass  # the record or the plots only: the points are on disk already
            raise
        outcome.response = latest_points(result.response)
        if len(outcome.response) < len(result.response):  # a frequency measured again: its first rows go
            save_response(outcome.response, outcome.directory)
        self._finish(outcome)

    def _bench_case(self, outcome: CaseOutcome, previous: FrequencyResponse | None, *, write: bool
                    ) -> SessionResult:
        from bodebench.bench.connection import plan_link

        bus_log = "" if self.log_bus is None else str(bus_log_path(self.log_bus, self.config, outcome.case))
        growing = GrowingPlan.of(outcome.case)
        if growing is not None and growing.adaptive.from_overview and previous is None:
            from bodebench.bench.overview import measure_overview_on_bench

            log.info("case %s: the overview first", outcome.case.name)
            self.listener(self._seed(outcome, growing, measure_overview_on_bench(
                outcome.case, plan_link(outcome.case, direct=self.direct),
                functools.partial(self._overview_progress, outcome.case.name),
                on_end=functools.partial(self._overview_ended, outcome), before_wait=self.controls.check_abort)))
        plan = plan_link(outcome.case, direct=self.direct, log=bus_log)
        log.info("case %s: the drive is reached %s%s", outcome.case.name, plan.where or "directly",
                 f"; bus log {bus_log}" if bus_log else "")
        mode = self.worker_mode
        if mode is None and self.direct:
            mode = outcome.case.on_bench.bench.worker_mode(in_process_setpoints=least_setpoints(outcome.case))
        session = BenchSession(outcome.case, plan, outcome.directory if write else None, self.listener,
                               worker_mode=mode, resume=previous, keep_samples=self.keep_samples,
                               controls=self.controls, growing=growing)
        outcome.session = session
        outcome.plan = session.growing
        outcome.result = session.run()
        return outcome.result

    def _offline_cases(self, indices: Sequence[int], previous: dict[int, FrequencyResponse | None]) -> None:
        """Simulated plants: every frequency of every case in ``indices`` on the one executor, each point appended
        to its case's file as it is done; events case by case (a later case's points, done early, are announced
        when its turn comes); each case's plots drawn on the executor too, while later cases are measured."""
        from bodebench.bench.offline import in_flight_limit, measure_cases, sort_points
        from bodebench.sim._jit import HAVE_NUMBA

        if not HAVE_NUMBA:
            log.warning("numba is not installed: the simulated plants run as plain Python, about 170 times slower "
                        "(pip install 'bodebench[sim]')")

        cases = [self._case(i) for i in indices]
        outcomes: list[CaseOutcome] = []
        skips: list[set[float]] = []
        for i, case in zip(indices, cases, strict=True):
            before = previous[i]
            outcomes.append(CaseOutcome(i, case, self._directory(i), FrequencyResponse(
                before.points if before else (), config=case.raw, case=case.name),
                earlier_runs=sidecar_runs(self._directory(i)) if before else [], resumed=before is not None))
            skips.append(completed_frequencies(before, tuple({q.channel for q in before.points}),
                                               case.analysis.harmonics) if before else set())
        self.measuring = outcomes
        for outcome in outcomes:  # every directory checked before the first frequency (one output a plant)
            case = outcome.case
            check_output(outcome.directory, len(outcome.response.points) + len(case.excitation.frequencies_hz)
                         * len(case.analysis.harmonics))
        try:
            writers = [ResultsWriter(o.directory, o.case.name, o.case.raw, resume=previous[o.index] is not None)
                       for o in outcomes]
        except OSError as exc:
            raise ResultsError(f"{exc.filename or self.out}: cannot write results there: {exc.strerror or exc}") \
                from None
        plans = [GrowingPlan.of(case) for case in cases]
        waiting: list[list[list[ResponsePoint] | PlanGrew]] = [[] for _ in cases]
        for k, (outcome, plan) in enumerate(zip(outcomes, plans, strict=True)):
            outcome.plan = plan
            before = previous[outcome.index]
            if plan is not None and before is not None:
                plan.resume(before)
                cases[k] = outcome.case = plan.case
            if plan is not None and plan.adaptive.from_overview and not outcome.resumed:
                from bodebench.bench.overview import measure_overview

                waiting[k].append(self._seed(outcome, plan, measure_overview(
                    cases[k], functools.partial(self._overview_progress, outcome.case.name))))
                cases[k] = plan.case
        remaining = [sum(f not in skip for f in case.excitation.frequencies_hz)
                     for case, skip in zip(cases, skips, strict=True)]
        drawing: list[tuple[CaseOutcome, list[Future[list[Path]]]]] = []
        turn = -1

        def advance() -> None:
            """Finish the cases whose every frequency is done (an adaptive one's plan too, unless the sweep was
            stopped), in order, and begin the next one."""
            nonlocal turn
            while turn < len(outcomes) and (turn < 0 or (remaining[turn] == 0 and (
                    self.controls.aborted or not _growing(plans[turn])))):
                if turn >= 0:
                    sort_points(outcomes[turn].response)
                    self._summarize(outcomes[turn], completed=not self.controls.aborted)
                    drawing.append((outcomes[turn], self._submit_plots(outcomes[turn])))
                turn += 1
                if turn < len(outcomes):
                    outcome = outcomes[turn]
                    self.listener(CaseBegins(outcome.index, outcome.case.name, outcome.directory))
                    self.current = outcome
                    self.outcomes.append(outcome)
                    for told in waiting[turn]:
                        self._tell(outcome.case, told)

        advance()
        samples_dirs = [str(o.directory) if self.keep_samples else "" for o in outcomes]
        active = list(range(len(cases)))  # the cases with frequencies to measure in this round
        while active:
            rounds = measure_cases([cases[k] for k in active], self.executor, [skips[k] for k in active],
                                   [samples_dirs[k] for k in active], in_flight_limit(self.executor))
            for j, points in rounds:
                k = active[j]
                try:
                    writers[k].append(points)
                except OSError as exc:
                    raise point_not_written(outcomes[k].directory, points[0].frequency_hz, exc) from None
                skips[k].add(points[0].frequency_hz)
                for point in points:
                    outcomes[k].response.add(point)
                self._tell(cases[k], points) if k == turn else waiting[k].append(points)
                remaining[k] -= 1
                if self.controls.aborted:
                    break
                advance()
            if self.controls.aborted:
                advance()
                break
            active = []
            for k, plan in enumerate(plans):
                if plan is None or plan.ended or remaining[k]:
                    continue
                additions = plan.grow(outcomes[k].response, sorted(skips[k]))
                if additions:
                    cases[k] = outcomes[k].case = plan.case
                    grew = plan.event(additions)
                    self._tell(cases[k], grew) if k == turn else waiting[k].append(grew)
                    remaining[k] = len(additions)
                    active.append(k)
            advance()
        for outcome, futures in drawing:
            if futures:
                outcome.files = _drawn(outcome.directory, futures)
            self.listener(CaseSaved(outcome.index, outcome.response, outcome.directory, outcome.files))

    def _overview_progress(self, case: str, periods: int) -> None:
        self.listener(OverviewProgress(case, periods))

    def _overview_ended(self, outcome: CaseOutcome, ended: SessionEnded) -> None:
        """A bench overview's end, kept on its case; told where it ended the case (a trip, an abort, an error),
        as a session's end is."""
        outcome.overview_ended = ended
        if not ended.completed:
            self.listener(ended)

    def _seed(self, outcome: CaseOutcome, plan: GrowingPlan, overview: OverviewResult) -> PlanGrew:
        """An adaptive case's grid grown from its overview's lines before it is measured (the event that tells of
        it); the overview's files go to ``overview/`` in the case's directory."""
        from bodebench.io.overview import save_overview

        response = save_overview(outcome.directory / OVERVIEW_DIR, overview.lines, overview.design, overview.periods,
                                 outcome.case.raw, outcome.case.name)
        seeded = plan.seed(response)
        outcome.case = plan.case
        return plan.event(seeded)

    def _tell(self, case: CaseConfig, told: list[ResponsePoint] | PlanGrew) -> None:
        """Tell the listener of a frequency's points (their start and end), or of a plan that grew."""
        if isinstance(told, PlanGrew):
            self.listener(told)
        else:
            self._announce(case, told)

    def _announce(self, case: CaseConfig, points: list[ResponsePoint]) -> None:
        index = case.excitation.frequencies_hz.index(points[0].frequency_hz)
        self.listener(PointStarted(index, points[0].frequency_hz, case.analysis.tolerance_percent,
                                   case.analysis.criterion))
        self.listener(PointFinished(index, tuple(points)))

    def _submit_plots(self, outcome: CaseOutcome) -> list[Future[list[Path]]]:
        """Draw ``outcome``'s plots on the drawer, else on the executor, each figure a task of its own, so that on a
        pool the last case's figures are drawn side by side ([]: drawn here, now, or no plots wanted, or no point
        to draw)."""
        executor = self.drawer or self.executor
        if self.plots is None or executor is None or not len(outcome.response):
            self._draw(outcome)
            return []
        plots, title = self.plots, self._title(outcome)
        return [executor.submit(plots, outcome.response, outcome.directory, title, summary=outcome.summary,
                                figures=(figure,)) for figure in PLOT_FIGURES]

    def _draw(self, outcome: CaseOutcome) -> None:
        """``outcome``'s plots drawn here (none without a point); SessionError (output) where they cannot be
        written."""
        if self.plots is not None and len(outcome.response):
            try:
                outcome.files = tuple(self.plots(outcome.response, outcome.directory, self._title(outcome),
                                                 summary=outcome.summary))
            except OSError as exc:
                raise _plots_not_written(outcome.directory, exc) from None

    def _title(self, outcome: CaseOutcome) -> str:
        """The plots' title: the configuration's, with the case's name for a file with [cases]."""
        return f"{self.config.title}: {outcome.case.name}" if self.config.has_cases else self.config.title

    def _summarize(self, outcome: CaseOutcome, completed: bool = True) -> None:
        """The figures read off the case's response, into the outcome and the sidecar, with the record of this
        run after those of the runs it continues; SessionError (output) when the disk will not take them (the
        points are on disk already)."""
        try:
            self._write_record(outcome, completed)
        except OSError as exc:
            raise SessionError(FaultKind.OUTPUT, f"{outcome.directory}: cannot write the run's record or summary: "
                                                 f"{exc.strerror or exc}") from None

    def _write_record(self, outcome: CaseOutcome, completed: bool) -> None:
        outcome.summary = tuple(summarize_response(outcome.response, outcome.case.analysis.response_kind))
        result = outcome.result
        if result is None and outcome.session is not None and outcome.session.last_health is not None:
            health = outcome.session.last_health
            result = SessionResult(outcome.response, False, "", math.nan, False, health.round_trip_s, health)
        session = outcome.session
        reason = outcome.result.reason if outcome.result is not None else \
            session.ended.reason if session is not None and session.ended is not None else ""
        record = run_record(outcome.case, outcome.clock, direct=self.direct, points=len(outcome.response),
                            resumed=outcome.resumed, result=result,
                            completed=completed and (outcome.result is None or outcome.result.completed),
                            reason=reason, refused=session.refused if session is not None else (),
                            plan_notes=outcome.case.plan_notes,
                            drive_start=session.drive_start if session is not None else "")
        if not (outcome.directory / SIDECAR_NAME).exists():  # a run that measured nothing still leaves its record
            ResultsWriter(outcome.directory, outcome.case.name, outcome.case.raw, resume=True)
        plan = {"plan": outcome.plan.record()} if outcome.plan is not None else {}
        update_sidecar(outcome.directory, {"summary": [s.to_json() for s in outcome.summary],
                                           "runs": [*outcome.earlier_runs, record], **plan})

    def _finish(self, outcome: CaseOutcome) -> None:
        """The record, the summary and the plots of a case that ran to its end; SessionError (output) when the
        disk will not take them (the points are on disk already)."""
        self._summarize(outcome)
        self._draw(outcome)
        self.listener(CaseSaved(outcome.index, outcome.response, outcome.directory, outcome.files))


def _plots_not_written(directory: Path, exc: BaseException) -> SessionError:
    """The one line that says why a case's plots are not in ``directory`` (its points are)."""
    if isinstance(exc, OSError):
        why = f"{exc.filename}: {exc.strerror}" if exc.filename and exc.strerror else exc.strerror or str(exc)
    else:
        why = f"{type(exc).__name__}: {exc}"
    return SessionError(FaultKind.OUTPUT, f"{directory}: cannot write the plots: {why}")


def _drawn(directory: Path, futures: Sequence[Future[list[Path]]]) -> tuple[Path, ...]:
    """The files a case's plots, drawn elsewhere, were written to; SessionError (output) where one failed."""
    files: list[Path] = []
    for future in futures:
        try:
            files += future.result()
        except Exception as exc:  # the disk, or the process that drew it
            raise _plots_not_written(directory, exc) from None
    return tuple(files)


def _growing(plan: GrowingPlan | None) -> bool:
    """Whether an adaptive case's plan may still add frequencies."""
    return plan is not None and not plan.ended


def latest_points(response: FrequencyResponse) -> FrequencyResponse:
    """``response`` keeping only the latest point of each (frequency, harmonic, channel), in first-seen order
    (a frequency measured again during the sweep appears once)."""
    latest: dict[tuple[float, int, str], ResponsePoint] = {}
    for p in response.points:
        latest[(p.frequency_hz, p.harmonic, p.channel)] = p
    return FrequencyResponse(latest.values(), config=response.config, case=response.case)


def merge_frequency(base: FrequencyResponse, new: Sequence[ResponsePoint], frequency_hz: float
                    ) -> FrequencyResponse:
    """``base`` with its points at ``frequency_hz`` replaced by ``new`` (in their place, else at the end)."""
    out: list[ResponsePoint] = []
    inserted = False
    for p in base.points:
        if math.isclose(p.frequency_hz, frequency_hz, rel_tol=1e-9):
            if not inserted:
                out.extend(new)
                inserted = True
        else:
            out.append(p)
    if not inserted:
        out.extend(new)
    return FrequencyResponse(out, config=base.config, case=base.case)
