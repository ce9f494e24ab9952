"""The Bode view: gain and phase of the responses measured and overlaid, and the summary figures of the first."""

from __future__ import annotations

from collections.abc import Sequence

from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import Static

from bodebench.apps.tui.braille import Trace, auto_axis
from bodebench.apps.tui.widgets import PALETTE, PlotView
from bodebench.core.response import FrequencyResponse
from bodebench.core.summary import ResponseSummary, summarize_response

_SHORT_NAMES = {"bandwidth (-3 dB)": "BW", "resonance peak": "peak", "phase -90 deg": "-90°",
                "phase -180 deg": "-180°", "phase margin": "PM", "gain margin": "GM"}


def summary_line(summary: ResponseSummary) -> Text:
    """The figures of one summary on one line: ``BW 9.95 Hz  peak +11.3 dB @ 8.52 Hz  -90° 9.13 Hz  -180° --``
    (``--``: not found in the measured range)."""
    text = Text()
    for figure in summary.figures:
        if text.plain:
            text.append("  ")
        text.append(_SHORT_NAMES.get(figure.name, figure.name) + " ", style="bold")
        if not figure.found:
            text.append("--", style="bright_black")
        elif figure.unit == "Hz":
            text.append(f"{figure.value:.3g} Hz")
        else:
            sign = "+" if figure.name == "resonance peak" else ""
            text.append(f"{figure.value:{sign}.3g} {figure.unit.replace('deg', '°')} @ {figure.at_hz:.3g} Hz")
    return text


class BodePanel(Vertical):
    """Gain (dB) and phase (deg) against log frequency, first harmonic, one colour per response and channel;
    under them the summary figures of the first response (its first channel), read off the points so far.

    It keeps the responses the user overlaid (``overlays``, (label, response)) and draws them after the sweep's;
    ``stale`` says the responses changed since they were last drawn.
    """

    DEFAULT_CSS = """
    BodePanel { height: 1fr; }
    BodePanel #bode-summary { height: 1; }
    """

    def __init__(self, *, id: str | None = None, classes: str | None = None) -> None:
        super().__init__(id=id, classes=classes)
        self.overlays: list[tuple[str, FrequencyResponse]] = []
        self.stale = True

    def compose(self) -> ComposeResult:
        yield PlotView("gain dB", "no converged points yet", id="bode-gain")
        yield PlotView("phase °", "", id="bode-phase")
        yield Static("", id="bode-summary")

    def overlay(self, loaded: Sequence[tuple[str, FrequencyResponse]]) -> None:
        """Add responses to draw over the sweep's, each label made unique (``name (2)``, ...)."""
        labels = {label for label, _ in self.overlays}
        for label, response in loaded:
            unique, n = label, 2
            while unique in labels:
                unique, n = f"{label} ({n})", n + 1
            labels.add(unique)
            self.overlays.append((unique, response))
        self.stale = True

    def redraw(self, responses: Sequence[tuple[str, FrequencyResponse]]) -> None:
        """Draw the sweep's ``responses`` (the current case's first), then the overlays."""
        self.stale = False
        self.show([*responses, *self.overlays])

    def show_summary(self, responses: Sequence[tuple[str, FrequencyResponse]]) -> None:
        text = Text()
        for label, response in responses[:1]:
            kind = response.config.get("analysis", {}).get("response") or "system"
            summaries = summarize_response(response, kind)
            if summaries:
                text = summary_line(summaries[0])
                if len(responses) > 1 or len(summaries) > 1:
                    text = Text(f"{label} {summaries[0].channel}: ", style="bold") + text
        self.query_one("#bode-summary", Static).update(text, layout=False)

    def show(self, responses: Sequence[tuple[str, FrequencyResponse]]) -> None:
        gain_traces, phase_traces, legend = [], [], Text()
        freqs, gains, phases = [], [], []
        colour_index = 0
        for label, response in responses:
            first = response.select(harmonic=1)
            for channel in first.channels:
                sel = first.select(channel=channel)
                if not len(sel):
                    continue
                colour = PALETTE[colour_index % len(PALETTE)]
                colour_index += 1
                f, g = sel.frequency_hz, sel.gain_db
                ph = sel.phase_unwrapped_deg()
                gain_traces.append(Trace(f, g, colour))
                phase_traces.append(Trace(f, ph, colour))
                freqs.append(f)
                gains.append(g)
                phases.append(ph)
                if legend.plain:
                    legend.append("  ")
                legend.append(f"● {label}" + (f" {channel}" if len(first.channels) > 1 else ""), style=colour)
        gain_view = self.query_one("#bode-gain", PlotView)
        phase_view = self.query_one("#bode-phase", PlotView)
        self.show_summary(responses)
        if not gain_traces:
            gain_view.clear()
            phase_view.clear()
            return
        x_axis = auto_axis(freqs, log=True)
        gain_view.set_plot(gain_traces, x_axis, auto_axis(gains), (), legend)
        phase_view.set_plot(phase_traces, x_axis, auto_axis(phases))
