"""A bench session: the sweep on a drive, joining the bus worker, the sampler and the results directory.

For each frequency the worker ramps the sine in over whole periods; the
sampler autointegrates from the end of the ramp with the configured rule;
the point is written to disk the moment it is measured; the worker ramps
out and starts the next frequency. Listeners (the command line, the terminal
UI) receive typed events; they never touch the measurement.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bodebench.bench.adaptive import GrowingPlan, extra_periods
from bodebench.bench.connection import LinkPlan
from bodebench.bench.controls import ABORTED, SweepControls
from bodebench.bench.conversation import WorkerConversation, dating_not_checked
from bodebench.bench.events import (
    BusStatus,
    Listener,
    PointFinished,
    PointProgress,
    PointStarted,
    SessionEnded,
    SessionError,
    SessionFault,
    SessionStarted,
    point_not_written,
)
from bodebench.bench.window import PointWindow
from bodebench.bench.worker import (
    Credit,
    Health,
    Ready,
    Samples,
    SineStarted,
    StartSine,
)
from bodebench.core.autointegration import Autointegrator, period_budget
from bodebench.core.benchgrid import flag_disturbed, mark_untied
from bodebench.core.liveness import FlatWatch, no_fundamental
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.core.setpoint_rounding import rounding_ratios, taken_against
from bodebench.drivers.codec import carries_lines
from bodebench.drivers.layout import SETPOINT, SETPOINT_ECHO
from bodebench.io.config import AnalysisConfig, BenchConfig, CaseConfig
from bodebench.io.results import CSV_NAME, ResultsWriter, RowsOnDiskError, check_output
from bodebench.io.samples import PointSamples
from bodebench.status import FaultKind


@dataclass
class SessionResult:
    response: FrequencyResponse
    completed: bool
    reason: str
    last_setpoint: float
    disabled: bool
    round_trip_s: float = math.nan
    health: Health | None = None
    periods_discarded: int = 0
    """Periods of the sweep's points not integrated for gaps in the feedback (refused points' included)."""
    log_failure: str = ""
    """Why the bus log stopped recording before the sweep ended ("" when it did not, or there was none)."""
    stale_samples: int = 0
    """Realtime: feedback samples left out because the drive held a stale setpoint (the periods they were in
    are among ``periods_discarded``)."""


class BenchSession:
    """A sweep of ``case`` on the drive ``plan`` reaches; points go to ``out_dir`` (None: memory only)."""

    def __init__(self, case: CaseConfig, plan: LinkPlan, out_dir: Path | None = None,
                 listener: Listener | None = None, worker_mode: str | None = None,
                 resume: FrequencyResponse | None = None, keep_samples: bool = True,
                 controls: SweepControls | None = None, growing: GrowingPlan | None = None) -> None:
        """resume: points of an interrupted sweep of the same case; their frequencies are not measured again.
        keep_samples: save each frequency's raw samples in ``out_dir/samples/`` before its rows. controls: the
        user's requests, shared with the procedure that runs this session (None: this session's own). growing: an
        adaptive case's plan already begun, whose ``case`` this is."""
        self.case = case
        self.keep_samples = keep_samples
        self.plan = plan
        self.out_dir = out_dir
        self.listener = listener or (lambda event: None)
        tables = case.on_bench
        self.bench = tables.bench
        self.safety = tables.safety
        self.analysis: AnalysisConfig = case.analysis
        self.disturbance_lines = case.disturbance_lines
        self.worker_mode = worker_mode or tables.bench.worker_mode()
        self.controls = controls if controls is not None else SweepControls()
        self.response = FrequencyResponse(resume.points if resume else (), config=case.raw, case=case.name)
        self.period = 1.0 / tables.bench.rate_hz
        self.ended: SessionEnded | None = None
        self.refused: list[tuple[float, str]] = []  # (frequency, reason) of points not written
        self.periods_discarded = 0  # periods not integrated for gaps in the feedback, all points so far
        self.stale_samples = 0  # realtime: feedback samples left out, the drive holding a stale setpoint
        self.drive_start = ""
        """What the driver did and measured to enable the drive (``Ready.drive_start``; empty before)."""
        self.last_samples: PointSamples | None = None
        """The samples of the frequency measured last (saved in ``samples/`` when there is a results directory)."""
        self._writer: ResultsWriter | None = None
        self._worker = WorkerConversation(
            plan, self.bench, self.safety, self.worker_mode, finished="sweep complete",
            on_fault=self._fault, on_health=lambda health: self.listener(BusStatus(health)),
            before_wait=self._check_abort, on_end=self._end, keep_off_pacing_cpu=True)
        self.growing = growing if growing is not None else GrowingPlan.of(case)
        """An adaptive case's plan as it grows (None: the planned frequencies only); ``growing``: one already
        begun (an overview's frequencies added to the case)."""
        if self.growing is not None and resume is not None:  # the frequencies an earlier run added are the plan's
            self.growing.resume(resume)
            self.case = self.growing.case

    # --- the sweep
    def run(self) -> SessionResult:
        """Run the whole sweep; never leaves the drive moving. Raises SessionError after a trip (points kept), and
        ResultsError before the first setpoint when the results directory cannot take the sweep's files."""
        made = False
        if self.out_dir is not None:
            points = len(self.case.excitation.frequencies_hz) * len(self.case.analysed_channels) * \
                len(self.analysis.harmonics)
            made = check_output(self.out_dir, points + len(self.response.points))
        try:
            return self._run()
        finally:
            if made and self.out_dir is not None and not any(self.out_dir.iterdir()):
                self.out_dir.rmdir()  # nothing measured: leave no empty directory behind

    def _run(self) -> SessionResult:
        with self._worker:
            try:
                self._sweep()
            except KeyboardInterrupt:
                self.controls.request_abort()
                raise
        assert self.ended is not None
        stopped, rt = self._worker.stopped, self.last_health.round_trip_s if self.last_health else math.nan
        return SessionResult(self.response, self.ended.completed, self.ended.reason,
                             stopped.last_setpoint if stopped else math.nan, stopped.disabled if stopped else False,
                             rt, self.last_health, self.periods_discarded, stopped.log_failure if stopped else "",
                             self.stale_samples)

    def _sweep(self) -> None:
        """Every frequency of the case not measured yet, those asked to be measured again, and an adaptive case's
        additions, in turn."""
        ready = self._worker.expect(Ready, timeout=60.0)
        self.channels = ready.channels
        self.drive_start = ready.drive_start
        done = completed_frequencies(self.response, self.case.analysed_channels, self.analysis.harmonics)
        self.listener(self._started(ready.channels, done))
        queue = [f for f in self.case.excitation.frequencies_hz if f not in done]
        attempted = set(done)
        index = 0
        while True:
            while queue or self.controls.remeasure:
                f = self.controls.remeasure.pop(0) if self.controls.remeasure else queue.pop(0)
                attempted.add(f)
                self._measure(index, f)
                index += 1
            queue = self._grow(attempted)
            if not queue:
                break

    @property
    def last_health(self) -> Health | None:
        """The bus worker's latest health report (None before the first)."""
        return self._worker.last_health

    def _fault(self, kind: FaultKind, message: str) -> None:
        self.listener(SessionFault(kind, message, len(self.response.points)))

    def _end(self, ended: SessionEnded) -> None:
        self.ended = ended
        self.listener(ended)

    def _grow(self, attempted: set[float]) -> list[float]:
        """An adaptive case's next round of frequencies, announced (none: the plan is done or there is none)."""
        if self.growing is None or self.controls.aborted:
            return []
        additions = self.growing.grow(self.response, sorted(attempted))
        if not additions:
            return []
        self.case = self.growing.case
        self.listener(self.growing.event(additions))
        return [a.frequency_hz for a in additions]

    def _started(self, channels: tuple[str, ...], done: set[float]) -> SessionStarted:
        excitation, bench = self.case.excitation, self.bench
        measured: dict[float, int] = {}
        for p in self.response.points:
            if p.frequency_hz in done:
                measured[p.frequency_hz] = max(measured.get(p.frequency_hz, 0), p.periods)
        extra = tuple(extra_periods(self.case, f) for f in excitation.frequencies_hz)
        budgets = tuple(period_budget(self.analysis, f, on_bench=True) for f in excitation.frequencies_hz)
        return SessionStarted(excitation.frequencies_hz, channels, self.plan.where, tuple(measured.items()), extra,
                              budgets, bench.clock == "realtime")

    def _results_writer(self) -> ResultsWriter:
        """The writer of the results directory, opened with the first point (an interrupted sweep's file is
        continued; its points are written first when it is not on disk in this directory)."""
        if self._writer is None:
            assert self.out_dir is not None
            on_disk = (self.out_dir / CSV_NAME).exists() and bool(self.response.points)
            self._writer = ResultsWriter(self.out_dir, self.case.name, self.case.raw, resume=on_disk)
            if not on_disk:
                self._writer.append(self.response.points)
        return self._writer

    def _check_abort(self) -> None:
        if self.controls.aborted:
            self.listener(SessionFault(FaultKind.ABORT, ABORTED, len(self.response.points)))
        self.controls.check_abort()

    def _absurd(self, points: list[ResponsePoint]) -> str:
        """Why the points of a frequency are refused ("" when they are not)."""
        # a ratio of channels (analysis.measured) is no feedback value: the windows hold for the samples only
        limits = self.safety.feedback_limits if self.analysis.measurement == "output" else {}
        for p in points:
            window = limits.get(p.channel)
            reason = _absurd_point(p, (float(window[0]), float(window[1])) if window else None)
            if reason:
                return reason
        return ""

    def _no_response(self, f: float, what: str) -> None:
        """End the sweep: the feedback at ``f`` Hz stopped answering the sine (``what`` says how); never a point."""
        why = (f"{f:g} Hz: {what}: the drive is not following the setpoint (disabled, tripped by its own watchdog, "
               "or a setpoint below the resolution of its frame); no point at this frequency")
        self.refused.append((f, why))
        self.listener(SessionFault(FaultKind.NO_RESPONSE, why, len(self.response.points)))
        raise SessionError(FaultKind.NO_RESPONSE, why)

    def _analysis(self) -> AnalysisConfig:
        if self.controls.tolerance_percent is not None:
            return replace(self.analysis, tolerance_percent=self.controls.tolerance_percent)
        return self.analysis

    def _measure(self, index: int, f: float) -> None:
        bench = self.bench
        analysis = self._analysis()
        amplitude = self.case.excitation.amplitude_at(f)
        settle = self.case.excitation.settle_at(f)  # whole periods at full amplitude before period 1
        if analysis.measurement == "output":
            reference, reference_phase, untied = sine_dating(bench, self.channels, f)
        else:  # a ratio of two channels: the host's clock never enters it
            reference, reference_phase, untied = "", 0.0, False
        formed = self.case.formed(reference)
        outputs, reference = formed.outputs, formed.reference
        columns = [self.channels.index(n) for n in formed.raw]
        # the drive's echo, where it sends one, is watched with the outputs: a drive that stopped applying the sine
        watched = columns + [self.channels.index(SETPOINT_ECHO)] \
            if SETPOINT_ECHO in self.channels and reference != SETPOINT_ECHO else columns
        watch = FlatWatch([self.channels[i] for i in watched], f)
        last_sent = math.nan  # the setpoint the host sent at the sample before this batch
        self._worker.send(StartSine(f, amplitude, bench.ramp_in_periods, bench.ramp_out_periods))
        self.listener(PointStarted(index, f, analysis.tolerance_percent, analysis.criterion))
        started = self._worker.expect(SineStarted, timeout=60.0)
        t0 = started.tick * self.period + (bench.ramp_in_periods + settle) / f

        def start(t0: float) -> tuple[Autointegrator, PointSamples]:
            return (Autointegrator(f, amplitude, outputs, analysis, t0=t0, reference=reference or None,
                                   reference_phase=reference_phase, samples_per_period=self.bench.rate_hz / f,
                                   disturbance_lines=self.disturbance_lines,
                                   reference_lines=carries_lines(reference)),
                    PointSamples(f, amplitude, outputs, t0, reference, "bench", reference_phase, untied))

        sampler, record = start(t0)
        ticks_per_period = max(1, math.ceil(1.0 / (f * self.period)))
        window = PointWindow(t0, f, sampler.max_gap_periods / f)
        scope = ScopeWindow(f)
        self.controls.skip.clear()
        unchecked = False  # the latest batch's samples may be dated wrongly until the driver checks its link
        while not sampler.done:
            self._check_abort()
            if self.controls.skip.is_set():
                self.listener(PointFinished(index, (), skipped=True))
                return
            if self.controls.pause.is_set():
                time.sleep(0.05)
                continue
            message = self._worker.receive(1.0)
            if not isinstance(message, Samples):
                continue
            unchecked = message.dating_unchecked
            t, values = message.t, message.values[:, watched]
            if t.size:  # the samples of the analysed periods (a friction link may stick through the ramp), each
                # with whether the host's setpoint moved at its tick
                sent = np.asarray(message.setpoint, dtype=np.float64)
                watch.add(t, values, (np.diff(sent, prepend=last_sent) != 0) & (t > window.t0))
                last_sent = float(sent[-1])
                stopped = watch.stuck()
                if stopped:
                    self._no_response(f, stopped)
            scope.add(t, message.setpoint, values[:, 0])
            t, values, moved, stale = window.take(t, values, message.held)
            self.stale_samples += stale
            if moved:  # the drive answered late: period 1 is the first whole period after its first sample
                sampler, record = start(window.t0)
            if t.size == 0:  # still before period 1 (the ramp, the settle periods): the drive goes on
                if bench.clock == "lockstep":
                    self._worker.send(Credit(message.last_tick + ticks_per_period))
                continue
            values = formed.combine(values)
            record.add(t, values)
            with np.errstate(all="ignore"):  # garbage that got this far is refused below, not warned about
                sampler.feed(t, values)
            if bench.clock == "lockstep" and not sampler.done:
                self._worker.send(Credit(message.last_tick + ticks_per_period))
            self.listener(PointProgress(index, f, sampler.periods, tuple(sampler.states()), scope.view(),
                                        discarded=sampler.discarded, discard_limit=sampler.discard_limit))
        self.periods_discarded += sampler.discarded
        if sampler.failure:  # too many periods with gaps in the feedback: no measurement
            self.refused.append((f, sampler.failure))
            self.listener(PointFinished(index, (), skipped=True, refused=sampler.failure))
            return
        try:
            with np.errstate(all="ignore"):
                points = sampler.points()
        except ValueError as exc:  # an infinite coefficient: no response point can hold it
            points, refused = [], f"not a measurement: {exc}"
        else:
            refused = self._absurd(points)
            silent = no_fundamental(points)
            if silent:
                self._no_response(f, silent)
        points = flag_disturbed(mark_untied(points) if untied else points, self.disturbance_lines)
        if not reference and self.case.layout is not None:  # taken against the sine as the frames carried it
            setpoint = self.case.layout.setpoint
            last = record.batches[-1][0][-1] if record.batches else record.t0
            whole = int(math.floor((last - record.t0) * f + 1e-9))
            ratios = rounding_ratios(lambda values: setpoint.carried(SETPOINT, values), amplitude, f, self.period,
                                     started.tick, record.t0, range(1, max([whole, *(p.periods for p in points)]) + 1))
            record.setpoint_ratios = np.array([ratios[n] for n in sorted(ratios)], dtype=np.complex128)
            points = taken_against(points, ratios)
        if refused:
            self.refused.append((f, refused))
            self.listener(PointFinished(index, (), skipped=True, refused=refused))
            return
        if unchecked:
            self._await_dating(f)
        self.last_samples = record
        if self.out_dir is not None:
            try:
                if self.keep_samples:
                    record.save(self.out_dir)  # before the rows: a point on disk always has its samples
                self._results_writer().append(points)
            except OSError as exc:  # the rows already on disk stay; a torn row of these is dropped on resume
                if isinstance(exc, RowsOnDiskError):  # these rows too: only their checksums are missing
                    for p in points:
                        self.response.add(p)
                self.listener(SessionFault(FaultKind.OUTPUT, str(exc), len(self.response.points)))
                raise point_not_written(self.out_dir, f, exc) from None
        for p in points:
            self.response.add(p)
        self.listener(PointFinished(index, tuple(points)))

    def _await_dating(self, f: float) -> None:
        """The point at ``f`` Hz is measured but its samples' dating is not checked yet: the sine ramps out, and the
        point is written once the driver has checked its link on the idle ticks (a failed check ends the sweep with
        the driver's fault, the point unwritten); SessionError when no check comes within ``DATING_WAIT_S`` after
        the ramp (:func:`dating_not_checked`)."""
        try:
            checked = self._worker.dating_checked(self.bench.ramp_out_periods / f)
        except SessionError as exc:
            self.refused.append((f, f"{f:g} Hz: measured, not written: {exc}"))
            raise
        if not checked:
            error = dating_not_checked(f"{f:g} Hz")
            self.refused.append((f, str(error)))
            raise error


