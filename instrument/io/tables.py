"""The tables of a configuration file, one frozen dataclass each, validated by :mod:`bodebench.io.schema`.

[plant], [excitation] and [analysis] describe a measurement (an offline one needs no more). A ``[bench]`` table
makes it a bench session on a drive over a bus: [can] or [serial] say how to reach it, [safety] what protects it,
[frames] (checked by the frame layout itself, :meth:`bodebench.drivers.Layout.from_mapping`) what the frames
carry, and [simulator] stands a simulated servo controller around [plant] in for the drive.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

from bodebench.core.autointegration import DEFAULT_BENCH_POINT_S, MIN_BUDGET_PERIODS
from bodebench.core.measured import MEASURED
from bodebench.core.multisine import Multisine, design_multisine
from bodebench.core.refine import FIGURE_NAMES
from bodebench.core.rules import CRITERIA, MIN_NOISE_EVIDENCE
from bodebench.core.summary import RESPONSE_KINDS
from bodebench.drivers.cia402 import ABORT_CONNECTION_OPTIONS
from bodebench.drivers.device_profile import PROFILES
from bodebench.io.schema import FieldError
from bodebench.sim.faults import CanopenFaults, FaultConfig
from bodebench.sim.loop_config import LoopConfig

DEFAULT_DISTURBANCE_HZ = (50.0,)
"""[analysis] disturbance_hz on a real drive when the configuration gives none: mains."""
DISTURBANCE_POLICIES = ("flag", "move")
"""What a bench does with a frequency whose measured harmonic lies on a disturbance line ([analysis] disturbances)."""
FOLD_POLICIES = ("bound", "keep", "move")
"""What a bench does with a frequency at which its sample rate folds harmonics exactly onto measured ones
([analysis] folds)."""

__all__ = [
    "AmplitudeProfile",
    "AnalysisConfig",
    "BenchConfig",
    "CanConfig",
    "CanopenConfig",
    "ExcitationConfig",
    "FrequencyRange",
    "OverviewConfig",
    "PlantConfig",
    "ResultsConfig",
    "SafetyConfig",
    "SerialConfig",
    "SimulatorConfig",
]

TRANSPORTS = ("can", "serial", "canopen")
CLOCKS = ("lockstep", "realtime")
TIMEBASES = ("counter", "sync", "timestamp", "receive")
MIN_SAMPLES_PER_PERIOD = 8  # of the highest harmonic measured
MIN_FREQUENCY_HZ = 1e-3
"""Lowest frequency swept: a period of 1000 s, so that a point (a ramp of whole periods, then the periods the
stopping rule needs) takes more than an hour. No drive is swept slower; a smaller value is a typing error (a
frequency in kHz, a wrong exponent)."""
MAX_FREQUENCY_HZ = 1e6
"""Highest frequency swept: far above any servo drive's loop (a few kHz at most); a larger value is a typing error."""
MAX_RATE_HZ = 1e5
"""Highest sample rate of a drive's setpoints and feedback: more frames a second than a CAN bus or a serial line
carries."""


_HYDRAULIC = ("model", ("hydraulic",))


@dataclass(frozen=True)
class PlantConfig:
    """The simulated plant (docs/METHOD.md section 2); all quantities dimensionless unless stated. Required where
    something is simulated (an offline experiment, a bench config with [simulator]); a real drive needs none."""

    TABLE_OPTIONAL = True

    model: str = field(
        metadata={
            "choices": ("coulomb", "linear", "lag", "hydraulic", "valve"),
            "doc": "plant model: coulomb, linear, lag, hydraulic (electrohydraulic position drive, SI units) or valve "
                   "(a proportional valve's spool in its position loop: valve_natural_frequency_hz, "
                   "valve_damping_ratio)",
        }
    )
    mass: float = field(
        default=1.0,
        metadata={"min": 0, "min_exclusive": True, "only_if": ("model", ("coulomb", "linear")), "doc": "mass m"},
    )
    stiffness: float = field(
        default=1.0,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": ("model", ("coulomb", "linear")),
            "doc": "position (spring) load K_p",
        },
    )
    friction: float = field(
        default=0.0,
        metadata={"min": 0, "only_if": ("model", ("coulomb",)), "doc": "dry-friction force F_ct"},
    )
    damping_ratio: float = field(
        default=0.0,
        metadata={
            "min": 0,
            "only_if": ("model", ("coulomb", "linear")),
            "doc": "viscous damping ratio zeta (dimensionless)",
        },
    )
    time_constant: float = field(
        default=1.0,
        metadata={"min": 0, "min_exclusive": True, "only_if": ("model", ("lag",)), "doc": "lag time constant, s"},
    )
    gain: float = field(
        default=1.0,
        metadata={"nonzero": True, "only_if": ("model", ("lag",)), "doc": "lag static gain (dimensionless)"},
    )

    # The electrohydraulic position drive (sim/hydraulic.py); defaults: a ~10 kN industrial cylinder.
    supply_pressure: float = field(
        default=210e5,
        metadata={"min": 0, "min_exclusive": True, "only_if": _HYDRAULIC, "doc": "supply pressure P_s, Pa"},
    )
    valve_gain: float = field(
        default=1.8e-7,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": _HYDRAULIC,
            "doc": "valve flow gain K_q in Q_L = K_q x_v sqrt((P_s - sign(x_v) P_L)/2), m^3/(s*Pa^0.5)",
        },
    )
    valve_natural_frequency_hz: float = field(
        default=150.0,
        metadata={"min": 0, "min_exclusive": True, "only_if": ("model", ("hydraulic", "valve")),
                  "doc": "servo valve natural frequency, Hz"},
    )
    valve_damping_ratio: float = field(
        default=0.7,
        metadata={"min": 0, "only_if": ("model", ("hydraulic", "valve")),
                  "doc": "servo valve damping ratio (dimensionless)"},
    )
    piston_area: float = field(
        default=5e-4,
        metadata={"min": 0, "min_exclusive": True, "only_if": _HYDRAULIC, "doc": "piston area A_p, m^2"},
    )
    total_volume: float = field(
        default=1.5e-4,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": _HYDRAULIC,
            "doc": "total oil volume V_t of both chambers and lines, m^3",
        },
    )
    bulk_modulus: float = field(
        default=1.4e9,
        metadata={"min": 0, "min_exclusive": True, "only_if": _HYDRAULIC, "doc": "effective bulk modulus, Pa"},
    )
    leakage: float = field(
        default=2e-12,
        metadata={"min": 0, "only_if": _HYDRAULIC, "doc": "cross-port leakage coefficient C_l, m^3/(s*Pa)"},
    )
    piston_mass: float = field(
        default=40.0,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": _HYDRAULIC,
            "doc": "moving mass (piston, rod, load), kg",
        },
    )
    load_stiffness: float = field(
        default=0.0,
        metadata={"min": 0, "only_if": _HYDRAULIC, "doc": "load spring stiffness K_load, N/m"},
    )
    viscous_damping: float = field(
        default=2000.0,
        metadata={"min": 0, "only_if": _HYDRAULIC, "doc": "viscous damping b, N*s/m"},
    )
    coulomb_friction: float = field(
        default=150.0,
        metadata={"min": 0, "only_if": _HYDRAULIC, "doc": "Coulomb (stick-slip) friction force F_c, N"},
    )
    loop_gain: float = field(
        default=60.0,
        metadata={
            "min": 0,
            "min_exclusive": True,
            "only_if": _HYDRAULIC,
            "doc": "position-loop gain K_loop: normalised valve current per metre of position error, 1/m",
        },
    )


