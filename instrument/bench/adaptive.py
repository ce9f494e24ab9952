"""An adaptive case's frequency plan as it grows: the case's rule (:mod:`bodebench.core.refine`) applied round after
round to the points measured so far, within the plan's ``max_points`` and ``budget_s``, each added frequency placed
on the bench's grid as the loader places the planned ones. The bench session and the offline sweep both grow
their plans through it; what it added, why, and where each figure stands go into the results' sidecar.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from bodebench.bench.events import PlanGrew
from bodebench.core.autointegration import period_budget
from bodebench.core.refine import Addition, Standing, next_round
from bodebench.core.response import FrequencyResponse
from bodebench.io.config import CaseConfig
from bodebench.io.tables import AdaptivePlan

__all__ = ["GrowingPlan", "bench_seconds", "extra_periods"]


def extra_periods(case: CaseConfig, frequency_hz: float) -> float:
    """Periods a point of ``case`` at ``frequency_hz`` spends besides those integrated: settling, and on a bench
    the ramps in and out."""
    bench = case.bench
    ramps = bench.ramp_in_periods + bench.ramp_out_periods if bench is not None else 0
    return ramps + case.excitation.settle_at(frequency_hz)


def bench_seconds(case: CaseConfig, response: FrequencyResponse) -> float:
    """Bench time the points of ``response`` (of ``case``) took, s: at each frequency its slowest series' periods
    and the extra periods (:func:`extra_periods`), over the frequency."""
    periods: dict[float, int] = {}
    for p in response.points:
        periods[p.frequency_hz] = max(periods.get(p.frequency_hz, 0), p.periods)
    return sum((n + extra_periods(case, f)) / f for f, n in periods.items())


class GrowingPlan:
    """The plan of an adaptive ``case`` (``excitation.frequencies.adaptive``): :meth:`grow` gives the next round's
    frequencies, :attr:`case` the case with every frequency planned so far, :meth:`record` what happened."""

    def __init__(self, case: CaseConfig) -> None:
        adaptive = case.excitation.adaptive
        if adaptive is None:
            raise ValueError(f"case {case.name!r} has no adaptive plan")
        self.adaptive: AdaptivePlan = adaptive
        self.case = case
        self.added: list[Addition] = []
        self.standings: tuple[Standing, ...] = ()
        self.rounds = 0
        self.ended = ""
        """Why the plan stopped growing ("" while it may still grow)."""

    @classmethod
    def of(cls, case: CaseConfig) -> GrowingPlan | None:
        """The plan of ``case``; None for a case without an adaptive plan."""
        return cls(case) if case.excitation.adaptive is not None else None

    def extra_periods(self, frequency_hz: float) -> float:
        """Periods a point at ``frequency_hz`` spends besides those integrated (:func:`extra_periods`)."""
        return extra_periods(self.case, frequency_hz)

    def max_periods(self, frequency_hz: float) -> int:
        """The periods a point at ``frequency_hz`` may integrate (its budget)."""
        return period_budget(self.case.analysis, frequency_hz, on_bench=self.case.bench is not None)

    def grow(self, response: FrequencyResponse, attempted: Sequence[float]) -> tuple[Addition, ...]:
        """The frequencies to measure next (none: the plan is done, :attr:`ended` says why), from the points of
        ``response``; ``attempted``: every frequency measured or tried so far (one that gave no point too)."""
        if self.ended:
            return ()
        plan = self.adaptive
        step = next_round(response, plan, self.case.analysis.response_kind, attempted)
        self.standings = step.standings
        tried = set(attempted)
        room = plan.max_points - len(tried)
        spent = bench_seconds(self.case, response)
        if not step.additions:
            unmet = [s.figure for s in step.standings if s.found and not s.met]
            absent = sum(not s.found for s in step.standings)
            curve = ", and the curve within its own" if plan.curve else ""
            self.ended = (f"every requested figure found within its accuracy{curve}" if not unmet
                          else f"no frequency it may add would bring within its accuracy: {', '.join(unmet)}")
            if absent:
                self.ended += f" ({absent} not found in the measured range)"
            return ()
        if room <= 0:
            self.ended = f"max_points ({plan.max_points}) reached"
            return ()
        if plan.budget_s is not None and spent >= plan.budget_s:
            self.ended = f"budget_s ({plan.budget_s:g} s) spent: {spent:.4g} s"
            return ()
        added = self._add(step.additions[:room], "", tried)
        if not added:  # on a bench, each moved onto a frequency measured already
            self.ended = "the frequencies it calls for, placed on the bench's grid, are measured already"
        else:
            self.rounds += 1
        return added

    def resume(self, earlier: FrequencyResponse) -> None:
        """An interrupted sweep continued: the frequencies its points were measured at join the plan (those not of
        the range were added by the earlier run)."""
        grid = set(self.case.excitation.frequencies_hz)
        self._add([Addition(f, "added by an earlier run of this sweep")
                   for f in sorted({p.frequency_hz for p in earlier.points} - grid)], "", grid, place=False)

    def seed(self, overview: FrequencyResponse) -> tuple[Addition, ...]:
        """Frequencies added to the range's before any is measured, read off an overview's lines (``overview``, a
        response of one point per line) as a round reads the measured points; within ``max_points``."""
        grid = self.case.excitation.frequencies_hz
        step = next_round(overview, self.adaptive, self.case.analysis.response_kind, grid, apart_from_points=False)
        return self._add(step.additions[:max(0, self.adaptive.max_points - len(grid))], "overview: ", set(grid))

    def _add(self, chosen: Sequence[Addition], prefix: str, tried: set[float], place: bool = True
             ) -> tuple[Addition, ...]:
        """``chosen`` placed on the bench's grid (unless not ``place``), ascending, those not measured yet added to
        the plan."""
        frequencies = [a.frequency_hz for a in chosen]
        placed = self.case.placed(frequencies) if place else tuple(frequencies)
        additions = tuple(sorted((Addition(f, prefix + a.reason) for a, f in zip(chosen, placed, strict=True)
                                  if f not in tried), key=lambda a: a.frequency_hz))
        self.added += additions
        frequencies = sorted({*self.case.excitation.frequencies_hz, *(a.frequency_hz for a in additions)})
        self.case = replace(self.case, excitation=self.case.excitation.with_frequencies(frequencies))
        return additions

    def event(self, additions: Sequence[Addition]) -> PlanGrew:
        """The event that tells listeners of a round's ``additions``."""
        added = tuple(a.frequency_hz for a in additions)
        return PlanGrew(added, tuple(a.reason for a in additions), tuple(self.extra_periods(f) for f in added),
                        tuple(self.max_periods(f) for f in added))

    def record(self) -> dict[str, Any]:
        """The plan's account for the results' sidecar: each added frequency with its reason and round, where each
        requested figure stands, and why the plan stopped growing."""
        return {
            "added": [{"frequency_hz": a.frequency_hz, "reason": a.reason} for a in self.added],
            "rounds": self.rounds,
            "figures": [{"channel": s.channel, "figure": s.figure, "found": s.found, "met": s.met,
                         "accuracy": _num(s.accuracy),
                         "interpolation": _num(s.interpolation), "measurement": _num(s.measurement),
                         "text": s.text} for s in self.standings],
            "ended": self.ended or "stopped before the plan was done",
        }

    def lines(self) -> list[str]:
        """The plan's account in words, one line each."""
        out = [f"adaptive plan: {len(self.added)} frequencies added in {self.rounds} rounds; "
               f"{self.ended or 'stopped before the plan was done'}"]
        out += [f"  {'ok  ' if s.met else 'open' if s.found else '--  '} {s.text}" for s in self.standings]
        return out


def _num(value: float) -> float | None:
    return value if math.isfinite(value) else None
