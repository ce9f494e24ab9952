"""The configuration of an experiment: one TOML file, validated on load into one typed object per case.

A file holds the tables of :mod:`bodebench.io.tables` (validated by :mod:`bodebench.io.schema`) and optionally
``[cases.NAME]`` tables that override them per case. :func:`load_config` returns an :class:`ExperimentConfig`
whose cases are :class:`CaseConfig` objects: typed tables, the file they came from, and for a bench case the
frame layout, built once. Every error is a :class:`ConfigError` whose text is one line:
``<source>: <dotted key>: <problem>``.
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bodebench.core.benchgrid import disturbance_lines, folding_notes, move_off_disturbances, move_off_folds
from bodebench.core.measured import MEASURED, RATIO_MODES, Formed, FormError, formed_columns
from bodebench.core.multisine import Multisine, MultisineError
from bodebench.drivers import cia408
from bodebench.drivers.canopen_link import CanopenSetup, ObjectRef, load_od, resolve_object
from bodebench.drivers.cia402 import ABORT_CONNECTION_OPTIONS
from bodebench.drivers.codec import COUNTER, SETPOINT, SETPOINT_ECHO, TIMESTAMP
from bodebench.drivers.device_profile import PROFILES
from bodebench.drivers.errors import LayoutError
from bodebench.drivers.extras import missing, require
from bodebench.drivers.layout import Layout, default_layout
from bodebench.drivers.ports import INTERFACE_NEEDS
from bodebench.io.document import Override, OverrideError, apply_overrides, names_override
from bodebench.io.schema import (
    ConfigError,
    FieldError,
    _build,
    _convert,
    _convert_scalar,
    _describe,
    _error,
    _expect_table,
    _Fault,
    _key_path,
    _schema,
    _to_raw,
    build_table,
)
from bodebench.io.tables import (
    DEFAULT_DISTURBANCE_HZ,
    MAX_FREQUENCY_HZ,
    MIN_FREQUENCY_HZ,
    MIN_SAMPLES_PER_PERIOD,
    AnalysisConfig,
    BenchConfig,
    CanConfig,
    CanopenConfig,
    ExcitationConfig,
    OverviewConfig,
    PlantConfig,
    ResultsConfig,
    SafetyConfig,
    SerialConfig,
    SimulatorConfig,
)

__all__ = [
    "AnalysisConfig",
    "BenchConfig",
    "CanConfig",
    "CanopenConfig",
    "CaseConfig",
    "ConfigError",
    "ExcitationConfig",
    "ExperimentConfig",
    "FieldError",
    "OverviewConfig",
    "PlantConfig",
    "SafetyConfig",
    "SerialConfig",
    "SimulatorConfig",
    "TABLES",
    "build_table",
    "disturbance_lines_of",
    "load_config",
    "parse_config",
    "read_document",
]

CASE_NAME_PATTERN = re.compile(r"[A-Za-z0-9_.-]+")
"""Allowed case names (they become directory names); "." and ".." are refused as well."""

TABLES: dict[str, type] = {
    "plant": PlantConfig,
    "excitation": ExcitationConfig,
    "analysis": AnalysisConfig,
    "overview": OverviewConfig,
    "bench": BenchConfig,
    "can": CanConfig,
    "canopen": CanopenConfig,
    "serial": SerialConfig,
    "safety": SafetyConfig,
    "simulator": SimulatorConfig,
    "results": ResultsConfig,
}
"""The schema tables, by TOML name. Each may also appear inside ``[cases.NAME]``."""

FRAMES = "frames"
"""The [frames] table: checked by :meth:`bodebench.drivers.Layout.from_mapping`, its only validator."""

_BENCH_ONLY = ("can", "canopen", "serial", FRAMES, "safety", "simulator")
SIMULATED_DRIVE_EDS = Path(__file__).resolve().parent.parent / "data" / "cia402_sim.eds"
"""The EDS of the simulated CiA 402 drive (package data), the default ``canopen.eds`` of a simulated bench."""
SIMULATED_EDS: dict[str, Path] = {"402": SIMULATED_DRIVE_EDS,
                                  "408": SIMULATED_DRIVE_EDS.with_name("cia408_sim.eds")}
"""The EDS of each profile's simulated device (package data), by ``canopen.profile``."""
_TOP_LEVEL_KEYS = ("title", "cases")


@dataclass(frozen=True)
class BenchTables:
    """The tables every bench case has (the loader makes sure of it)."""

    bench: BenchConfig
    safety: SafetyConfig
    layout: Layout


