"""Autointegration of a multisine's lines: the overview measurement's numerics (docs/overview.md).

Each whole period of the multisine (N samples of the setpoint sent and of the output, on the same instants) gives
every excited line's response as the ratio of the output's coefficient to the setpoint's, H(i) (output units per
input unit). Each line's ratios form one series judged by the stopping rule ``[analysis] criterion`` names, exactly
as a sine's fundamental is (:mod:`bodebench.core.rules`): period after period until its 95 % interval is within
the tolerance, the rule finds the noise hopeless (noise-limited), or the period budget is spent (capped).

Beside every excited line, its detection lines (:meth:`bodebench.core.multisine.Multisine.detection_lines`) carry
what the plant adds that a linear plant would not. Over the later half of the analysed periods, each detection
line's mean coefficient and the standard error of that mean (from the period-to-period spread) give the line's
distortion (the rms of those means) and the noise it is read against (the rms of those standard errors), both in
output units: a linear plant's distortion is its noise (each mean is then noise alone), a nonlinear plant's stands
above it. Pure numerics: no I/O, no threads.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bodebench.core.multisine import Multisine, sine_coefficients
from bodebench.core.response import ResponsePoint
from bodebench.core.rules import SeriesHistory, StoppingRule, Verdict, make_rule

__all__ = ["LineIntegrator", "OverviewLine", "RuleSettings", "level_db"]


@dataclass(frozen=True)
class RuleSettings:
    """The stopping rule of every line: its name (``[analysis] criterion``) and parameters, the tolerance (percent)
    and the period budget of the whole measurement."""

    criterion: str
    tolerance_percent: float
    skip_periods: int
    window: int
    max_periods: int
    settle_periods: int = 50
    average_periods: int = 50

    def rule(self) -> StoppingRule:
        """A fresh rule for one line."""
        return make_rule(self.criterion, tolerance_percent=self.tolerance_percent, skip_periods=self.skip_periods,
                         window=self.window, settle_periods=self.settle_periods,
                         average_periods=self.average_periods, max_periods=self.max_periods)


@dataclass(frozen=True)
class OverviewLine:
    """One excited line's result.

    point: its response as a point of a sweep (amplitude the line's, input units; p + jq the output's coefficient,
    output units; its intervals and status the rule's verdict). distortion: the rms of the mean coefficients at
    its detection lines; noise: the rms of their standard errors (both output units, over the later half of the
    analysed periods; NaN with fewer than two periods there). detection: the detection lines' frequencies, Hz.
    """

    point: ResponsePoint
    distortion: float
    noise: float
    detection_hz: tuple[float, ...]

    @property
    def distortion_db(self) -> float:
        """The distortion relative to the output at the line, dB."""
        return level_db(self.distortion, self.point.magnitude)

    @property
    def noise_db(self) -> float:
        """The noise relative to the output at the line, dB."""
        return level_db(self.noise, self.point.magnitude)


def level_db(level: float, reference: float) -> float:
    """20 log10(level / reference), dB (NaN where either is not a positive number)."""
    if not (level > 0.0 and reference > 0.0) or math.isinf(level) or math.isinf(reference):
        return math.nan
    return 20.0 * math.log10(level / reference)


class LineIntegrator:
    """Integrates a multisine period after period until every excited line's rule has a verdict.

    design: the multisine; channel: the output's name; rules: the rule of every line and the period budget.
    Feed each whole period with :meth:`feed_period`; ``done`` says when to stop, :meth:`lines` gives the results.
    """

    def __init__(self, design: Multisine, channel: str, rules: RuleSettings) -> None:
        self.design = design
        self.channel = channel
        self.settings = rules
        self.lines = np.asarray(design.lines)
        detection = [design.detection_lines(int(k)) for k in self.lines]
        self._detection = detection
        # the lines whose output coefficients are kept every period: the excited ones, then their detection lines
        watched = sorted({int(k) for k in self.lines} | {d for lines in detection for d in lines})
        self._watched = np.asarray(watched)
        self._where = {k: i for i, k in enumerate(watched)}
        self._outputs: list[np.ndarray] = []  # per period, the output's coefficients on the watched lines
        self._histories = [SeriesHistory() for _ in self.lines]
        self._rules = [rules.rule() for _ in self.lines]
        self._verdicts: list[Verdict | None] = [None] * len(self.lines)
        self._scale = math.nan
        self.periods = 0

    @property
    def done(self) -> bool:
        """True once every line has a verdict."""
        return all(v is not None for v in self._verdicts)

    def feed_period(self, setpoint: np.ndarray, output: np.ndarray) -> None:
        """One whole period: the N setpoint samples sent (input units) and the N output samples (output units)
        taken on the same instants, sample n at n / rate_hz after the period's start."""
        if setpoint.shape != (self.design.samples,) or output.shape != (self.design.samples,):
            raise ValueError(f"a period is {self.design.samples} samples of setpoint and output, got "
                             f"{setpoint.shape} and {output.shape}")
        inputs = sine_coefficients(setpoint, self.lines)
        outputs = sine_coefficients(output, self._watched)
        self._outputs.append(outputs)
        ratios = outputs[[self._where[int(k)] for k in self.lines]] / inputs
        self.periods += 1
        n = self.periods
        sizes = np.abs(ratios)
        # the scale a line near zero is judged against: the largest response of the period, as a sine's largest
        # harmonic is for its others
        scale = float(np.max(sizes[np.isfinite(sizes)])) if np.isfinite(sizes).any() else math.nan
        self._scale = scale
        for i, (hist, rule) in enumerate(zip(self._histories, self._rules, strict=True)):
            hist.append(complex(ratios[i]))
            if self._verdicts[i] is not None:
                continue
            verdict = rule.check(hist, n, scale)
            if verdict is None and n >= self.settings.max_periods:
                verdict = rule.capped(hist, n, scale)
            self._verdicts[i] = verdict

    def result(self) -> list[OverviewLine]:
        """Every excited line's result, ascending in frequency (requires ``done``)."""
        if not self.done:
            raise RuntimeError("LineIntegrator.result() before every line has a verdict")
        outputs = np.array(self._outputs)  # (periods, watched lines)
        analysed = outputs[self.settings.skip_periods:]
        later = analysed[analysed.shape[0] // 2:]
        count = later.shape[0]
        means = later.mean(axis=0)
        if count >= 2:
            spread = np.sum(np.abs(later - means) ** 2, axis=0) / (count - 1)  # per period, both components
            errors = np.sqrt(spread / count)
        else:
            errors = np.full(means.shape, math.nan)
        resolution = self.design.resolution_hz
        out = []
        for i, k in enumerate(self.lines):
            verdict = self._verdicts[i]
            assert verdict is not None
            amplitude = self.design.line_amplitude
            point = ResponsePoint(frequency_hz=float(k) * resolution, harmonic=1, channel=self.channel,
                                  amplitude=amplitude, p=verdict.p * amplitude, q=verdict.q * amplitude,
                                  periods=verdict.period, converged=verdict.converged, status=verdict.status,
                                  uncertainty=verdict.uncertainty * amplitude,
                                  uncertainty_1d=verdict.uncertainty_1d * amplitude, within_eps=verdict.within_eps,
                                  periods_needed=verdict.periods_needed,
                                  tolerance_percent=self.settings.tolerance_percent)
            where = [self._where[d] for d in self._detection[i]]
            distortion = _rms(np.abs(means[where]))
            noise = _rms(errors[where])
            out.append(OverviewLine(point, distortion, noise, tuple(float(d) * resolution for d in self._detection[i])))
        return out

    @property
    def scale(self) -> float:
        """The largest line response of the latest period (output units per input unit): the tolerance's floor is
        :data:`~bodebench.core.rules.RESOLUTION` of it."""
        return self._scale


def _rms(values: Sequence[float] | np.ndarray) -> float:
    """The root mean square of ``values`` (NaN for none)."""
    array = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(array * array))) if array.size else math.nan