PLAN_MAX_POINTS = 10_000
"""Most frequencies a log-spaced range may expand to."""


PLAN_FIGURES = tuple(FIGURE_NAMES)
"""Summary figures an adaptive plan can pin down (:mod:`bodebench.core.refine`)."""


@dataclass(frozen=True)
class AdaptivePlan:
    """A plan that adds frequencies between those of the range until each requested summary figure, and the curve
    between the points, is known to the stated accuracy by interpolation, or the budget is spent."""

    figures: tuple[str, ...] = field(default=PLAN_FIGURES, metadata={
        "choices": PLAN_FIGURES, "unique": True,
        "doc": "the summary figures to pin down (those the response kind has: a closed loop's bandwidth and "
               "resonance, an open loop's margins, the phase crossings of either)"})
    frequency_percent: float = field(default=1.0, metadata={
        "min": 0, "min_exclusive": True, "max": 50,
        "doc": "accuracy of each figure read as a frequency (bandwidth, crossings, the resonance frequency), % of it"})
    gain_db: float = field(default=0.1, metadata={
        "min": 0, "min_exclusive": True, "doc": "accuracy of each figure in dB (resonance peak, gain margin), dB"})
    phase_deg: float = field(default=1.0, metadata={
        "min": 0, "min_exclusive": True, "doc": "accuracy of each figure in degrees (phase margin), deg"})
    curve: bool = field(default=True, metadata={
        "doc": "add frequencies where the curve drawn between two neighbouring points may be further from the "
               "response than curve_gain_db or curve_phase_deg (false: for the figures only)"})
    curve_gain_db: float = field(default=1.0, metadata={
        "min": 0, "min_exclusive": True,
        "doc": "largest interpolation error of the gain curve between two neighbouring points, dB"})
    curve_phase_deg: float = field(default=10.0, metadata={
        "min": 0, "min_exclusive": True,
        "doc": "largest interpolation error of the phase curve between two neighbouring points, deg"})
    max_points: int = field(default=60, metadata={
        "min": 2, "max": PLAN_MAX_POINTS, "doc": "most frequencies in all, the range's included"})
    from_overview: bool = field(default=False, metadata={
        "doc": "run the [overview] multisine first and add to the range's frequencies those its lines call for, "
               "read as the rounds read the measured points"})
    budget_s: float | None = field(default=None, metadata={
        "min": 0, "min_exclusive": True,
        "doc": "bench time after which no frequency is added, s (the periods measured, settled and ramped at each "
               "frequency over its frequency; none: no limit but max_points)"})


@dataclass(frozen=True)
class FrequencyRange:
    """Log-spaced frequencies: ``start_hz * 10**(i / per_decade)`` for i = 0, 1, ... up to ``stop_hz``, each
    rounded to 6 significant digits; ``stop_hz`` is the last one when it falls on the grid (within 1e-9). With
    ``adaptive``, these are the first frequencies of a plan that adds more between them."""

    start_hz: float = field(metadata={"min": 0, "min_exclusive": True, "doc": "first frequency, Hz"})
    stop_hz: float = field(metadata={"min": 0, "min_exclusive": True, "doc": "last frequency at most, Hz"})
    per_decade: int = field(metadata={"min": 1, "max": 1000, "doc": "points per decade"})
    adaptive: AdaptivePlan | None = field(default=None, metadata={
        "doc": "add frequencies where the curve bends or a summary figure is not yet known to its accuracy "
               "(none: the range's frequencies only)"})

    def validate(self, where: Callable[[str], str]) -> None:
        """Stop above start, and not too many points; raises :class:`FieldError`."""
        if not self.stop_hz > self.start_hz:
            raise FieldError("stop_hz", f"must be > {where('start_hz')} ({self.start_hz:g} Hz), got {self.stop_hz:g}")
        count = len(self.expand())
        if count > PLAN_MAX_POINTS:
            raise FieldError("per_decade", f"{count} frequencies, more than {PLAN_MAX_POINTS}")
        if self.adaptive is not None and count > self.adaptive.max_points:
            raise FieldError("adaptive", f"max_points = {self.adaptive.max_points} is fewer than the range's "
                                         f"{count} frequencies")
        if self.adaptive is not None and not self.adaptive.figures and not self.adaptive.curve:
            raise FieldError("adaptive", "asks for no figure and no curve (figures = [], curve = false): nothing "
                                         "would add a frequency")

    def expand(self) -> tuple[float, ...]:
        """The frequencies, Hz, ascending."""
        decades = math.log10(self.stop_hz / self.start_hz)
        count = math.floor(decades * self.per_decade + 1e-9) + 1
        return tuple(float(f"{self.start_hz * 10.0 ** (i / self.per_decade):.6g}") for i in range(count))