@dataclass(frozen=True)
class CaseConfig:
    """One validated case: base tables merged with the case's overrides.

    ``source``: the configuration file (relative paths in it, such as a DBC file, are taken from its directory).
    ``plant``: the simulated plant (None for a real drive: nothing is simulated, and the saved copy has no [plant]).
    ``raw``: the merged, validated configuration as a JSON-serialisable dict (defaults filled in; plant keys the
    model does not use left out), as saved with the results. ``layout``: the frame layout of a bench case (None
    offline); on transport canopen the layout of its PDOs, and ``canopen_setup`` the [canopen] table resolved
    against the device's EDS.
    """

    name: str
    source: Path
    plant: PlantConfig | None
    excitation: ExcitationConfig
    analysis: AnalysisConfig
    raw: dict[str, Any] = field(hash=False, repr=False)
    bench: BenchConfig | None = None
    can: CanConfig | None = None
    serial: SerialConfig | None = None
    safety: SafetyConfig | None = None
    simulator: SimulatorConfig | None = None
    results: ResultsConfig | None = None
    layout: Layout | None = field(default=None, compare=False, repr=False)
    canopen: CanopenConfig | None = None
    canopen_setup: CanopenSetup | None = field(default=None, compare=False, repr=False)
    overview: OverviewConfig | None = None
    plan_notes: tuple[str, ...] = field(default=(), compare=False)
    """What the loader changed in the frequency plan and why (a frequency moved off a disturbance line), and what it
    warns of (a harmonic that the bench's sample rate folds onto a measured one)."""

    @property
    def disturbance_lines(self) -> tuple[float, ...]:
        """The disturbance lines (Hz) a bench point is judged against: [analysis] disturbance_hz with harmonics,
        by default mains at 50 Hz on a real drive and none on the simulated one (it has no mains); () offline."""
        return disturbance_lines_of(self.raw, self.analysis)

    def formed(self, reference_channel: str | None = None) -> Formed:
        """The columns a bench case analyses, formed from the drive's channels by ``analysis.measured``, with the
        divisor ``reference_channel`` in output mode (None: ``bench.reference_channel``); ValueError offline."""
        bench = self.on_bench.bench
        reference = bench.reference_channel if reference_channel is None else reference_channel
        return formed_columns(self.analysis.measurement, bench.output_channels, reference, bench.effort_channel,
                              bench.control_channel)

    def placed(self, frequencies_hz: Sequence[float]) -> tuple[float, ...]:
        """Frequencies (Hz) added to a bench case's plan, moved as the loader moves the planned ones (off the
        disturbance lines, off folding sample counts, as [analysis] says); offline, as they are."""
        if self.bench is None:
            return tuple(frequencies_hz)
        moved, _ = _off_disturbances(frequencies_hz, self.analysis, self.raw)
        return _off_folds(moved, self.bench.rate_hz, self.analysis, self.raw)[0]

    @property
    def analysed_channels(self) -> tuple[str, ...]:
        """The channel names of a bench case's points: the output channels, or what its mode forms ("loop",
        ...); ValueError offline."""
        return self.formed().outputs

    @property
    def overview_rate_hz(self) -> float:
        """The sample rate of the overview's multisine, Hz (bench.rate_hz on a bench); ValueError without
        [overview]."""
        if self.overview is None:
            raise ValueError(f"case {self.name!r} of {self.source} has no [overview] table")
        return self.overview.rate_at(self.bench.rate_hz if self.bench is not None else None)

    def multisine(self) -> Multisine:
        """The overview's multisine (the loader has checked that the grid holds it); ValueError without
        [overview]."""
        rate = self.overview_rate_hz
        assert self.overview is not None  # overview_rate_hz raised without it
        return self.overview.multisine(rate)

    @property
    def on_bench(self) -> BenchTables:
        """The bench, safety and frame layout of a bench case; ValueError for an offline case."""
        if self.bench is None or self.safety is None or self.layout is None:
            raise ValueError(f"case {self.name!r} of {self.source} has no [bench] table")
        return BenchTables(self.bench, self.safety, self.layout)


@dataclass(frozen=True)
class ExperimentConfig:
    """A loaded configuration file. ``has_cases`` is False when the file had no ``[cases]`` table (then there is
    one case, named after the file stem)."""

    path: Path
    title: str
    cases: tuple[CaseConfig, ...]
    has_cases: bool

    @property
    def on_bench(self) -> bool:
        """Whether the cases run on a bench (a [bench] table) rather than offline."""
        return self.cases[0].bench is not None


def _default_case_name(source: str) -> str:
    stem = Path(source).stem
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", stem).strip("_.")
    return name or "config"


