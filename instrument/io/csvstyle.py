"""How ``response.csv`` is laid out: its delimiter and decimal mark, and the description of every column's meaning,
units and the confidence level of the intervals.

The ``[results]`` table of a configuration chooses the style; a reader needs no configuration: the header is the
first line and the delimiter is the one it uses. The description sits beside the table, in
``response.csv-metadata.json`` (W3C's metadata vocabulary for tabular data, CSVW), so that the file itself is a
plain table to pandas, a spreadsheet or MATLAB's ``readtable``. Files of earlier versions carried it as comment
lines starting with ``#`` above the header; those are still read.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["COLUMN_DOCS", "CsvStyle", "DELIMITERS", "csv_metadata", "style_of_config", "style_of_header"]

DELIMITERS: dict[str, str] = {",": ",", ";": ";", "tab": "\t"}
"""``results.delimiter`` values and the character each stands for."""

COLUMN_DOCS: dict[str, str] = {
    "frequency_hz": "excitation frequency f, Hz",
    "harmonic": "harmonic number k: the row describes the output at k f against the input sine at f",
    "channel": "feedback channel measured",
    "amplitude": "input amplitude A_i, input units",
    "gain": "|P + jQ| / A_i: the amplitude of harmonic k of the output per unit of input amplitude, output "
            "units per input unit (for k > 1 a distortion ratio, not a transfer function)",
    "gain_db": "20 log10(gain), dB",
    "phase_deg": "phase of harmonic k of the output against the input sine, atan2(Q, P), degrees in (-360, 0]; "
                 "nan where undefined (below the resolution)",
    "p": "P, averaged sine coefficient of harmonic k: y ~ P sin(2 pi k f t) + Q cos(2 pi k f t), output units",
    "q": "Q, averaged cosine coefficient of harmonic k, output units",
    "periods": "periods integrated, the skipped ones included",
    "converged": "true when the stopping rule's error bound met the tolerance",
    "status": "converged, below_resolution, noise_limited, capped or fixed (docs/measurement.md, Results)",
    "uncertainty": "radius of the confidence disc of (P, Q), output units",
    "gain_ci": "half-width of the gain's confidence interval, output units per input unit",
    "gain_db_ci": "half-width of the gain's confidence interval above the gain, dB",
    "phase_ci_deg": "half-width of the phase's confidence interval, degrees",
    "uncertainty_1d": "half-width of the confidence interval of (P, Q) along one direction, output units",
    "within_eps": "true when the stated uncertainty is within the requested tolerance",
    "periods_needed": "noise-limited points: periods the requested tolerance would take (0: not estimated)",
    "thd": "harmonic-1 rows: total harmonic distortion sqrt(sum over k >= 2 of |Z_k|^2) / |Z_1| from the "
           "harmonics measured, a ratio (nan: none measured, or another harmonic's row)",
    "coherence": "|mean Z_i|^2 / mean |Z_i|^2 over the later half of the analysed periods: the share of the "
                 "output's power at k f locked to the excitation, 0 to 1",
    "periods_discarded": "periods not integrated because a gap in the samples, longer than max_gap_cycles of the "
                         "highest harmonic, touched them (not among periods)",
    "drift_per_s": "the channel's linear drift over the analysed periods, estimated and taken off every period's "
                   "coefficients, output units per second (nan: not estimated, as offline)",
    "tolerance_percent": "the tolerance the point was measured to, percent: within_eps and converged are against "
                         "it (it may differ from the configuration's where it was changed during the sweep)",
}


@dataclass(frozen=True)
class CsvStyle:
    """A delimiter character and a decimal mark ("." or ",")."""

    delimiter: str = ","
    decimal: str = "."

    def number(self, text: str) -> str:
        """A number as written: its decimal point replaced by the decimal mark."""
        return text.replace(".", ",") if self.decimal == "," else text

    def join(self, cells: list[str]) -> str:
        for cell in cells:
            if self.delimiter in cell:
                raise ValueError(f"value {cell!r} contains the CSV delimiter {self.delimiter!r}")
        return self.delimiter.join(cells)


def style_of_config(config: Mapping[str, Any]) -> CsvStyle:
    """The style a configuration (as saved with the results) asks for: its ``results`` table, else the default."""
    table = config.get("results") if isinstance(config, Mapping) else None
    if not isinstance(table, Mapping):
        return CsvStyle()
    return CsvStyle(DELIMITERS.get(str(table.get("delimiter", ",")), ","), str(table.get("decimal", ".")))


def style_of_header(header: str) -> CsvStyle:
    """The style of a file from its header line: its delimiter, and a decimal comma wherever the delimiter is not a
    comma (a reader accepts either mark then)."""
    for delimiter in (";", "\t"):
        if delimiter in header:
            return CsvStyle(delimiter, ",")
    return CsvStyle()


def csv_metadata(csv_name: str, format_version: int, confidence: float, style: CsvStyle,
                 columns: tuple[str, ...]) -> dict[str, Any]:
    """The CSVW description of ``csv_name``: what a row is, the confidence level, the dialect (delimiter; the decimal
    mark of the numbers) and each column's name and meaning with units."""
    return {
        "@context": "http://www.w3.org/ns/csvw",
        "url": csv_name,
        "dc:title": f"bodebench response, format {format_version}",
        "dc:description": (f"one row per frequency, harmonic and channel, in the order measured; every interval and "
                           f"uncertainty is at {confidence:.0%} confidence; decimal mark {style.decimal!r}"),
        "dialect": {"delimiter": style.delimiter, "header": True, "encoding": "utf-8"},
        "tableSchema": {"columns": [{"name": name, "titles": name, "dc:description": COLUMN_DOCS[name]}
                                    for name in columns]},
    }