@dataclass(frozen=True)
class AmplitudeProfile:
    """Amplitude against frequency: straight lines between the knots on log-log axes, constant beyond the ends."""

    frequencies_hz: tuple[float, ...] = field(metadata={
        "min": 0, "min_exclusive": True, "non_empty": True, "unique": True, "doc": "knot frequencies, Hz, ascending"})
    amplitudes: tuple[float, ...] = field(metadata={
        "min": 0, "min_exclusive": True, "non_empty": True, "doc": "amplitude at each knot, input units"})

    def validate(self, where: Callable[[str], str]) -> None:
        """As many amplitudes as knots, knots ascending; raises :class:`FieldError`."""
        if len(self.amplitudes) != len(self.frequencies_hz):
            raise FieldError("amplitudes", f"{len(self.amplitudes)} values for {len(self.frequencies_hz)} knots in "
                                           f"{where('frequencies_hz')}")
        for i in range(1, len(self.frequencies_hz)):
            if not self.frequencies_hz[i] > self.frequencies_hz[i - 1]:
                raise FieldError("frequencies_hz", f"knots must ascend: [{i}] = {self.frequencies_hz[i]:g} Hz "
                                                   f"after {self.frequencies_hz[i - 1]:g} Hz")

    def at(self, frequency_hz: float) -> float:
        """The amplitude at ``frequency_hz``, input units."""
        x = math.log10(frequency_hz)
        xs = [math.log10(f) for f in self.frequencies_hz]
        ys = [math.log10(a) for a in self.amplitudes]
        if x <= xs[0]:
            return self.amplitudes[0]
        if x >= xs[-1]:
            return self.amplitudes[-1]
        i = max(j for j in range(len(xs)) if xs[j] <= x)
        t = (x - xs[i]) / (xs[i + 1] - xs[i])
        return float(10.0 ** (ys[i] + t * (ys[i + 1] - ys[i])))


@dataclass(frozen=True)
class ExcitationConfig:
    """The sine input: the frequencies to measure at (a list or a log-spaced range), the amplitude at each (a
    constant, a list or a profile), and the periods to settle at each before the analysis."""

    amplitude: float | None = field(
        default=None,
        metadata={"min": 0, "min_exclusive": True,
                  "doc": "input amplitude A_i (A_F for the friction link) at every frequency (or give amplitudes or "
                         "amplitude_profile)"}
    )
    frequencies_hz: tuple[float, ...] = field(
        default=(),
        metadata={
            "min": 0,
            "min_exclusive": True,
            "non_empty": True,
            "unique": True,
            "doc": f"measurement frequencies, Hz, {MIN_FREQUENCY_HZ:g} to {MAX_FREQUENCY_HZ:g} (or give frequencies)",
        }
    )
    frequencies: FrequencyRange | None = field(default=None, metadata={
        "doc": "log-spaced frequencies {start_hz, stop_hz, per_decade}, instead of frequencies_hz"})
    amplitudes: tuple[float, ...] | None = field(default=None, metadata={
        "min": 0, "min_exclusive": True, "doc": "amplitude at each frequency, input units (one per frequency)"})
    amplitude_profile: AmplitudeProfile | None = field(default=None, metadata={
        "doc": "amplitude against frequency {frequencies_hz, amplitudes}: log-log lines between the knots"})
    settle_periods: int | None = field(default=None, metadata={
        "min": 0, "doc": "whole periods at full amplitude before the first integrated period of each frequency "
                         "(not counted in its periods)"})
    settle_periods_per_frequency: tuple[int, ...] | None = field(default=None, metadata={
        "min": 0, "doc": "settle periods at each frequency (one per frequency), instead of settle_periods"})

    def __post_init__(self) -> None:
        if not self.frequencies_hz and self.frequencies is not None:
            object.__setattr__(self, "frequencies_hz", self.frequencies.expand())

    def validate(self, where: Callable[[str], str]) -> None:
        """One frequency plan, lists as long as it, one amplitude rule, one settle rule; raises
        :class:`FieldError`."""
        if not self.frequencies_hz:
            raise FieldError("frequencies_hz", "missing (give frequencies_hz = [...] or frequencies = {start_hz, "
                                               "stop_hz, per_decade})")
        if self.frequencies is not None and self.frequencies_hz != self.frequencies.expand():
            raise FieldError("frequencies", f"give either this or {where('frequencies_hz')}, not both")
        if self.adaptive is not None:
            for name in ("amplitudes", "settle_periods_per_frequency"):
                if getattr(self, name) is not None:
                    raise FieldError(name, "one value per frequency cannot follow an adaptive plan, whose frequencies "
                                           "are not known before the sweep (give amplitude or amplitude_profile, and "
                                           "settle_periods)")
        n = len(self.frequencies_hz)
        rules = [name for name in ("amplitude", "amplitudes", "amplitude_profile") if getattr(self, name) is not None]
        if not rules:
            raise FieldError("amplitude", "missing (give amplitude, amplitudes = [...] (one per frequency) or "
                                          "amplitude_profile = {frequencies_hz, amplitudes})")
        if len(rules) > 1:
            raise FieldError(rules[1], f"give either this or {where(rules[0])}, not both")
        if self.amplitudes is not None and len(self.amplitudes) != n:
            raise FieldError("amplitudes", f"{len(self.amplitudes)} values for {n} frequencies")
        if self.settle_periods_per_frequency is not None:
            if self.settle_periods is not None:
                raise FieldError("settle_periods_per_frequency",
                                 f"give either this or {where('settle_periods')}, not both")
            if len(self.settle_periods_per_frequency) != n:
                raise FieldError("settle_periods_per_frequency",
                                 f"{len(self.settle_periods_per_frequency)} values for {n} frequencies")

    @property
    def adaptive(self) -> AdaptivePlan | None:
        """The adaptive plan that adds frequencies to these, if any."""
        return self.frequencies.adaptive if self.frequencies is not None else None

    def with_frequencies(self, frequencies_hz: Sequence[float]) -> ExcitationConfig:
        """The plan with ``frequencies_hz`` (Hz) in place of its frequencies (a bench's moved ones, an adaptive plan's
        grown ones); the range and its adaptive plan are kept."""
        return replace(self, frequencies_hz=tuple(frequencies_hz))

    def frequencies_to_check(self) -> tuple[float, ...]:
        """The frequencies (Hz) whose amplitude and slew bound every frequency the plan can measure: its own, and for
        an adaptive plan with an amplitude profile, the profile's knots between them too (the amplitude and the
        slew 2 pi f A are monotonic between knots on log-log lines, so their largest lie there or at the ends)."""
        if self.adaptive is None or self.amplitude_profile is None:
            return self.frequencies_hz
        lo, hi = min(self.frequencies_hz), max(self.frequencies_hz)
        return self.frequencies_hz + tuple(f for f in self.amplitude_profile.frequencies_hz
                                           if lo < f < hi and f not in self.frequencies_hz)

    def _index(self, frequency_hz: float) -> int:
        try:
            return self.frequencies_hz.index(frequency_hz)
        except ValueError:
            raise ValueError(f"{frequency_hz:g} Hz is not a frequency of the plan") from None

    def amplitude_at(self, frequency_hz: float) -> float:
        """The input amplitude at ``frequency_hz`` (one of the plan's), input units."""
        if self.amplitudes is not None:
            return self.amplitudes[self._index(frequency_hz)]
        if self.amplitude_profile is not None:
            return self.amplitude_profile.at(frequency_hz)
        assert self.amplitude is not None  # validate() saw one amplitude rule
        return self.amplitude

    def settle_at(self, frequency_hz: float) -> int:
        """Periods settled at ``frequency_hz`` (one of the plan's) before its analysis."""
        if self.settle_periods_per_frequency is not None:
            return self.settle_periods_per_frequency[self._index(frequency_hz)]
        return self.settle_periods or 0

    def only(self, frequency_hz: float) -> ExcitationConfig:
        """The plan reduced to ``frequency_hz`` (one of the plan's), with its amplitude and settle periods."""
        amplitudes = None if self.amplitudes is None else (self.amplitude_at(frequency_hz),)
        settle = (None if self.settle_periods_per_frequency is None else (self.settle_at(frequency_hz),))
        return replace(self, frequencies_hz=(frequency_hz,), frequencies=None, amplitudes=amplitudes,
                       settle_periods_per_frequency=settle)