def _build_case(
    name: str,
    base: Mapping[str, Mapping[str, Any]],
    overrides: Mapping[str, Mapping[str, Any]],
    case_parts: tuple[str, ...],
    source: str,
) -> CaseConfig:
    """Merge ``overrides`` (the case's sub-tables, from ``case_parts``) over ``base`` and validate the result."""
    built: dict[str, Any] = {}
    raw: dict[str, Any] = {}
    for table, cls in TABLES.items():
        base_keys = base.get(table, {})
        case_keys = overrides.get(table, {})
        if table not in base and table not in overrides and getattr(cls, "TABLE_OPTIONAL", False):
            built[table] = None
            continue
        merged = {**base_keys, **case_keys}

        def origin(key: str, table: str = table, case_keys: Mapping[str, Any] = case_keys) -> str:
            if key in case_keys:
                return _key_path(*case_parts, table, key)
            return _key_path(table, key)

        def missing(key: str, table: str = table) -> str:
            return _key_path(*case_parts, table, key)

        def default_key(key: str, table: str = table) -> str:
            return _key_path(table, key)

        obj: object = _build(cls, merged, origin, missing, default_key)
        built[table] = obj
        raw[table] = _to_raw(obj)
    frames: dict[str, Any] | None = None
    if FRAMES in base or FRAMES in overrides:
        frames = {**base.get(FRAMES, {}), **overrides.get(FRAMES, {})}
        raw[FRAMES] = frames

    def key(table: str, name: str) -> str:
        return _key_path(*case_parts, table, name) if name in overrides.get(table, {}) else _key_path(table, name)

    if built["bench"] is not None and built["bench"].transport in ("can", "canopen") and built["can"] is not None:
        built["can"] = _resolve_can(built["can"], built["simulator"] is not None, key)
        raw["can"] = _to_raw(built["can"])
    bench = built["bench"]
    if bench is not None and not bench.timebase:
        canopen = built["canopen"]
        built["bench"] = replace(bench, timebase=bench.default_timebase(canopen.sync if canopen is not None else None))
        raw["bench"] = _to_raw(built["bench"])
    if built["plant"] is None and (built["bench"] is None or built["simulator"] is not None):
        what = "an offline experiment" if built["bench"] is None else "a simulated drive ([simulator])"
        raise _Fault(_key_path("plant"), f"missing: {what} needs a [plant] table (only a real drive needs none)")
    _check_frequencies(built["excitation"], key)
    analysis = built["analysis"]
    if built["bench"] is None and max(analysis.harmonics) * MIN_SAMPLES_PER_PERIOD > analysis.steps_per_period:
        raise _Fault(key("analysis", "harmonics"),
                     f"harmonic {max(analysis.harmonics)} needs at least {MIN_SAMPLES_PER_PERIOD} steps a period of "
                     f"its own: analysis.steps_per_period = {analysis.steps_per_period} allows harmonics up to "
                     f"{analysis.steps_per_period // MIN_SAMPLES_PER_PERIOD}")
    notes: tuple[str, ...] = ()
    if built["bench"] is not None:
        frequencies, notes = _off_disturbances(built["excitation"].frequencies_hz, built["analysis"], raw)
        built["excitation"] = built["excitation"].with_frequencies(frequencies)
    layout, setup = _check_bench(built, frames, key, source)
    if built["simulator"] is not None and layout is not None:
        _check_simulated_outputs(built["plant"], built["simulator"], layout, built["bench"].transport, key)
    if built["overview"] is not None:
        _check_overview(built["overview"], built["bench"], built["safety"], key)
    adaptive = built["excitation"].adaptive
    if adaptive is not None and adaptive.from_overview:
        if built["overview"] is None:
            raise _Fault(f"{key('excitation', 'frequencies')}.adaptive.from_overview",
                         "needs an [overview] table (start_hz, stop_hz, amplitude): the multisine run first")
        if built["analysis"].measurement != "output":
            raise _Fault(f"{key('excitation', 'frequencies')}.adaptive.from_overview",
                         f'the overview measures the output against the setpoint, not analysis.measured = '
                         f'"{built["analysis"].measurement}"')
    if built["bench"] is not None:
        # after the checks, which name the frequencies as given: a move lowers one by a fraction of a percent
        frequencies, moves = _off_folds(built["excitation"].frequencies_hz, built["bench"].rate_hz,
                                        built["analysis"], raw)
        built["excitation"] = built["excitation"].with_frequencies(frequencies)
        notes += moves
    if built["bench"] is not None:
        if built["analysis"].fold_policy != "bound":  # bound: each interval carries it
            notes += folding_notes(built["bench"].rate_hz, built["excitation"].frequencies_hz,
                                   built["analysis"].harmonics)
        assert layout is not None
        notes += _check_setpoint_resolution(layout, built["excitation"], key)
    return CaseConfig(
        name=name,
        source=Path(source),
        plant=built["plant"],
        excitation=built["excitation"],
        analysis=built["analysis"],
        raw=raw,
        bench=built["bench"],
        can=built["can"],
        serial=built["serial"],
        safety=built["safety"],
        simulator=built["simulator"],
        results=built["results"],
        layout=layout,
        canopen=built["canopen"],
        canopen_setup=setup,
        overview=built["overview"],
        plan_notes=notes,
    )


def _check_overview(overview: OverviewConfig, bench: BenchConfig | None, safety: SafetyConfig | None,
                    key: Callable[[str, str], str]) -> None:
    """[overview] against the sample rate and, on a bench, the safety limits: the whole multisine's peak and the
    steepest step of its held samples; raises :class:`_Fault` naming the key."""
    if bench is not None and overview.rate_hz is not None:
        raise _Fault(key("overview", "rate_hz"), f"not on a bench: the multisine is sent at bench.rate_hz "
                                                 f"({bench.rate_hz:g} Hz)")
    rate = overview.rate_at(bench.rate_hz if bench is not None else None)
    rate_key = "bench.rate_hz" if bench is not None else "overview.rate_hz"
    if overview.stop_hz * MIN_SAMPLES_PER_PERIOD > rate:
        raise _Fault(key("overview", "stop_hz"), f"{overview.stop_hz:g} Hz needs at least {MIN_SAMPLES_PER_PERIOD} "
                                                 f"samples a period at {rate_key} = {rate:g} (at most "
                                                 f"{rate / MIN_SAMPLES_PER_PERIOD:g} Hz)")
    try:
        design = overview.multisine(rate)
    except MultisineError as exc:
        raise _Fault(key("overview", exc.key), str(exc)) from None
    if safety is None:
        return
    if overview.amplitude > safety.max_amplitude:
        raise _Fault(key("overview", "amplitude"), f"the multisine's peak {overview.amplitude:g} exceeds "
                                                   f"safety.max_amplitude ({safety.max_amplitude:g})")
    if safety.max_rate is not None and design.peak_slew > safety.max_rate:
        raise _Fault(key("overview", "amplitude"),
                     f"{overview.amplitude:g}: the multisine's steepest step is {design.peak_slew:g} a second, above "
                     f"safety.max_rate ({safety.max_rate:g}); lower it or overview.stop_hz")


MIN_SETPOINT_COUNTS = 4.0
"""Fewest steps of the setpoint's frame an amplitude may span: fewer, and the drive is sent a staircase, not a sine."""
FINE_SETPOINT_COUNTS = 100.0
"""Below this many steps an amplitude is warned of: the wire's rounding adds harmonics of about one step."""


