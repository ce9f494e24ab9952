"""The overview measurement on a simulated plant offline: the multisine held sample by sample at its rate, the
output sampled on the same instants, period after period until every line has its verdict (docs/overview.md)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bodebench.bench.offline import OUTPUT_CHANNEL, build_plant
from bodebench.core.multisine import Multisine
from bodebench.core.overview import LineIntegrator, OverviewLine, RuleSettings
from bodebench.io.config import CaseConfig

__all__ = ["OverviewResult", "measure_overview", "rule_settings"]


@dataclass(frozen=True)
class OverviewResult:
    """A finished overview: its multisine, each excited line's result (ascending in frequency) and the periods
    the measurement ran."""

    design: Multisine
    lines: tuple[OverviewLine, ...]
    periods: int


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
