"""The overview measurement (docs/overview.md): the multisine held sample by sample at its rate, the output
sampled on the same instants, period after period until every line has its verdict. Offline on a simulated plant
(:func:`measure_overview`), or on a drive through the bus worker (:func:`measure_overview_on_bench`), which sends the
multisine as a table of setpoints ramped in and out over whole periods and leaves the drive at zero on every way
out."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bodebench.bench.connection import LinkPlan
from bodebench.bench.conversation import WorkerConversation, dating_not_checked
from bodebench.bench.events import SessionEnded, SessionError
from bodebench.bench.offline import OUTPUT_CHANNEL, build_plant
from bodebench.bench.worker import Credit, Ready, Samples, SineStarted, StartTable
from bodebench.core.multisine import Multisine
from bodebench.core.overview import LineIntegrator, OverviewLine, RuleSettings
from bodebench.io.config import CaseConfig
from bodebench.status import FaultKind

__all__ = ["OverviewResult", "measure_overview", "measure_overview_on_bench", "rule_settings"]


@dataclass(frozen=True)
class OverviewResult:
    """A finished overview: its multisine, each excited line's result (ascending in frequency), the whole periods
    the measurement ran, those it discarded for samples missing in them (a bench), and how a bench session ended
    (None offline)."""

    design: Multisine
    lines: tuple[OverviewLine, ...]
    periods: int
    discarded: int = 0
    ended: SessionEnded | None = None


def rule_settings(case: CaseConfig) -> RuleSettings:
    """The lines' stopping rule: ``[analysis]``'s criterion and parameters, ``[overview]``'s tolerance and period
    budget."""
    overview, analysis = case.overview, case.analysis
    if overview is None:
        raise ValueError(f"case {case.name!r} of {case.source} has no [overview] table")
    return RuleSettings(criterion=analysis.criterion, tolerance_percent=overview.tolerance(analysis),
                        skip_periods=analysis.skip_periods, window=analysis.window,
                        max_periods=overview.max_periods, settle_periods=analysis.settle_periods,
                        average_periods=analysis.average_periods)


def measure_overview(case: CaseConfig, on_period: Callable[[int], None] | None = None) -> OverviewResult:
    """Run a case's overview on its simulated plant, starting at rest: every setpoint held over one sample
    interval, the output read at the start of each (its value at the sample instant). ``on_period`` gets the
    periods done after each one."""
    if case.plant is None:
        raise ValueError(f"case {case.name!r} of {case.source} has no [plant] to simulate")
    design = case.multisine()
    plant = build_plant(case.plant)
    channel = plant.output_names.index(OUTPUT_CHANNEL)
    step = 1.0 / design.rate_hz
    setpoint = design.waveform()
    integrator = LineIntegrator(design, OUTPUT_CHANNEL, rule_settings(case))
    state = plant.initial_state()
    at_start = 0.0  # the output at the period's first instant: the plant at rest
    while not integrator.done:
        after = plant.run_held(state, setpoint, step)[:, channel]  # the output at the end of each sample interval
        output = np.concatenate([[at_start], after[:-1]])
        at_start = float(after[-1])
        integrator.feed_period(setpoint, output)
        if on_period is not None:
            on_period(integrator.periods)
    return OverviewResult(design, tuple(integrator.result()), integrator.periods)


MAX_DISCARDED_SHARE = 0.5
"""A bench overview fails when more than this share of its whole periods missed samples (lost replies)."""


class _PeriodAssembler:
    """Samples dated on the tick grid, gathered into whole periods of N ticks from ``first_tick``: each period's
    output at ticks first_tick + p N + n, n = 0 .. N-1 (the instant the setpoint of that tick starts to be held)."""

    def __init__(self, first_tick: int, samples: int, step_s: float) -> None:
        self.start = first_tick
        self.samples = samples
        self.step_s = step_s
        self.buffer = np.full(samples, np.nan)

    def add(self, t: np.ndarray, values: np.ndarray) -> list[np.ndarray | None]:
        """Samples (session time t, s; one channel's values); returns the periods they complete, in order (None
        for one that misses a sample)."""
        done: list[np.ndarray | None] = []
        ticks = np.rint(t / self.step_s).astype(np.int64)
        for tick, value in zip(ticks.tolist(), values.tolist(), strict=True):
            if tick < self.start:
                continue
            while tick >= self.start + self.samples:
                done.append(self.buffer if np.isfinite(self.buffer).all() else None)
                self.buffer = np.full(self.samples, np.nan)
                self.start += self.samples
            self.buffer[tick - self.start] = value
        return done


def measure_overview_on_bench(case: CaseConfig, plan: LinkPlan, on_period: Callable[[int], None] | None = None,
                              worker_mode: str | None = None,
                              on_end: Callable[[SessionEnded], None] | None = None,
                              before_wait: Callable[[], None] | None = None) -> OverviewResult:
    """Run a bench case's overview on the drive ``plan`` reaches: the multisine as a table of setpoints (ramped in
    over bench.ramp_in_periods of its periods, out over bench.ramp_out_periods), the first output channel
    analysed period after period from the end of the ramp in. Whatever ends it (every line measured, a trip, an
    error, a stop signal), the worker ramps out or slews to zero, sends zero setpoints and the disable frame;
    ``on_end`` (and the result's ``ended``) gets what the drive was last sent; ``before_wait`` is called before
    each wait for the worker (at least once a second) and may raise to end the run (an abort). SessionError on a
    trip, where more than :data:`MAX_DISCARDED_SHARE` of the periods missed samples, or where the driver had a gap
    in the samples' dating to check and its check failed or did not come (a result is returned only once the
    samples' dating is checked)."""
    tables = case.on_bench
    bench = tables.bench
    design = case.multisine()
    channel = bench.output_channels[0]
    integrator = LineIntegrator(design, channel, rule_settings(case))
    setpoint = design.waveform()
    discarded = 0
    worker = WorkerConversation(plan, bench, tables.safety, worker_mode, finished="overview complete",
                                on_end=on_end or (lambda ended: None),
                                before_wait=before_wait or (lambda: None))
    with worker:
        column = worker.expect(Ready, 60.0).channels.index(channel)
        worker.send(StartTable(tuple(float(u) for u in setpoint), bench.ramp_in_periods, bench.ramp_out_periods))
        started = worker.expect(SineStarted, 60.0)
        periods = _PeriodAssembler(started.tick + bench.ramp_in_periods * design.samples, design.samples,
                                   1.0 / bench.rate_hz)
        unchecked = False  # the latest batch's samples may be dated wrongly until the driver checks its link
        while not integrator.done:
            worker.before_wait()
            message = worker.receive(1.0)
            if not isinstance(message, Samples):
                continue
            unchecked = message.dating_unchecked
            for output in periods.add(message.t, message.values[:, column]):
                if integrator.done:
                    break
                if output is None:
                    discarded += 1
                    spanned = discarded + integrator.periods
                    if discarded > MAX_DISCARDED_SHARE * max(spanned, 8):
                        raise SessionError(FaultKind.BUS, f"{discarded} of {spanned} periods of the multisine "
                                                          "missed samples (replies lost on the bus)")
                    continue
                integrator.feed_period(setpoint, output)
                if on_period is not None:
                    on_period(integrator.periods)
            if bench.clock == "lockstep" and not integrator.done:
                worker.send(Credit(message.last_tick + design.samples))
        if unchecked and not worker.dating_checked(bench.ramp_out_periods * design.period_s):
            raise dating_not_checked("the overview's multisine")
    return OverviewResult(design, tuple(integrator.result()), integrator.periods, discarded, worker.ended)