def _check_setpoint_resolution(layout: Layout, excitation: ExcitationConfig, key: Callable[[str, str], str]
                               ) -> tuple[str, ...]:
    """The smallest amplitude of the plan against the step of the setpoint as its frame carries it (an integer
    signal's scale, a CANopen object's setpoint_scale): refused below ``MIN_SETPOINT_COUNTS`` steps, warned below
    ``FINE_SETPOINT_COUNTS``; raises :class:`_Fault`, returns the warning lines."""
    amplitude, f = min((excitation.amplitude_at(f), f) for f in excitation.frequencies_hz)
    rule = next((name for name in ("amplitudes", "amplitude_profile") if getattr(excitation, name) is not None),
                "amplitude")
    message = layout.setpoint
    try:
        levels = np.unique([message.decode(message.encode({SETPOINT: float(v), COUNTER: 0}))[SETPOINT]
                            for v in amplitude * np.sin(np.linspace(0.0, np.pi / 2, 257))])
    except LayoutError as exc:
        raise _Fault(key("excitation", rule), f"{amplitude:g}: the setpoint's frame cannot carry it: {exc}") from None
    step = float(np.min(np.diff(levels))) if levels.size > 1 else math.inf
    counts = amplitude / step
    if counts < MIN_SETPOINT_COUNTS:
        raise _Fault(key("excitation", rule),
                     f"{amplitude:g} at {f:g} Hz is {counts:.3g} steps of the setpoint's frame ({step:g} each): the "
                     "drive would be sent a staircase, not a sine; raise the amplitude or the setpoint's resolution "
                     "(its scale)")
    if counts < FINE_SETPOINT_COUNTS:
        return (f"{f:g} Hz: the amplitude {amplitude:g} is {counts:.3g} steps of the setpoint's frame ({step:g} "
                f"each): its rounding adds harmonics of about {100 / counts:.2g} % of the amplitude",)
    return ()


def _check_frequencies(excitation: ExcitationConfig, key: Callable[[str, str], str]) -> None:
    """Every frequency of the plan within what any drive is swept at; raises :class:`_Fault` naming the key."""
    for i, f in enumerate(excitation.frequencies_hz):
        at = (f"{key('excitation', 'frequencies_hz')}[{i}]" if excitation.frequencies is None
              else f"{key('excitation', 'frequencies')} (frequency {i})")
        if f < MIN_FREQUENCY_HZ:
            raise _Fault(at, f"{f:g} Hz is below {MIN_FREQUENCY_HZ:g} Hz (a period of 1000 s): a point would "
                             "take hours")
        if f > MAX_FREQUENCY_HZ:
            raise _Fault(at, f"{f:g} Hz is above {MAX_FREQUENCY_HZ:g} Hz, far beyond any servo drive's loop")


def measured_of(config: Mapping[str, Any]) -> str:
    """What a case measured (``analysis.measured``, :data:`bodebench.core.measured.MEASURED`), from its validated
    configuration (``CaseConfig.raw``, a sidecar's ``config``)."""
    analysis = config.get("analysis")
    measured = analysis.get("measured") if isinstance(analysis, Mapping) else None
    return measured if isinstance(measured, str) and measured in MEASURED else MEASURED[0]


def _off_disturbances(frequencies_hz: Sequence[float], analysis: AnalysisConfig, raw: Mapping[str, Any]
                      ) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """A bench plan's frequencies (Hz) moved off the disturbance lines where ``analysis.disturbance_policy`` says
    "move", with a note per move."""
    if analysis.disturbance_policy != "move":
        return tuple(frequencies_hz), ()
    return move_off_disturbances(frequencies_hz, analysis.harmonics, disturbance_lines_of(raw, analysis))


def _off_folds(frequencies_hz: Sequence[float], rate_hz: float, analysis: AnalysisConfig, raw: Mapping[str, Any]
               ) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """A bench plan's frequencies (Hz) moved where ``analysis.fold_policy`` says "move" so that the folds of their
    harmonics turn (and kept off the disturbance lines when those move too), with one note for the moves."""
    if analysis.fold_policy != "move":
        return tuple(frequencies_hz), ()
    lines = disturbance_lines_of(raw, analysis) if analysis.disturbance_policy == "move" else ()
    return move_off_folds(rate_hz, frequencies_hz, analysis.harmonics, lines)


def disturbance_lines_of(config: Mapping[str, Any], analysis: AnalysisConfig) -> tuple[float, ...]:
    """The disturbance lines (Hz) of a case, from its validated configuration (``CaseConfig.raw``, a sidecar's
    ``config``) and [analysis] table: disturbance_hz with their harmonics; when not given, mains
    (DEFAULT_DISTURBANCE_HZ) on a real drive, the simulated drive's own hum where it has one ([simulator] hum), and
    none offline."""
    if not isinstance(config.get("bench"), Mapping):
        return ()
    listed = analysis.disturbance_hz
    if listed is None:
        simulator = config.get("simulator")
        if not isinstance(simulator, Mapping):
            listed = DEFAULT_DISTURBANCE_HZ
        else:
            hum, hum_hz = simulator.get("hum", 0.0), simulator.get("hum_hz", 50.0)
            listed = (float(hum_hz),) if isinstance(hum, (int, float)) and hum > 0 else ()
    return disturbance_lines(listed)


def _parse(data: Mapping[str, Any], source: str) -> ExperimentConfig:
    if not isinstance(data, Mapping):
        raise _Fault("(top level)", f"expected a table, got {_describe(data)}")
    for key in data:
        if key not in _TOP_LEVEL_KEYS and key not in TABLES and key != FRAMES:
            raise _Fault(_key_path(key), "unknown key")

    title = Path(source).stem
    if "title" in data:
        title = _convert_scalar(str, data["title"], {}, "title")

    base: dict[str, Mapping[str, Any]] = {}
    for table in (*TABLES, FRAMES):
        if table in data:
            base[table] = _expect_table(data[table], table)

    if "cases" not in data:
        case = _build_case(_default_case_name(source), base, {}, (), source)
        return ExperimentConfig(path=Path(source), title=title, cases=(case,), has_cases=False)

    cases = _expect_table(data["cases"], "cases")
    if not cases:
        raise _Fault("cases", "must contain at least one case")
    folded: dict[str, str] = {}
    overrides: dict[str, dict[str, Mapping[str, Any]]] = {}
    for name, body in cases.items():
        label = _key_path("cases", name)
        if not isinstance(name, str) or not CASE_NAME_PATTERN.fullmatch(name) or name in (".", ".."):
            raise _Fault(label, 'case name must match [A-Za-z0-9_.-]+ and not be "." or ".."')
        if name.lower() in folded:
            raise _Fault(label, f"same directory name as {_key_path('cases', folded[name.lower()])} "
                                "on case-insensitive file systems")
        folded[name.lower()] = name
        body = _expect_table(body, "cases", name)
        for key in body:
            if key not in TABLES and key != FRAMES:
                raise _Fault(_key_path("cases", name, key), "unknown key")
        overrides[name] = {table: _expect_table(sub, "cases", name, table) for table, sub in body.items()}

    # Every value in the base tables is checked even if each case overrides it.
    for table, keys in base.items():
        if table == FRAMES:
            continue
        by_name = {s.name: s for s in _schema(TABLES[table])}
        for key, value in keys.items():
            if key not in by_name:
                raise _Fault(_key_path(table, key), "unknown key")
            _convert(by_name[key], value, _key_path(table, key))

    built = tuple(_build_case(name, base, overrides[name], ("cases", name), source) for name in cases)
    return ExperimentConfig(path=Path(source), title=title, cases=built, has_cases=True)