@dataclass(frozen=True)
class AnalysisConfig:
    """Harmonic analysis and stopping rule (docs/METHOD.md section 1)."""

    harmonics: tuple[int, ...] = field(
        default=(1,),
        metadata={"min": 1, "non_empty": True, "unique": True, "doc": "harmonic numbers k to measure"},
    )
    tolerance_percent: float = field(
        default=0.01,
        metadata={"min": 0, "min_exclusive": True, "max": 100, "max_exclusive": True,
                  "doc": "stopping tolerance eps, percent (below 100: a tolerance of the whole response is none)"},
    )
    skip_periods: int = field(default=1, metadata={"min": 0, "doc": "periods n_k not analysed"})
    criterion: str = field(default="adaptive", metadata={"choices": CRITERIA, "doc": "stopping rule"})
    window: int = field(default=5, metadata={"min": 2, "doc": "window length l, periods"})
    max_periods: int = field(default=20000, metadata={"min": 1, "doc": "period limit per frequency"})
    max_point_s: float | None = field(default=None, metadata={
        "min": 0, "min_exclusive": True,
        "doc": "time budget per point, s: at most this many seconds of periods are integrated (never fewer than "
               f"{MIN_BUDGET_PERIODS} periods, never more than max_periods), and a series whose noise needs more "
               f"than twice that ends noise_limited after {MIN_NOISE_EVIDENCE} periods (default: "
               f"{DEFAULT_BENCH_POINT_S:g} on a bench, none offline)"})
    steps_per_period: int = field(default=200, metadata={"min": 8, "doc": "integration steps per period K_f"})
    settle_periods: int = field(
        default=50, metadata={"min": 0, "doc": 'periods discarded (criterion "fixed" only)'}
    )
    average_periods: int = field(
        default=50, metadata={"min": 1, "doc": 'periods averaged (criterion "fixed" only)'}
    )
    max_gap_cycles: float = field(default=0.25, metadata={
        "min": 0, "min_exclusive": True, "max": 1,
        "doc": "longest interval between two samples a period may contain, in cycles of the highest harmonic "
               "measured; a period with a longer gap is discarded, not integrated"})
    max_discarded_percent: float = field(default=50.0, metadata={
        "min": 0, "max": 100, "max_exclusive": True,
        "doc": "a point fails when more than this share of its periods was discarded for gaps, percent"})
    disturbance_hz: tuple[float, ...] | None = field(default=None, metadata={
        "min": 0, "min_exclusive": True, "unique": True,
        "doc": "periodic disturbances on the bench, Hz, each with its 2nd and 3rd harmonic (mains hum): a point "
               "whose measured harmonic lies within its resolution of one is flagged disturbed, and what a line "
               "near a harmonic above the measured ones leaks into them is bounded in the interval; "
               "[] for none "
               "(default: [50] on a real drive; on the simulated drive its hum_hz where it has a hum, else none)"})
    disturbances: str | None = field(default=None, metadata={
        "choices": DISTURBANCE_POLICIES,
        "doc": "flag (default): such points are measured and flagged disturbed; move: the plan moves each frequency "
               "whose harmonic lies within 2 % of a disturbance line off it, saying so"})
    folds: str | None = field(default=None, metadata={
        "choices": FOLD_POLICIES,
        "doc": "bench: bound (default): the frequencies as given, and each point's interval carries a bound on "
               "what the sample rate folds onto it, read from the record's content above the measured harmonics "
               "(on a whole number of samples a period, from the waveform averaged phase by phase, up to half the "
               "samples a period); a point goes on while more periods can make room for it, and ends "
               "alias_limited where the bound alone exceeds the tolerance; the bound assumes harmonics falling as "
               "1/j^2, as an output with corners does (a saturated or rate-limited signal), and errs large on a "
               "smoother one (fold_decay declares a faster fall in the tail a whole grid shows); keep: the "
               "frequencies as given and no bound, the loader warning where the rate folds harmonics up to 32 "
               "exactly onto measured ones; move: each frequency at which the rate would fold high harmonics of a "
               "nonlinear response onto measured ones, every period alike, is moved by the least that makes each "
               "fold turn (a fraction of a percent), saying so: such content then shows in the spread of the "
               "periods and the point ends capped or noise-limited instead of converged to it"})
    fold_decay: float = field(default=2.0, metadata={
        "min": 1, "max": 4,
        "doc": "bench, folds = bound: the power j^-d at least as fast as which the output's harmonics fall in "
               "their tail, beyond those the record shows, for the fold bound on a whole number N of samples a "
               "period (read from harmonics N/4 to N/2 of the waveform averaged phase by phase; elsewhere the "
               "bound extends the solved harmonics, up to 8, as j^-2): 1 for an output with steps (a relay, an "
               "on/off valve, a coarse quantiser's staircase); 2 (default) for an output with corners (a "
               "saturated or rate-limited signal, a velocity where the force jumps); 3 for a position whose "
               "acceleration jumps (a mass under dry friction or a held setpoint); declared slower than the true "
               "fall, the bound errs large, declared faster, it can miss"})
    measured: str | None = field(default=None, metadata={
        "choices": MEASURED,
        "doc": "what the sweep measures (docs/loop.md): output (default: each output channel against the excitation), "
               "plant (each output channel over bench.effort_channel), loop (-control/effort, the loop gain), "
               "sensitivity (effort/(effort - control)) or complementary (-control/(effort - control)); the "
               "ratios are taken period by period"})
    response: str | None = field(default=None, metadata={
        "choices": RESPONSE_KINDS,
        "doc": "what the measured response is, for its summary: system, closed_loop, or open_loop (adds the gain "
               "and phase margins); default: open_loop when measured = loop, closed_loop when complementary, else "
               "system"})

    @property
    def disturbance_policy(self) -> str:
        """What the plan does with a frequency on a disturbance line (:data:`DISTURBANCE_POLICIES`)."""
        return self.disturbances or DISTURBANCE_POLICIES[0]

    @property
    def fold_policy(self) -> str:
        """What the plan does with a frequency whose sample count folds harmonics onto measured ones
        (:data:`FOLD_POLICIES`)."""
        return self.folds or FOLD_POLICIES[0]

    @property
    def response_kind(self) -> str:
        """The kind of response the summary reads (:data:`bodebench.core.summary.RESPONSE_KINDS`)."""
        return self.response or {"loop": "open_loop", "complementary": "closed_loop"}.get(self.measurement, "system")

    @property
    def measurement(self) -> str:
        """What the sweep measures (:data:`bodebench.core.measured.MEASURED`)."""
        return self.measured or MEASURED[0]

    def validate(self, where: Callable[[str], str]) -> None:
        """Cross-field checks; raises :class:`FieldError`."""
        if self.max_periods <= self.skip_periods:
            raise FieldError("max_periods", f"must be > {where('skip_periods')} ({self.skip_periods})")