def sine_dating(bench: BenchConfig, channels: tuple[str, ...], frequency_hz: float) -> tuple[str, float, bool]:
    """How a point's sine is dated against its feedback: (reference channel, its ideal phase in rad, untied).

    Two-channel mode divides by ``bench.reference_channel``. On the lockstep clock, and over CANopen where each
    sample answers the host's SYNC, the feedback's counter is the host's own tick. On the realtime clock otherwise
    the host's send times and the drive's counter are two clocks: the drive's ``setpoint_echo`` (the setpoint it
    applied over the period before each sample, PROTOCOL.md section 7) dates the sine on the drive's clock, taken as
    the reference with the phase an ideal echo has, -2 pi f h, so the result reads as on the lockstep clock and the
    host's latency never enters it. A drive with no echo gives no way to tie the clocks: untied (its phase holds the
    host's latency)."""
    if bench.reference_channel or bench.clock != "realtime" or bench.transport == "canopen":
        return bench.reference_channel, 0.0, False
    if SETPOINT_ECHO in channels:
        return SETPOINT_ECHO, -2.0 * math.pi * frequency_hz / bench.rate_hz, False
    return "", 0.0, True


def _absurd_point(p: ResponsePoint, window: tuple[float, float] | None) -> str:
    """Why point ``p`` cannot be a physical response ("" when it can): a non-finite coefficient, or a response
    amplitude larger than half the channel's feedback window (a sine that could never fit inside it)."""
    where = f"{p.frequency_hz:g} Hz {p.channel} harmonic {p.harmonic}"
    if not (math.isfinite(p.p) and math.isfinite(p.q)):
        return f"{where}: the response is not finite (p = {p.p:g}, q = {p.q:g})"
    if window is not None and p.magnitude > (window[1] - window[0]) / 2:
        return (f"{where}: response amplitude {p.magnitude:g} ({p.gain_db:+.1f} dB) exceeds half the feedback "
                f"window safety.feedback_limits.{p.channel} = [{window[0]:g}, {window[1]:g}]")
    return ""


