"""The files of an overview measurement (docs/overview.md): its lines as a response like any sweep's
(``response.csv`` and the ``response.json`` sidecar, which ``bodebench fit`` and ``bodebench plot`` read), the
multisine in the sidecar's ``multisine`` key, and ``overview.csv``: each line's gain and phase with their 95 %
intervals, its periods and status, and the distortion and noise at its detection lines."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bodebench.core.multisine import Multisine
from bodebench.core.overview import OverviewLine
from bodebench.core.response import FrequencyResponse
from bodebench.io.csvstyle import style_of_config
from bodebench.io.results import atomic_write_text, save_response, update_sidecar

__all__ = ["OVERVIEW_COLUMNS", "OVERVIEW_CSV", "design_record", "overview_response", "save_overview"]

OVERVIEW_CSV = "overview.csv"
OVERVIEW_COLUMNS: dict[str, str] = {
    "frequency_hz": "the line's frequency, Hz",
    "line_amplitude": "the line's amplitude in the setpoint (peak of its sine), input units",
    "gain": "|output / setpoint| at the line, output units per input unit",
    "gain_ci": "half-width of the gain's 95 % interval, output units per input unit",
    "phase_deg": "phase of output / setpoint, degrees, in (-360, 0] (nan: below resolution, or an interval "
                 "holding zero)",
    "phase_ci_deg": "half-width of the phase's 95 % interval, degrees",
    "periods": "periods the line's stopping rule took (its verdict's period)",
    "status": "how the rule ended the line: converged, below_resolution, noise_limited or capped",
    "distortion": "rms of the mean output coefficients at the line's detection lines, output units",
    "noise": "rms of the standard errors of those means, from their period-to-period spread, output units",
    "distortion_db": "distortion relative to the output at the line, dB",
    "noise_db": "noise relative to the output at the line, dB",
}
"""Columns of overview.csv, in file order, with their meaning."""


def overview_response(lines: Sequence[OverviewLine], config: Mapping[str, Any], case: str) -> FrequencyResponse:
    """The lines as a response: one harmonic-1 point per excited line."""
    return FrequencyResponse((line.point for line in lines), config=config, case=case)


def design_record(design: Multisine, periods: int) -> dict[str, Any]:
    """The multisine as the sidecar records it: rate (Hz), samples a period, period (s), line spacing (Hz), the
    excited lines' indices, their phases (rad) and amplitude (input units), peak and rms (input units), crest
    factor, steepest slew (input units per s), and the periods the measurement ran."""
    return {"rate_hz": design.rate_hz, "samples": design.samples, "period_s": design.period_s,
            "resolution_hz": design.resolution_hz, "lines": list(design.lines), "phases": list(design.phases),
            "line_amplitude": design.line_amplitude, "peak": design.peak, "rms": design.rms,
            "crest_factor": design.crest_factor, "peak_slew": design.peak_slew, "periods": periods}


def save_overview(directory: str | Path, lines: Sequence[OverviewLine], design: Multisine, periods: int,
                  config: Mapping[str, Any], case: str) -> FrequencyResponse:
    """Write an overview's files into ``directory`` (made where it does not exist); returns its response."""
    directory = Path(directory)
    response = overview_response(lines, config, case)
    save_response(response, directory)
    update_sidecar(directory, {"multisine": design_record(design, periods)})
    style = style_of_config(response.config)

    def number(value: float) -> str:
        return style.number(repr(float(value)))

    rows = [style.join(list(OVERVIEW_COLUMNS))]
    for line in lines:
        p = line.point
        rows.append(style.join([number(p.frequency_hz), number(p.amplitude), number(p.gain), number(p.gain_ci),
                                number(p.phase_deg), number(p.phase_ci_deg), str(p.periods), p.status,
                                number(line.distortion), number(line.noise), number(line.distortion_db),
                                number(line.noise_db)]))
    atomic_write_text(directory / OVERVIEW_CSV, "\n".join(rows) + "\n")
    return response