OVERVIEW_RATE_PER_STOP = 50
"""Offline, the overview's sample rate where ``[overview] rate_hz`` is not given: this many samples a period of its
highest line."""


@dataclass(frozen=True)
class OverviewConfig:
    """The overview measurement (``bodebench overview``, docs/overview.md): a periodic multisine of odd lines
    log-spread between two frequencies, each line averaged period after period to the tolerance, the lines left out
    showing the plant's nonlinear distortion."""

    TABLE_OPTIONAL = True

    start_hz: float = field(metadata={"min": MIN_FREQUENCY_HZ, "max": MAX_FREQUENCY_HZ,
                                      "doc": "lowest excited line, Hz (the first line lies on the period's grid "
                                             "within a fraction of a percent of it)"})
    stop_hz: float = field(metadata={"min": MIN_FREQUENCY_HZ, "max": MAX_FREQUENCY_HZ,
                                     "doc": "highest excited line at most, Hz"})
    amplitude: float = field(metadata={
        "min": 0, "min_exclusive": True,
        "doc": "peak of the whole multisine, input units: the largest |setpoint| it sends (each line's amplitude is "
               "this over the waveform's crest factor and sqrt(lines / 2); overview.csv gives it)"})
    lines_per_decade: int = field(default=10, metadata={
        "min": 1, "max": 100, "doc": "excited lines per decade, where the period's grid allows (at least 4 lines "
                                     "apart, so that an odd line left out lies between two)"})
    rate_hz: float | None = field(default=None, metadata={
        "min": 0, "min_exclusive": True, "max": MAX_RATE_HZ,
        "doc": "offline: the sample rate the setpoint is held at and the output sampled, Hz (default "
               f"{OVERVIEW_RATE_PER_STOP} x stop_hz); on a bench it is bench.rate_hz and this key is refused"})
    tolerance_percent: float | None = field(default=None, metadata={
        "min": 0, "min_exclusive": True, "max": 100, "max_exclusive": True,
        "doc": "tolerance of every line, percent (default: analysis.tolerance_percent)"})
    max_periods: int = field(default=200, metadata={
        "min": 2, "doc": "period budget of the whole measurement: a line still open then ends capped or "
                         "noise_limited"})
    seed: int = field(default=0, metadata={"min": 0, "doc": "seed of the lines' random starting phases"})

    def validate(self, where: Callable[[str], str]) -> None:
        """Stop above start; raises :class:`FieldError`."""
        if not self.stop_hz > self.start_hz:
            raise FieldError("stop_hz", f"must be > {where('start_hz')} ({self.start_hz:g} Hz), got {self.stop_hz:g}")

    def rate_at(self, bench_rate_hz: float | None) -> float:
        """The sample rate of the multisine, Hz: the bench's, else ``rate_hz``, else its default."""
        if bench_rate_hz is not None:
            return bench_rate_hz
        return self.rate_hz if self.rate_hz is not None else OVERVIEW_RATE_PER_STOP * self.stop_hz

    def tolerance(self, analysis: AnalysisConfig) -> float:
        """The lines' tolerance, percent: ``tolerance_percent`` or the analysis'."""
        return self.tolerance_percent if self.tolerance_percent is not None else analysis.tolerance_percent

    def multisine(self, rate_hz: float) -> Multisine:
        """The multisine this table describes at ``rate_hz`` (Hz); ValueError where the grid cannot hold it."""
        return design_multisine(rate_hz, self.start_hz, self.stop_hz, self.lines_per_decade, self.amplitude,
                                self.seed)