def _resolve_can(table: CanConfig, simulated: bool, key: Callable[[str, str], str]) -> CanConfig:
    """``[can]`` with the interface, channel and bitrate it leaves empty taken from python-can's own configuration
    (``can.util.load_config``: the environment's CAN_INTERFACE, CAN_CHANNEL, CAN_BITRATE, CAN_CONFIG, then
    ~/.canrc and the other files it reads), as ``can.Bus()`` resolves them; a simulated drive keeps its own channel.
    Raises :class:`_Fault`."""
    if table.interface and (table.channel or simulated) and table.bitrate is not None:
        return table
    from bodebench.drivers.ports import resolve_can_config

    try:
        resolved = resolve_can_config(table.interface, table.channel, table.bitrate, table.context)
    except ValueError as exc:
        raise _Fault(key("can", "interface"), str(exc)) from None
    interface = resolved.get("interface") or ""
    channel = table.channel or ("" if simulated else str(resolved.get("channel") or ""))
    bitrate = table.bitrate if table.bitrate is not None else resolved.get("bitrate")
    if bitrate is not None and (isinstance(bitrate, bool) or not isinstance(bitrate, int) or bitrate < 1):
        raise _Fault(key("can", "bitrate"), f"python-can's configuration gives bitrate {bitrate!r}: not a bit rate")
    fd = table.fd or bool(resolved.get("fd", False))
    return replace(table, interface=interface, channel=channel, bitrate=bitrate, fd=fd)


def _check_simulated_outputs(plant: PlantConfig, simulator: SimulatorConfig, layout: Layout, transport: str,
                             key: Callable[[str, str], str]) -> None:
    """The simulated drive's loop regulates an output of the plant, and on CAN frames or a serial line it can send
    every feedback channel of the layout (a simulated CANopen device maps its objects to the plant itself); raises
    :class:`_Fault`."""
    from dataclasses import asdict

    from bodebench.sim.loop_config import CONTROL, EFFORT
    from bodebench.sim.models import plant_from_table

    outputs = plant_from_table(asdict(plant)).output_names
    loop = simulator.loop
    if loop.inject and loop.feedback and loop.feedback not in outputs:
        raise _Fault(f"{key('simulator', 'loop')}.feedback",
                     f"{loop.feedback!r} is not an output of the {plant.model} plant ({', '.join(outputs)})")
    sent = (*outputs, *((EFFORT, CONTROL) if loop.inject else ()), SETPOINT_ECHO)
    for name in layout.channels if transport != "canopen" else ():
        if name not in sent:
            message = next(m for m in layout.feedback if name in m.signal_names)
            raise _Fault(_key_path("simulator"),
                         f"feedback channel {name!r} ({message.name}, id 0x{message.id:X}) is not sent by the "
                         f"simulated drive: it sends the {plant.model} plant's {', '.join(outputs)}"
                         + (f", the loop's {EFFORT} and {CONTROL}" if loop.inject else "")
                         + f" and {SETPOINT_ECHO}")


def _check_bench(tables: Mapping[str, Any], frames: Mapping[str, Any] | None, key: Callable[[str, str], str],
                 source: str) -> tuple[Layout | None, CanopenSetup | None]:
    """Cross-table checks of a bench case; the frame layout it uses (None offline) and, on transport canopen, the
    resolved [canopen] table. Raises :class:`_Fault`."""
    bench: BenchConfig | None = tables.get("bench")
    if bench is None:
        for name in _BENCH_ONLY:
            if tables.get(name) is not None or (name == FRAMES and frames is not None):
                raise _Fault(name, "needs a [bench] table")
        if tables["analysis"].measurement != "output":
            raise _Fault(key("analysis", "measured"), f'"{tables["analysis"].measurement}" needs a [bench] table (a '
                                                      "drive's effort and control channels)")
        return None, None
    link = tables.get(bench.transport)
    if link is None:
        raise _Fault(key("bench", "transport"), f'"{bench.transport}" needs a [{bench.transport}] table')
    setup: CanopenSetup | None = None
    if bench.transport == "canopen":
        link = tables.get("can")
        if link is None:
            raise _Fault(key("bench", "transport"), '"canopen" needs a [can] table (the bus the drive is on)')
        if frames is not None:
            raise _Fault(FRAMES, "not used on transport canopen: the PDOs come from [canopen]")
        setup = replace(_canopen_setup(tables["canopen"], tables.get("simulator") is not None, key, source),
                        timebase=bench.timebase,
                        sync_period_s=1.0 / bench.rate_hz if bench.clock == "realtime" else 0.0)
    elif tables.get("canopen") is not None:
        raise _Fault("canopen", f'only used with bench.transport = "canopen" (not "{bench.transport}")')
    simulated = tables.get("simulator") is not None
    _check_machine(link, bench, key, source)
    if isinstance(link, CanConfig) and not link.channel and not simulated:
        raise _Fault(key("can", "channel"), "missing: not in the file, nor in python-can's configuration "
                                            "(CAN_CHANNEL, ~/.canrc); only a [simulator] provides its own")
    if isinstance(link, SerialConfig) and not link.port and not simulated:
        raise _Fault(key("serial", "port"), "missing (only a [simulator] provides its own)")
    if bench.timebase == "sync" and (setup is None or setup.sync != "produce"):
        raise _Fault(key("bench", "timebase"), 'sync: only on transport "canopen" with canopen.sync = "produce" '
                                               "(samples are dated by the host's own SYNCs)")
    if bench.clock == "lockstep" and bench.timebase == "receive":
        raise _Fault(key("bench", "timebase"), "receive times mean nothing on the lockstep clock")
    safety: SafetyConfig | None = tables.get("safety")
    if safety is None:
        raise _Fault("safety", "a bench config needs a [safety] table (at least max_amplitude)")
    _check_plan(tables, bench, safety, key)
    layout = _bench_layout(tables, bench, frames, setup, key, source)
    _check_channels(tables, bench, safety, layout, setup, key)
    return layout, setup


