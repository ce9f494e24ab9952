"""Monoharmonic autointegration of one frequency point: samples in, verdicts out.

Joins the per-period integrator (``bodebench.core.fourier``) with a stopping rule
per series (one series = one channel x one harmonic). Pure numerics: the
caller brings timestamped samples from a simulation or a bus.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bodebench.core.fourier import PeriodIntegrator
from bodebench.core.quality import coherence, coherence_periods, total_harmonic_distortion
from bodebench.core.response import ResponsePoint
from bodebench.core.rules import SeriesHistory, StoppingRule, Verdict, make_rule


class AnalysisSettings(Protocol):
    """What the sampler needs to know of the analysis (``[analysis]`` of a configuration provides it): the
    harmonics, the stopping rule's name and parameters (tolerance in percent, periods), and the period limit."""

    @property
    def harmonics(self) -> tuple[int, ...]: ...
    @property
    def criterion(self) -> str: ...
    @property
    def tolerance_percent(self) -> float: ...
    @property
    def skip_periods(self) -> int: ...
    @property
    def window(self) -> int: ...
    @property
    def settle_periods(self) -> int: ...
    @property
    def average_periods(self) -> int: ...
    @property
    def max_periods(self) -> int: ...

_FEW_PERIODS = 4  # periods up to which feed() works on Python scalars (cheaper than numpy's per-call cost)


@dataclass(frozen=True)
class SeriesState:
    """Where one series stands after the latest period (for progress displays).

    estimate: the rule's current coefficient estimate P + jQ (output units);
    uncertainty: its confidence half-width (NaN until the rule can tell);
    tolerance: the half-width at which the rule stops (output units, NaN until known).
    """

    channel: str
    harmonic: int
    periods: int
    estimate: complex
    uncertainty: float
    verdict: Verdict | None
    tolerance: float = math.nan