@dataclass(frozen=True)
class BenchConfig:
    """How the session drives the bench."""

    TABLE_OPTIONAL = True

    transport: str = field(metadata={"choices": TRANSPORTS, "doc": "bus to the drive: can, serial, or canopen "
                                                                   "(a CiA 402 drive on the [can] bus)"})
    rate_hz: float = field(metadata={"min": 0, "min_exclusive": True, "max": MAX_RATE_HZ,
                                     "doc": "setpoint and feedback sample rate of the drive controller, Hz"})
    clock: str = field(default="lockstep", metadata={
        "choices": CLOCKS, "doc": "lockstep: one controller period per setpoint (simulated drives); realtime"})
    timebase: str = field(default="", metadata={
        "choices": TIMEBASES,
        "doc": "sample times from the feedback counter, the SYNC each CANopen TPDO answers (sync: no counter "
               "needed), the controller's timestamp, or the host's receive time; default: sync on transport canopen "
               "with canopen.sync = \"produce\", else counter"})
    output_channels: tuple[str, ...] = field(default=("position",), metadata={
        "non_empty": True, "unique": True, "doc": "feedback channels measured"})
    reference_channel: str = field(default="", metadata={
        "doc": "two-channel mode: gain and phase relative to this channel (e.g. setpoint_echo); "
               "empty: relative to the commanded sine"})
    effort_channel: str = field(default="", metadata={
        "doc": "the plant input after the excitation is added (a drive's torque or current demand), for "
               "analysis.measured = plant, loop, sensitivity, complementary"})
    control_channel: str = field(default="", metadata={
        "doc": "the controller output before the excitation is added, for analysis.measured = loop, sensitivity, "
               "complementary"})
    ramp_in_periods: int = field(default=2, metadata={"min": 0, "doc": "amplitude ramp before analysis, periods"})
    ramp_out_periods: int = field(default=1, metadata={"min": 0, "doc": "amplitude ramp after a point, periods"})
    worker: str = field(default="auto", metadata={
        "choices": ("auto", "thread", "process"),
        "doc": "where pacing and bus I/O run: auto = own process on the realtime clock, beside the terminal UI or "
               "for a long sweep of the in-process drive (bodebench simulate), else a thread"})
    batch_ms: float = field(default=10.0, metadata={"min": 0, "min_exclusive": True,
                                                    "doc": "samples are handed to the analysis this often, ms"})
    reply_timeout_s: float = field(default=0.05, metadata={
        "min": 0, "min_exclusive": True,
        "doc": "lockstep: longest wait for a setpoint's reply (8 typical round trips, at least 2 ms, are waited), s"})
    pacing_cpu: int | None = field(default=None, metadata={
        "min": 0, "doc": "realtime: the CPU the bus worker keeps to itself (e.g. one isolated with isolcpus); "
                         "default: the last CPU the process may use"})

    def default_timebase(self, canopen_sync: str | None) -> str:
        """The time base when [bench] gives none: "sync" on transport canopen where the host produces the SYNC
        (``canopen_sync``: [canopen] sync; a CiA 402 drive has no sample counter), else "counter"."""
        return "sync" if self.transport == "canopen" and canopen_sync == "produce" else "counter"

    def worker_mode(self, beside_a_ui: bool = False, in_process_setpoints: int = 0) -> str:
        """Where the bus worker runs: ``worker`` as given; for "auto" its own process on the realtime clock (its
        pacing keeps clear of this process's garbage collector), beside a terminal UI (whose share of the
        interpreter would delay the lockstep exchange with the drive), or where it steps the simulated drive in
        its own process (``bodebench simulate``) for a sweep of at least :data:`SETPOINTS_FOR_A_PROCESS`
        setpoints (``in_process_setpoints``: as many as the sweep takes at least): the drive and the analysis
        then run on two cores, which repays the second process' start; else a thread."""
        if self.worker != "auto":
            return self.worker
        if self.clock == "realtime" or beside_a_ui or in_process_setpoints >= SETPOINTS_FOR_A_PROCESS:
            return "process"
        return "thread"


SETPOINTS_FOR_A_PROCESS = 20_000
"""Setpoints from which a sweep of the in-process drive runs its worker in a process of its own (about 5 s of
steps: a process takes about a second to start)."""