def _check_machine(link: Any, bench: BenchConfig, key: Callable[[str, str], str], source: str) -> None:
    """What a bench case asks of this machine rather than of the file: the package python-can's interface needs,
    and the CPU the pacing loop is pinned to. Raises :class:`_Fault` (a missing package: MissingDependency)."""
    if isinstance(link, CanConfig) and link.interface in INTERFACE_NEEDS:
        try:
            require(INTERFACE_NEEDS[link.interface], "")
        except ImportError:
            raise missing(INTERFACE_NEEDS[link.interface],
                          f'{source}: can.interface = "{link.interface}" (python-can\'s {link.interface})') from None
    cpus = os.cpu_count() or 1
    if bench.clock == "realtime" and bench.pacing_cpu is not None and bench.pacing_cpu >= cpus:
        raise _Fault(key("bench", "pacing_cpu"),
                     f"CPU {bench.pacing_cpu} does not exist on this machine ({cpus} CPUs, numbered from 0)")


def _check_plan(tables: Mapping[str, Any], bench: BenchConfig, safety: SafetyConfig,
                key: Callable[[str, str], str]) -> None:
    """Each frequency of a bench plan against the safety limits and the sample rate; raises :class:`_Fault`."""
    excitation: ExcitationConfig = tables["excitation"]
    top = max(tables["analysis"].harmonics)
    for i, f in enumerate(excitation.frequencies_to_check()):
        at = (f"{key('excitation', 'frequencies_hz')}[{i}]" if excitation.frequencies is None
              else f"{key('excitation', 'frequencies')} (frequency {i})" if i < len(excitation.frequencies_hz)
              else f"{key('excitation', 'frequencies')} (adaptive, at the profile's knot {f:g} Hz)")
        amplitude = excitation.amplitude_at(f)
        if amplitude > safety.max_amplitude:
            if excitation.amplitudes is None and excitation.amplitude_profile is None:
                raise _Fault(key("excitation", "amplitude"),
                             f"{amplitude:g} exceeds safety.max_amplitude ({safety.max_amplitude:g})")
            rule = "amplitudes" if excitation.amplitudes is not None else "amplitude_profile"
            raise _Fault(f"{key('excitation', rule)}" + (f"[{i}]" if rule == "amplitudes" else ""),
                         f"{amplitude:g} at {f:g} Hz exceeds safety.max_amplitude ({safety.max_amplitude:g})")
        if top * f * MIN_SAMPLES_PER_PERIOD > bench.rate_hz:
            raise _Fault(at, f"{f:g} Hz: harmonic {top} needs at least {MIN_SAMPLES_PER_PERIOD} samples a "
                                 f"period at bench.rate_hz = {bench.rate_hz:g} (at most "
                                 f"{bench.rate_hz / (MIN_SAMPLES_PER_PERIOD * top):g} Hz)")
        gap_cycles = tables["analysis"].max_gap_cycles
        if top * f / bench.rate_hz >= gap_cycles:
            raise _Fault(key("analysis", "max_gap_cycles"),
                         f"{gap_cycles:g}: at {f:g} Hz one sample interval at bench.rate_hz = {bench.rate_hz:g} is "
                         f"already {top * f / bench.rate_hz:g} cycles of harmonic {top}: every period would be "
                         "discarded")
        if safety.max_rate is not None and 2 * math.pi * f * amplitude > safety.max_rate:
            raise _Fault(at, f"{f:g} Hz: the sine's slew 2*pi*f*A = {2 * math.pi * f * amplitude:g} exceeds "
                                 f"safety.max_rate ({safety.max_rate:g})")


def _bench_layout(tables: Mapping[str, Any], bench: BenchConfig, frames: Mapping[str, Any] | None,
                  setup: CanopenSetup | None, key: Callable[[str, str], str], source: str) -> Layout:
    """The frame layout of a bench case (the PDOs on CANopen, else [frames] or the default), validated for its
    transport; raises :class:`_Fault`."""
    try:
        if setup is not None:
            layout = setup.layout()
        else:
            layout = default_layout() if frames is None else Layout.from_mapping(frames, source)
        framing = tables["serial"].framing if bench.transport == "serial" else ""
        fd = bench.transport == "can" and tables["can"].fd
        layout.validate(f"serial-{framing}" if framing else "can-fd" if fd else "can")
    except LayoutError as exc:
        text = str(exc)
        head, _, problem = text.partition(": ")
        if head.startswith("frames") and problem:
            raise _Fault(head, problem) from None
        absent = "" if frames is not None else " (the default layout: give a [frames] table)"
        raise _Fault("frames", text + absent) from None
    except OSError as exc:
        raise _Fault(key("frames", "dbc"), f"cannot read: {exc.strerror or exc}") from None
    return layout