class ScopeWindow:
    """The live scope's trace: setpoint and first output channel over the last two periods (s, setpoint units,
    output units). Keeps only the batches that reach into those two periods, so its cost per batch does not grow
    with the point's length, however the batches are cut (an empty one included)."""

    def __init__(self, frequency_hz: float) -> None:
        self.span = 2.0 / frequency_hz  # s
        self.chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def add(self, t: np.ndarray, setpoint: np.ndarray, output: np.ndarray) -> None:
        """One batch: times (s, increasing), setpoints and output, each (n,)."""
        if t.size == 0:
            return
        self.chunks.append((t, setpoint, output))
        while len(self.chunks) > 1 and self.chunks[1][0][0] <= t[-1] - self.span:
            del self.chunks[0]

    def view(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(t, setpoint, output) of the last two periods; None before the first sample."""
        if not self.chunks:
            return None
        t = np.concatenate([c[0] for c in self.chunks])
        keep = t >= t[-1] - self.span
        return (t[keep], np.concatenate([c[1] for c in self.chunks])[keep],
                np.concatenate([c[2] for c in self.chunks])[keep])


def completed_frequencies(response: FrequencyResponse, channels: tuple[str, ...],
                          harmonics: tuple[int, ...]) -> set[float]:
    """Frequencies at which every (channel, harmonic) point of a sweep is present."""
    have: dict[float, set[tuple[str, int]]] = {}
    for p in response.points:
        have.setdefault(p.frequency_hz, set()).add((p.channel, p.harmonic))
    need = {(c, k) for c in channels for k in harmonics}
    return {f for f, got in have.items() if need <= got}