@dataclass(frozen=True)
class CanConfig:
    """python-can bus: any interface; options are passed to can.Bus as they are."""

    TABLE_OPTIONAL = True

    interface: str = field(default="", metadata={"doc": "python-can interface: socketcan, pcan, kvaser, vector, "
                                                        "slcan, virtual, udp_multicast, ...; empty: python-can's "
                                                        "configuration (CAN_INTERFACE, ~/.canrc)"})
    channel: str = field(default="", metadata={"doc": "interface channel; empty: python-can's configuration, or "
                                                      "with [simulator] the simulator's"})
    bitrate: int | None = field(default=None, metadata={"min": 1, "doc": "bit/s; none: python-can's "
                                                                         "configuration, else the interface's"})
    fd: bool = field(default=False, metadata={"doc": "CAN FD: frames of up to 64 bytes (python-can's fd=True)"})
    context: str = field(default="", metadata={"doc": "section of python-can's configuration file (its "
                                                      "config_context); empty: [default]"})
    options: dict = field(default_factory=dict, metadata={"doc": "further can.Bus keyword arguments"})


@dataclass(frozen=True)
class CanopenConfig:
    """A CANopen device on the [can] bus (a CiA 402 drive or a CiA 408 valve or hydraulic drive): its node, EDS,
    profile and the objects the sweep uses."""

    TABLE_OPTIONAL = True

    node_id: int = field(metadata={"min": 1, "max": 127, "doc": "the device's CANopen node id"})
    eds: str = field(default="", metadata={
        "doc": "the device's EDS or DCF file (relative to the config file); empty with [simulator]: the simulated "
               "device's shipped EDS"})
    profile: str = field(default="402", metadata={
        "choices": tuple(PROFILES), "doc": "the device profile: 402 (drives) or 408 (fluid power: valves, hydraulic "
                                           "drives)"})
    mode: str = field(default="", metadata={
        "choices": ("", *dict.fromkeys(m for p in PROFILES.values() for m in p.modes)),
        "doc": "CiA 402 mode of operation: csp (default), csv, cst (cyclic synchronous position, velocity, torque), "
               "pv, tq (profile velocity, torque); CiA 408 control mode: spool (default, spool position closed "
               "loop), spool_open_loop, pq (pressure/flow: the pressure set point), velocity, position (axis)"})
    setpoint: str = field(default="", metadata={
        "doc": "the object the RPDO carries: index[:subindex] or EDS name; empty: the mode's set point object "
               "(CiA 402 0x607A, 0x60FF or 0x6071; CiA 408 0x6300:1, 0x6380:1, 0x6500:1 or 0x6600:1)"})
    setpoint_scale: float | None = field(default=None, metadata={
        "nonzero": True, "doc": "setpoint units per count of the setpoint object (CiA 402 default 1; CiA 408 "
                                "default: a spool value in % of its reference value 0x6311:1, any other process "
                                "value 10**prefix from its sub-index 3 in the EDS)"})
    actual: dict = field(default_factory=dict, metadata={
        "doc": "channel = object the TPDO carries after the statusword, in order (counter: a sample counter, "
               "timestamp_us: a controller time); empty: the mode's actual value (CiA 402 position = 0x6064; CiA "
               "408 spool = 0x6301:1, velocity = 0x6501:1, position = 0x6601:1)"})
    actual_scale: dict = field(default_factory=dict, metadata={
        "doc": "channel = its units per count (default as setpoint_scale's, for the actual value's object)"})
    rpdo: int = field(default=1, metadata={"min": 1, "max": 4, "doc": "the RPDO that carries the setpoint"})
    tpdo: int = field(default=1, metadata={"min": 1, "max": 4, "doc": "the TPDO that carries the actual values"})
    sync: str = field(default="produce", metadata={
        "choices": ("produce", "consume"),
        "doc": "produce: the host sends SYNC after each setpoint; consume: another node produces it"})
    heartbeat_ms: int = field(default=100, metadata={
        "min": 0, "max": 65535, "doc": "producer heartbeat time written to 0x1017, ms (0: left as the drive has it)"})
    heartbeat_timeout_s: float = field(default=0.5, metadata={
        "min": 0, "min_exclusive": True, "doc": "a drive heartbeat missing this long is a fault, s"})
    state_timeout_s: float = field(default=1.0, metadata={
        "min": 0, "min_exclusive": True, "doc": "longest wait for an SDO answer or a state change, s"})
    fault_reset: bool = field(default=False, metadata={
        "doc": "a drive found in fault is reset (controlword bit 7) instead of refused"})
    host_node_id: int = field(default=127, metadata={
        "min": 1, "max": 127, "doc": "the host's own node id on the bus, for its heartbeat (COB-ID 0x700 + it); not "
                                     "node_id nor any other node's"})
    host_heartbeat_ms: int = field(default=100, metadata={
        "min": 0, "max": 65535, "doc": "the host's heartbeat period, ms, from enable to the end of the session (0: "
                                       "none, and the drive cannot tell that the host died)"})
    drive_heartbeat_timeout_ms: int | None = field(default=None, metadata={
        "min": 1, "max": 65535, "doc": "consumer heartbeat time written to the drive's 0x1016 for the host's node, "
                                       "ms: the drive stops itself when the host's heartbeat is missing this long; "
                                       "longer than host_heartbeat_ms (default: 20 x host_heartbeat_ms)"})
    abort_connection: str = field(default="quick stop", metadata={
        "choices": tuple(ABORT_CONNECTION_OPTIONS),
        "doc": "what the drive does when the host's heartbeat is lost, written to its 0x6007 (abort connection "
               "option code): quick stop (3), disable voltage (2) or fault (1)"})

    @property
    def consumer_ms(self) -> int:
        """The consumer heartbeat time for the drive's 0x1016, ms (``drive_heartbeat_timeout_ms`` or its default)."""
        if self.drive_heartbeat_timeout_ms is not None:
            return self.drive_heartbeat_timeout_ms
        return min(65535, 20 * self.host_heartbeat_ms)

    @property
    def mode_name(self) -> str:
        """The mode the sweep runs in: ``mode`` or the profile's default."""
        return self.mode or PROFILES[self.profile].default_mode

    def validate(self, where: Callable[[str], str]) -> None:
        """The mode, the scales, the heartbeats and the host's node id; raises :class:`FieldError`."""
        profile = PROFILES[self.profile]
        if self.mode_name not in profile.modes:
            raise FieldError("mode", f'"{self.mode}" is not a {profile.name} mode (with {where("profile")} = '
                                     f'"{self.profile}": {", ".join(profile.modes)})')
        for table, name in ((self.actual, "actual"), (self.actual_scale, "actual_scale")):
            for channel, value in table.items():
                ok = isinstance(value, str) and value.strip() if name == "actual" else (
                    isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
                    and value != 0)
                if not ok:
                    expected = "an object: index[:subindex] or EDS name" if name == "actual" else \
                        "a finite non-zero number"
                    raise FieldError(name, f"{channel}: expected {expected}, got {value!r}")
        for channel in self.actual_scale:
            if channel not in (self.actual or PROFILES[self.profile].actuals[self.mode_name]):
                raise FieldError("actual_scale", f"{channel}: not a channel of canopen.actual")
        if self.heartbeat_ms and self.heartbeat_timeout_s <= self.heartbeat_ms / 1000:
            raise FieldError("heartbeat_timeout_s", f"must be longer than the heartbeat period "
                                                    f"({where('heartbeat_ms')} = {self.heartbeat_ms} ms)")
        if self.host_node_id == self.node_id:
            raise FieldError("host_node_id", f"{self.host_node_id} is the drive's own node id ({where('node_id')}): "
                                             "the host needs one of its own")
        if self.host_heartbeat_ms and self.consumer_ms <= self.host_heartbeat_ms:
            raise FieldError("drive_heartbeat_timeout_ms",
                             f"{self.consumer_ms} ms must be longer than the host's heartbeat period "
                             f"({where('host_heartbeat_ms')} = {self.host_heartbeat_ms} ms), or the drive stops on "
                             "a heartbeat that is merely on time")


