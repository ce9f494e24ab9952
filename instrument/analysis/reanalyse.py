"""A sweep analysed again from its raw samples, without the bench: another stopping rule, another tolerance.

Every frequency of a results directory has its samples in ``samples/`` (:mod:`bodebench.io.samples`). Each is fed
to a fresh sampler in the batches the live sampler took, so that with the settings of the sweep the points come out
bit for bit as they were measured. A rule that wants more periods than the record holds is capped where the record
ends (status ``capped``). Periods that gaps in a bench record touch are discarded as live (the offline experiment's
samples have none); a frequency of which too many were is left out, its reason in ``failed``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from bodebench.core.autointegration import AnalysisSettings, Autointegrator, GapsError
from bodebench.core.benchgrid import flag_disturbed, mark_untied
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.core.setpoint_rounding import taken_against
from bodebench.drivers.codec import carries_lines
from bodebench.io.config import AnalysisConfig, ConfigError, build_table, disturbance_lines_of, measured_of
from bodebench.io.results import SIDECAR_NAME, load_response
from bodebench.io.samples import PointSamples, load_samples, samples_path

__all__ = ["Reanalysis", "reanalyse", "reanalyse_point"]


@dataclass(frozen=True)
class Reanalysis:
    """The response analysed again (its configuration's [analysis] is the one used), the frequencies whose
    record ended before the rule stopped (Hz), and those that failed for gaps in their samples (Hz, why)."""

    response: FrequencyResponse
    analysis: AnalysisConfig
    record_ended: tuple[float, ...]
    failed: tuple[tuple[float, str], ...] = ()


def _grid_steps_per_period(samples: PointSamples) -> int:
    """The steps per period of an offline record's grid (its samples are every h = 1/(N f) from t = 0)."""
    t = samples.t
    if t.size < 2 or not t[-1] > t[0]:
        raise ValueError(f"the offline record of {samples.frequency_hz:g} Hz holds fewer than two sample times")
    return round((t.size - 1) / (samples.frequency_hz * (t[-1] - t[0])))


def reanalyse_point(samples: PointSamples, analysis: AnalysisSettings, rate_hz: float = 0.0,
                    disturbance_lines: Sequence[float] = ()) -> tuple[list[ResponsePoint], bool]:
    """The points of one frequency from its samples (a bench's taken at ``rate_hz``, 0 if unknown, with the
    disturbance lines of its configuration, Hz); True when the record ended before every series stopped.
    ValueError saying why when too many of its periods had gaps."""
    grid = _grid_steps_per_period(samples) if samples.source == "offline" else 0
    sampler = Autointegrator(samples.frequency_hz, samples.amplitude, samples.channels, analysis, t0=samples.t0,
                             reference=samples.reference or None, grid_steps_per_period=grid,
                             reference_phase=samples.reference_phase,
                             samples_per_period=rate_hz / samples.frequency_hz if not grid else 0.0,
                             disturbance_lines=disturbance_lines,
                             reference_lines=carries_lines(samples.reference))
    for t, y in samples.batches:
        if sampler.done:
            break
        with np.errstate(all="ignore"):  # as live: garbage that got this far shows in the verdict
            sampler.feed(t, y)
    if sampler.failure:
        raise GapsError(sampler.failure)
    ended = not sampler.done
    if ended:
        sampler.end_of_record()
    with np.errstate(all="ignore"):
        points = sampler.points()
    ratios = samples.setpoint_ratios
    if ratios.size:  # taken against the setpoints as their frames carried them, as live
        points = taken_against(points, {p.periods: complex(ratios[p.periods - 1]) for p in points
                                        if 1 <= p.periods <= ratios.size})
    return (mark_untied(points) if samples.untied else points), ended


def reanalyse(directory: str | Path, **overrides: Any) -> Reanalysis:
    """Analyse the sweep in ``directory`` again from its samples, with its own [analysis] table (each frequency to the
    tolerance its points record, where the sweep changed it) but for ``overrides`` (keys of [analysis], e.g.
    ``criterion="full"``, ``tolerance_percent=0.1``; validated as in a configuration file). Raises ResultsError,
    ConfigError (a bad override), SamplesError (a missing or bad samples file)."""
    directory = Path(directory)
    stored = load_response(directory)
    measured = measured_of(stored.config)
    if overrides.get("measured", measured) != measured:
        raise ConfigError(f"{directory / SIDECAR_NAME}: analysis.measured: the samples hold the columns of "
                          f"{measured!r}; measuring {overrides['measured']!r} takes a new sweep", "analysis.measured")
    table = {**stored.config.get("analysis", {}), **overrides}
    analysis = build_table(AnalysisConfig, table, "analysis", str(directory / SIDECAR_NAME))
    config = {**stored.config, "analysis": {**stored.config.get("analysis", {}), **overrides}}
    points: list[ResponsePoint] = []
    ended: list[float] = []
    failed: list[tuple[float, str]] = []
    lines = disturbance_lines_of(stored.config, analysis)
    rate_hz = float(stored.config.get("bench", {}).get("rate_hz", 0.0) or 0.0)
    for f in dict.fromkeys(p.frequency_hz for p in stored.points):
        # a frequency measured to another tolerance than the table's (changed during the sweep) keeps its own
        recorded = {p.tolerance_percent for p in stored.points if p.frequency_hz == f}
        at_f = analysis
        if "tolerance_percent" not in overrides and len(recorded) == 1 and math.isfinite(tol := recorded.pop()):
            at_f = replace(analysis, tolerance_percent=tol)
        try:
            found, short = reanalyse_point(load_samples(samples_path(directory, f)), at_f, rate_hz, lines)
        except GapsError as exc:
            failed.append((f, str(exc)))
            continue
        points.extend(flag_disturbed(found, lines))
        if short:
            ended.append(f)
    return Reanalysis(FrequencyResponse(points, config=config, case=stored.case), analysis, tuple(ended),
                      tuple(failed))