class Autointegrator:
    """Integrates period after period until every series' rule stops or ``max_periods`` is reached.

    frequency_hz: excitation frequency f (Hz); amplitude: input amplitude A_i
    (input units), for gains; channels: names of the measured columns fed;
    t0: instant (s) at which the excitation sine has phase zero.

    reference: two-channel mode. One more column (fed last) carries the input
    as the drive saw it (e.g. the echoed setpoint). Every period, each output
    coefficient is taken relative to that period's reference fundamental
    ``Z_r``: ``Z_k * A_i * (conj(Z_r)/|Z_r|)**k / |Z_r|``, so gain and phase
    are output over input whatever delay or amplitude error the path to the
    drive added, and the rules judge that ratio.
    """

    def __init__(self, frequency_hz: float, amplitude: float, channels: Sequence[str],
                 analysis: AnalysisSettings, t0: float = 0.0, reference: str | None = None) -> None:
        self.frequency_hz = frequency_hz
        self.amplitude = amplitude
        self.channels = tuple(channels)
        self.harmonics = tuple(analysis.harmonics)
        self.max_periods = analysis.max_periods
        self.skip_periods = analysis.skip_periods
        self.reference = reference
        harmonics = self.harmonics if reference is None or 1 in self.harmonics else (*self.harmonics, 1)
        self._ref_index = harmonics.index(1) if reference is not None else -1
        self._integrator = PeriodIntegrator(frequency_hz, harmonics, len(self.channels) + (reference is not None),
                                            t0)
        self._histories = [[SeriesHistory() for _ in self.harmonics] for _ in self.channels]
        self._rules: list[list[StoppingRule]] = [
            [make_rule(analysis.criterion, tolerance_percent=analysis.tolerance_percent,
                       skip_periods=analysis.skip_periods, window=analysis.window,
                       settle_periods=analysis.settle_periods, average_periods=analysis.average_periods,
                       max_periods=analysis.max_periods)
             for _ in self.harmonics] for _ in self.channels]
        self._verdicts: list[list[Verdict | None]] = [[None] * len(self.harmonics) for _ in self.channels]
        self._pending = len(self.channels) * len(self.harmonics)  # series still without a verdict
        self.periods = 0
        # the first harmonic (else the first listed) leads: the others are judged only once it has settled,
        # so a small harmonic cannot stop on the calm before the transient of its channel has died out
        self._primary = self.harmonics.index(1) if 1 in self.harmonics else 0
        self._order = [self._primary] + [k for k in range(len(self.harmonics)) if k != self._primary]
        self._last_references: list[float] = [math.nan] * len(self.channels)

    @property
    def done(self) -> bool:
        """True once every series has a verdict."""
        return self._pending == 0

    def feed(self, t: np.ndarray, y: np.ndarray) -> int:
        """Take samples (t in s, increasing; y shaped (n, channels)); returns the periods completed."""
        p, q = self._integrator.feed(t, y)
        m = p.shape[0]
        if m == 0 or self.done:
            self.periods += m
            return m
        z = p + 1j * q  # (m, channel, harmonic)
        if self.reference is not None:
            z_ref = z[:, -1, self._ref_index]
            rotation = np.conj(z_ref) / np.abs(z_ref)
            powers = np.array(self.harmonics)
            z = z[:, :-1, : len(self.harmonics)] * (self.amplitude / np.abs(z_ref))[:, None, None] \
                * rotation[:, None, None] ** powers[None, None, :]
        # each channel's scale: its largest coefficient of the period (output units)
        if m <= _FEW_PERIODS:
            values = z.tolist()
            for period in values:
                for c, row in enumerate(self._histories):
                    for k, hist in enumerate(row):
                        hist.append(period[c][k])
            references = [[max(abs(v) for v in row) for row in period] for period in values]
        else:
            for c, row in enumerate(self._histories):
                for k, hist in enumerate(row):
                    hist.extend(z[:, c, k])
            references = np.max(np.abs(z), axis=2).tolist()
        self._last_references = references[-1]
        primary, order, max_periods = self._primary, self._order, self.max_periods
        for i in range(m):
            n = self.periods + i + 1
            for c, verdicts in enumerate(self._verdicts):
                reference = references[i][c]
                rules, histories = self._rules[c], self._histories[c]
                for k in order:
                    if verdicts[k] is not None or (k != primary and verdicts[primary] is None):
                        continue
                    verdict = rules[k].check(histories[k], n, reference)
                    if verdict is None and n >= max_periods:
                        verdict = rules[k].capped(histories[k], n, reference)
                    if verdict is not None:
                        verdicts[k] = verdict
                        self._pending -= 1
            if self._pending == 0:
                break
        self.periods += m
        return m

    def end_of_record(self) -> None:
        """The samples ended before every series had a verdict (a record analysed again with a rule that wants more
        periods): each series still open is capped at the last whole period, as at ``max_periods``."""
        for c, verdicts in enumerate(self._verdicts):
            for k in self._order:
                if verdicts[k] is None:
                    hist = self._histories[c][k]
                    if hist.n == 0:
                        raise ValueError(f"the record of {self.frequency_hz:g} Hz holds no whole period")
                    verdicts[k] = self._rules[c][k].capped(hist, hist.n, self._last_references[c])
                    self._pending -= 1

    def states(self) -> list[SeriesState]:
        """Progress of every series at the latest period."""
        out = []
        for c, name in enumerate(self.channels):
            for k, harmonic in enumerate(self.harmonics):
                verdict = self._verdicts[c][k]
                hist = self._histories[c][k]
                if verdict is not None:
                    est, unc, n = complex(verdict.p, verdict.q), verdict.uncertainty, verdict.period
                elif hist.n:
                    est, unc = self._rules[c][k].estimate(hist, hist.n)
                    n = hist.n
                else:
                    est, unc, n = complex("nan"), float("nan"), 0
                reference = self._last_references[c]
                tol = self._rules[c][k].tolerance(est, reference) if n and math.isfinite(reference) else math.nan
                out.append(SeriesState(name, harmonic, n, est, unc, verdict, tol))
        return out

    def history(self, channel: str, harmonic: int) -> np.ndarray:
        """Per-period coefficients P(i) + jQ(i) of one series so far."""
        return self._histories[self.channels.index(channel)][self.harmonics.index(harmonic)].values

    def points(self) -> list[ResponsePoint]:
        """The measured points, one per series (requires ``done``)."""
        if not self.done:
            raise RuntimeError("Autointegrator.points() before every series has a verdict")
        pts = []
        for c, name in enumerate(self.channels):
            verdicts = self._verdicts[c]
            thd = math.nan
            if 1 in self.harmonics:
                fundamental = verdicts[self.harmonics.index(1)]
                assert fundamental is not None
                thd = total_harmonic_distortion(complex(fundamental.p, fundamental.q),
                                                [complex(v.p, v.q) for k, v in zip(self.harmonics, verdicts,
                                                                                   strict=True)
                                                 if k != 1 and v is not None])
            for k, harmonic in enumerate(self.harmonics):
                v = verdicts[k]
                assert v is not None
                start, stop = coherence_periods(self.skip_periods, v.period)
                pts.append(ResponsePoint(frequency_hz=self.frequency_hz, harmonic=harmonic, channel=name,
                                         amplitude=self.amplitude, p=v.p, q=v.q, periods=v.period,
                                         converged=v.converged, status=v.status, uncertainty=v.uncertainty,
                                         uncertainty_1d=v.uncertainty_1d, within_eps=v.within_eps,
                                         periods_needed=v.periods_needed,
                                         thd=thd if harmonic == 1 else math.nan,
                                         coherence=coherence(self._histories[c][k].values[start:stop])))
        return pts