def _check_channels(tables: Mapping[str, Any], bench: BenchConfig, safety: SafetyConfig, layout: Layout,
                    setup: CanopenSetup | None, key: Callable[[str, str], str]) -> None:
    """The channels and the time base a bench case names against its frame layout; raises :class:`_Fault`."""
    channels = set(layout.channels)
    ratio = tables["analysis"].measurement in RATIO_MODES  # formed from the effort and control channels alone
    for field_name in ("output_channels", "reference_channel", "effort_channel", "control_channel")[ratio:]:
        value = getattr(bench, field_name)
        for name in (value if isinstance(value, tuple) else (value,) if value else ()):
            if name not in channels:
                raise _Fault(key("bench", field_name), f"{name!r} is not a feedback channel of the frame layout "
                                                       f"({', '.join(layout.channels)})")
    _check_measured(tables["analysis"], bench, key)
    for name in safety.feedback_limits:
        if name not in channels:
            raise _Fault(key("safety", "feedback_limits"), f"{name!r} is not a feedback channel")
    if bench.reference_channel and 1 not in tables["analysis"].harmonics:
        raise _Fault(key("analysis", "harmonics"), "two-channel mode (bench.reference_channel) needs "
                                                           "harmonic 1")
    if bench.timebase == "counter" and not layout.has_counter:
        raise _Fault(key("bench", "timebase"), "counter: the feedback frames carry no counter"
                     + (' (map a sample counter object as canopen.actual.counter, or use timebase = "sync")'
                        if setup is not None else ""))
    if bench.timebase == "timestamp" and not layout.has_timestamp:
        raise _Fault(key("bench", "timebase"), "timestamp: the feedback frames carry no timestamp_us")


def _check_measured(analysis: AnalysisConfig, bench: BenchConfig, key: Callable[[str, str], str]) -> None:
    """What ``analysis.measured`` needs of the bench's channels and harmonics; raises :class:`_Fault`."""
    measured = analysis.measurement
    if measured == "output":
        return
    if bench.reference_channel:
        raise _Fault(key("bench", "reference_channel"), f'not with analysis.measured = "{measured}": its '
                                                        "divisor is the effort channel")
    try:
        formed_columns(measured, bench.output_channels, "", bench.effort_channel, bench.control_channel)
    except FormError as exc:
        raise _Fault(key("bench", exc.field), str(exc)) from None
    if measured in RATIO_MODES and analysis.harmonics != (1,):
        raise _Fault(key("analysis", "harmonics"), f'analysis.measured = "{measured}" is a ratio of fundamentals: '
                                                   "harmonics = [1]")


def _canopen_setup(table: CanopenConfig, simulated: bool, key: Callable[[str, str], str],
                   source: str) -> CanopenSetup:
    """The [canopen] table resolved against its EDS (objects by index or name, PDO sizes); raises :class:`_Fault`."""
    if table.eds:
        eds = Path(table.eds)
        if not eds.is_absolute():
            eds = Path(source).parent / eds
    elif simulated:
        eds = SIMULATED_EDS[table.profile]
    else:
        raise _Fault(key("canopen", "eds"), "missing: the drive's EDS or DCF file (only a [simulator] brings its own)")
    require("canopen", f'{source}: bench.transport = "canopen"')
    try:
        od = load_od(eds, table.node_id)
    except ValueError as exc:
        raise _Fault(key("canopen", "eds"), str(exc)) from None
    for index, what in ((0x1400 + table.rpdo - 1, "rpdo"), (0x1800 + table.tpdo - 1, "tpdo")):
        if index not in od or (index + 0x200) not in od:
            raise _Fault(key("canopen", what), f"the EDS has no PDO {getattr(table, what)} (objects 0x{index:04X} "
                                               f"and 0x{index + 0x200:04X})")
    profile = PROFILES[table.profile]
    for index, name in profile.required:
        if index not in od:
            raise _Fault(key("canopen", "eds"), f"the EDS has no {name} (0x{index:04X}): not a {profile.name} "
                                                f"{profile.device} (canopen.profile = \"{table.profile}\")")
    mode = table.mode_name
    try:
        setpoint = resolve_object(od, table.setpoint or profile.setpoints[mode])
    except ValueError as exc:
        raise _Fault(key("canopen", "setpoint"), str(exc)) from None
    assumed: dict[tuple[int, int], tuple[int, int, int, str]] = {}
    setpoint_scale = table.setpoint_scale if table.setpoint_scale is not None else \
        _default_scale(od, profile.number, setpoint, assumed)
    actual_table = table.actual or profile.actuals[mode]
    actual = []
    for channel, text in actual_table.items():
        try:
            ref = resolve_object(od, text)
        except ValueError as exc:
            raise _Fault(f"{key('canopen', 'actual')}.{channel}", str(exc)) from None
        if channel == COUNTER and ref.type not in ("uint8", "uint16"):
            raise _Fault(f"{key('canopen', 'actual')}.{channel}",
                         f"{ref} is {ref.type}: a sample counter must be UNSIGNED8 or UNSIGNED16")
        if channel == TIMESTAMP and not ref.type.startswith("uint"):
            raise _Fault(f"{key('canopen', 'actual')}.{channel}", f"{ref} is {ref.type}: a timestamp is unsigned")
        if channel in (COUNTER, TIMESTAMP):
            scale = 1.0
        elif channel in table.actual_scale:
            scale = float(table.actual_scale[channel])
        else:
            scale = _default_scale(od, profile.number, ref, assumed)
        actual.append((channel, ref, scale))
    size = 2 + sum(ref.size for _, ref, _ in actual)
    if size > 8:
        raise _Fault(key("canopen", "actual"), f"the statusword and these objects take {size} bytes: a TPDO carries 8")
    operating_point = None
    target = resolve_object(od, profile.setpoints[mode])
    if (setpoint.index, setpoint.subindex) != (target.index, target.subindex):
        # an offset excited around the mode's target: the target holds the position where the drive stands
        held = resolve_object(od, next(iter(profile.actuals[mode].values()))) if mode in profile.position_modes \
            else None
        operating_point = (target, held)
    return CanopenSetup(table.node_id, str(eds), mode, setpoint, setpoint_scale, tuple(actual),
                        table.rpdo, table.tpdo, table.sync, table.heartbeat_ms, table.heartbeat_timeout_s,
                        table.state_timeout_s, table.fault_reset, host_node_id=table.host_node_id,
                        host_heartbeat_ms=table.host_heartbeat_ms, drive_heartbeat_timeout_ms=table.consumer_ms,
                        abort_connection=ABORT_CONNECTION_OPTIONS[table.abort_connection], profile=table.profile,
                        assumed=tuple(assumed.values()), operating_point=operating_point)