@dataclass(frozen=True)
class SerialConfig:
    """Serial line (pyserial)."""

    TABLE_OPTIONAL = True

    port: str = field(default="", metadata={"doc": "tty path or pyserial URL; empty with [simulator]: the "
                                                   "simulator's pseudo-terminal"})
    baudrate: int = field(default=1_000_000, metadata={"min": 1, "doc": "bit/s"})
    framing: str = field(default="binary", metadata={"choices": ("binary", "ascii"),
                                                     "doc": "binary (sync, length, CRC-16) or ASCII lines"})


@dataclass(frozen=True)
class SafetyConfig:
    """Limits that protect the drive; any trip drives the setpoint to zero and disables the drive."""

    TABLE_OPTIONAL = True

    max_amplitude: float = field(metadata={"min": 0, "min_exclusive": True,
                                           "doc": "largest |setpoint| ever sent, setpoint units"})
    max_rate: float | None = field(default=None, metadata={"min": 0, "min_exclusive": True,
                                                           "doc": "setpoint slew limit, setpoint units/s"})
    feedback_limits: dict = field(default_factory=dict, metadata={
        "doc": "channel = [low, high]: a feedback sample outside aborts the sweep"})
    watchdog_s: float = field(default=0.5, metadata={"min": 0, "min_exclusive": True,
                                                     "doc": "no feedback for this long aborts, s"})

    def validate(self, where: Callable[[str], str]) -> None:
        """The feedback windows; raises :class:`FieldError`."""
        for channel, window in self.feedback_limits.items():
            ok = (isinstance(window, list) and len(window) == 2
                  and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                          for v in window) and window[0] < window[1])
            if not ok:
                raise FieldError("feedback_limits", f"{channel}: expected [low, high] with low < high, "
                                                    f"got {window!r}")


@dataclass(frozen=True)
class SimulatorConfig:
    """The simulated servo controller around [plant], standing in for the drive."""

    TABLE_OPTIONAL = True

    jitter: float = field(default=0.0, metadata={"min": 0, "max": 0.5, "max_exclusive": True,
                                                 "doc": "sampling-instant jitter, fraction of a period"})
    noise: float = field(default=0.0, metadata={"min": 0, "doc": "standard deviation of white noise added to "
                                                                 "every feedback channel, the channel's units"})
    quantization: float = field(default=0.0, metadata={"min": 0, "doc": "least significant bit of every feedback "
                                                                        "channel, the channel's units (0: none)"})
    seed: int = field(default=0, metadata={"min": 0, "doc": "random seed of the jitter and the noise"})
    hum: float = field(default=0.0, metadata={"min": 0, "doc": "amplitude of a sine added to every feedback "
                                                               "channel (mains pick-up), the channel's units"})
    hum_hz: float = field(default=50.0, metadata={"min": 0, "min_exclusive": True,
                                                  "doc": "frequency of the hum, Hz"})
    faults: FaultConfig = field(default_factory=FaultConfig, metadata={
        "doc": "fault injection on the wire and in the drive (docs/faults.md)"})
    canopen: CanopenFaults = field(default_factory=CanopenFaults, metadata={
        "doc": "faults of the simulated CiA 402 drive (transport canopen)"})
    loop: LoopConfig = field(default_factory=LoopConfig, metadata={
        "doc": "the simulated drive's own control loop around [plant] (docs/loop.md)"})


@dataclass(frozen=True)
class ResultsConfig:
    """How response.csv is written: its delimiter and decimal mark, for spreadsheets of comma-decimal locales."""

    TABLE_OPTIONAL = True

    delimiter: str = field(default=",", metadata={
        "choices": (",", ";", "tab"), "doc": 'column delimiter of response.csv: ",", ";" or "tab"'})
    decimal: str = field(default=".", metadata={
        "choices": (".", ","), "doc": 'decimal mark of the numbers in response.csv: "." or "," (not with the '
                                      'comma delimiter)'})

    def validate(self, where: Callable[[str], str]) -> None:
        """A decimal comma needs another delimiter; raises :class:`FieldError`."""
        if self.decimal == "," and self.delimiter == ",":
            raise FieldError("decimal", f'"," needs {where("delimiter")} = ";" or "tab" (the comma separates '
                                        "the columns)")