def _default_scale(od: Any, profile: int, ref: ObjectRef,
                   assumed: dict[tuple[int, int], tuple[int, int, int, str]]) -> float:
    """Units per count of ``ref`` when the config gives none: 1 on CiA 402; on CiA 408 a process value's scale from
    the EDS (``cia408.process_value_scale``), the EDS values it used added to ``assumed``."""
    if profile != 408 or ref.subindex != 1:
        return 1.0
    if cia408.is_spool_value(ref.index):
        index, sub = cia408.SPOOL_REFERENCE
        reference = _eds_default(od, index, sub)
        if reference is None or reference <= 0:
            return cia408.process_value_scale(ref.index)
        assumed[(index, sub)] = (index, sub, reference, "spool position reference value")
        return cia408.process_value_scale(ref.index, reference=reference)
    prefix = _eds_default(od, ref.index, cia408.PREFIX_SUBINDEX)
    if prefix is None:
        return 1.0
    assumed[(ref.index, cia408.PREFIX_SUBINDEX)] = (ref.index, cia408.PREFIX_SUBINDEX, prefix,
                                                    f"decimal prefix of {ref.name}")
    return cia408.process_value_scale(ref.index, prefix=prefix)


def _eds_default(od: Any, index: int, subindex: int) -> int | None:
    """The EDS's default value of ``index``:``subindex`` as an integer; None where it has none."""
    try:
        value = od[index][subindex].default
    except (KeyError, TypeError, AttributeError):
        return None
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def parse_config(data: Mapping[str, Any], source: str = "<config>", overrides: Sequence[Override] = ()
                 ) -> ExperimentConfig:
    """Validate an already parsed configuration (a dict shaped like the TOML file).

    ``source`` names the configuration in error messages; its stem names the single case of a file without
    ``[cases]`` and is the default title. ``overrides`` (the command line's ``--set``) are set in the document
    first, so they are validated as the file's own keys are, and an error at a key one of them set names it
    with its option (``configs/x.toml: --set serial.prt: unknown key``). Raises :class:`ConfigError`.
    """
    created: list[tuple[str, ...]] = []
    cases = data.get("cases") if isinstance(data, Mapping) else None
    for override in overrides:
        if len(override.parts) > 1 and override.parts[0] == "cases" and isinstance(cases, Mapping) and \
                override.parts[1] not in cases:
            names = ", ".join(_key_path(name) for name in cases)
            raise ConfigError(f"{source}: {override.option} {override.key}: no case {_key_path(override.parts[1])} "
                              f"in the file (its cases: {names}; quote a name holding a dot: "
                              'cases."fbar_0.8".plant.friction)', override.key)
    if overrides:
        try:
            data, created = apply_overrides(data, overrides)
        except OverrideError as exc:
            raise ConfigError(f"{source}: {exc}", exc.key) from None
    try:
        return _parse(data, source)
    except _Fault as fault:
        setter = names_override(fault.key, overrides, created)
        if setter is not None:
            raise ConfigError(f"{source}: {setter.option} {fault.key}: {fault.problem}", fault.key) from None
        raise _error(source, fault) from None


_TOML_POSITION = re.compile(r"\s*\(at line (\d+), column (\d+)\)$")
_TOML_END = re.compile(r"\s*\(at end of document\)$")


def _toml_error(source: str, text: str, err: tomllib.TOMLDecodeError) -> ConfigError:
    message = " ".join(str(err).split())
    found = _TOML_POSITION.search(message)
    if found:
        line, column = int(found.group(1)), int(found.group(2))
        message = message[: found.start()]
    else:
        lines = text.split("\n")
        line, column = len(lines), len(lines[-1]) + 1
        message = _TOML_END.sub("", message)
    return ConfigError(f"{source}: line {line} column {column}: {message}")


def read_document(path: str | Path) -> dict[str, Any]:
    """A TOML configuration file as parsed, not validated. Raises :class:`ConfigError` (one-line message)."""
    source = str(path)
    try:
        blob = Path(path).read_bytes()
    except OSError as err:
        raise ConfigError(f"{source}: cannot read: {err.strerror or err}") from None
    try:
        text = blob.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{source}: cannot read: not UTF-8 (byte {err.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise _toml_error(source, text, err) from None


def load_config(path: str | Path, overrides: Sequence[Override] = ()) -> ExperimentConfig:
    """Read and validate a TOML configuration file, ``overrides`` set in it first (see :func:`parse_config`).
    Raises :class:`ConfigError` (one-line message); :class:`~bodebench.drivers.extras.MissingDependency` (one line
    naming the extra) for transport canopen without the canopen package."""
    return parse_config(read_document(path), str(path), overrides)
