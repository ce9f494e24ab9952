"""The plots show what was measured: below-resolution points as bounds, named confidence bands, plain log ticks,
the configuration's title, one colour per harmonic, the summary marked; the comparison command."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import LineCollection
from matplotlib.colors import to_hex

from bodebench.apps.cli import main
from bodebench.apps.plots import bode_figure, harmonic_colour, periods_figure, write_plots
from bodebench.bench.procedure import SweepProcedure
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.core.summary import summarize_response
from bodebench.io.config import parse_config
from bodebench.io.results import save_response

FREQS = np.geomspace(1.0, 100.0, 21)


def response(label: str = "a", fn: float = 10.0) -> FrequencyResponse:
    """Harmonics 1 and 3 of a second-order system; harmonic 2 exactly zero (below the resolution)."""
    out = FrequencyResponse(case=label)
    for f in FREQS:
        g = 1.0 / (1.0 - (f / fn) ** 2 + 0.6j * f / fn)
        for k, value, status in ((1, g, "converged"), (2, 0j, "below_resolution"), (3, 0.01 * g, "converged")):
            u = 1e-3 * abs(g)
            out.add(ResponsePoint(float(f), k, "position", 0.5, 0.5 * value.real, 0.5 * value.imag, 50, True,
                                  status, uncertainty=u * 1.2, uncertainty_1d=u))
    return out


def lines_of(ax) -> list:  # noqa: ANN001 - a matplotlib Axes
    return [line for line in ax.get_lines() if np.asarray(line.get_ydata(), dtype=float).size]


def test_below_resolution_points_are_upper_bounds_not_data() -> None:
    r = response()
    fig = bode_figure(r)
    ax_gain, ax_phase, ax_dist = fig.axes[:3]
    zero = [p for p in r.points if p.harmonic == 2]
    first = {p.frequency_hz: p.gain_db for p in r.points if p.harmonic == 1}
    bounds = sorted(20 * math.log10(p.magnitude / p.amplitude + p.gain_ci) - first[p.frequency_hz] for p in zero)
    triangles = [line for line in lines_of(ax_dist) if line.get_marker() == "v"]
    assert len(triangles) == 1 and not [line for line in lines_of(ax_gain) if line.get_marker() == "v"]
    assert sorted(np.asarray(triangles[0].get_ydata(), dtype=float)) == pytest.approx(bounds)
    assert to_hex(triangles[0].get_markeredgecolor()) == harmonic_colour(2)
    for line in lines_of(ax_dist):
        if line is triangles[0]:
            continue
        y = np.asarray(line.get_ydata(), dtype=float)
        if to_hex(line.get_color()) == harmonic_colour(2):  # the k = 2 curve itself draws nothing
            assert not np.isfinite(y).any()
    for line in lines_of(ax_gain) + lines_of(ax_phase):  # harmonic 1 only above the distortion panel
        assert to_hex(line.get_color()) == harmonic_colour(1)
    legend = [t.get_text() for t in ax_gain.get_legend().get_texts()]
    assert "below resolution: upper bound" in legend and "95% confidence band" in legend


def test_harmonics_above_the_first_are_drawn_as_distortion_relative_to_it() -> None:
    """Harmonic 3 is 0.01 of harmonic 1 at every frequency: -40 dB in the distortion panel, whatever the gain."""
    fig = bode_figure(response())
    ax_dist = fig.axes[2]
    assert ax_dist.get_ylabel() == "Distortion (dB re k=1)"
    third = [line for line in lines_of(ax_dist) if to_hex(line.get_color()) == harmonic_colour(3)
             and line.get_label() == "k=3"]
    assert len(third) == 1
    assert np.asarray(third[0].get_ydata(), dtype=float) == pytest.approx(-40.0, abs=1e-9)


def test_the_amplitude_and_the_tolerance_are_on_the_plot() -> None:
    r = response()
    r.config = {"analysis": {"tolerance_percent": 0.05}}
    legend = [t.get_text() for t in bode_figure(r).axes[0].get_legend().get_texts()]
    assert "amplitude 0.5, tolerance 0.05 %" in legend


def test_confidence_bands_are_the_point_intervals() -> None:
    r = response()
    fig = bode_figure(r)
    ax_gain, ax_dist = fig.axes[0], fig.axes[2]

    def bands(ax) -> list:  # noqa: ANN001 - a matplotlib Axes
        return [c for c in ax.collections if not isinstance(c, LineCollection)]  # not the minor grid

    assert len(bands(ax_gain)) == 1 and len(bands(ax_dist)) == 1  # k = 1; k = 3; none for the zero harmonic
    first = r.select(harmonic=1)
    path = bands(ax_gain)[0].get_paths()[0].vertices
    top = max(path[:, 1])
    assert top == pytest.approx(max(20 * np.log10(first.gain + np.array([p.gain_ci for p in first.points]))))


def test_log_ticks_are_plain_numbers_and_the_title_is_shown() -> None:
    fig = bode_figure(response(), title="Drive X, axis 2")
    fig.canvas.draw()
    labels = [t.get_text() for t in fig.axes[-1].get_xticklabels() if t.get_text()]
    assert labels and all(float(text) > 0 for text in labels), labels
    assert {"1", "2", "5", "10", "20", "50", "100"} <= set(labels)
    assert fig._suptitle is not None and fig._suptitle.get_text() == "Drive X, axis 2"
    chart = periods_figure(response())
    chart.canvas.draw()
    for axis in (chart.axes[0].xaxis, chart.axes[0].yaxis):
        minor = [t.get_text() for t in axis.get_minorticklabels() if t.get_text()]
        assert minor == []  # no minor labels to overlap
        assert all("10^" not in t.get_text() and "$" not in t.get_text() for t in axis.get_majorticklabels())


def wide_response(periods: int, low_db: float, high_db: float) -> FrequencyResponse:
    """Gains from low_db to high_db over 0.1 .. 2000 Hz, phases down to -720 deg, every point ``periods`` long."""
    out = FrequencyResponse(case="wide")
    freqs = np.geomspace(0.1, 2000.0, 30)
    for i, f in enumerate(freqs):
        gain = 10.0 ** ((low_db + (high_db - low_db) * i / (freqs.size - 1)) / 20.0)
        value = gain * np.exp(-1j * np.pi * 4.0 * i / (freqs.size - 1))
        out.add(ResponsePoint(float(f), 1, "position", 1.0, value.real, value.imag, periods, True, "converged",
                              uncertainty=1e-3 * gain, uncertainty_1d=1e-3 * gain))
    return out


@pytest.mark.parametrize("periods, low_db, high_db", [(12, -320.0, 140.0), (20000, -0.5, 0.5), (3, 40.0, 90.0)])
def test_nothing_drawn_falls_off_the_figure(periods: int, low_db: float, high_db: float) -> None:
    r = wide_response(periods, low_db, high_db)
    for fig in (bode_figure(r, title="Electrohydraulic actuator, axis 2, valve spool loop (rig B)",
                            summary=summarize_response(r)), bode_figure(r), periods_figure(r, title="rig B"),
                periods_figure(r)):
        fig.canvas.draw()
        box = fig.get_tightbbox(fig.canvas.get_renderer())  # inches
        width, height = fig.get_size_inches()
        assert box.x0 >= 0.0 and box.y0 >= 0.0 and box.x1 <= width and box.y1 <= height, (box, width, height)


def test_the_minor_grid_is_at_every_integer_of_each_decade_between_the_major_ticks() -> None:
    fig = periods_figure(wide_response(20000, 0.0, 1.0))
    ax = fig.axes[0]
    grids = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(grids) == 2

    def expected(low: float, high: float) -> list[float]:
        return [s * 10.0 ** d for d in range(-6, 9) for s in (3, 4, 6, 7, 8, 9) if low <= s * 10.0 ** d <= high]

    x_at = [float(seg[0][0]) for seg in grids[0].get_segments()]
    y_at = [float(seg[0][1]) for seg in grids[1].get_segments()]
    assert x_at == pytest.approx(expected(*ax.get_xlim())) and y_at == pytest.approx(expected(*ax.get_ylim()))
    assert 900.0 in x_at and 30000.0 in y_at and len(x_at) == 3 + 6 * 4 + 1  # 0.07 .. 0.09, four decades, 3000 Hz


def test_each_harmonic_has_one_colour_in_every_figure() -> None:
    r = {"drive A": response("a"), "drive B": response("b", fn=20.0)}
    for fig in (bode_figure(r), periods_figure(r)):
        for line in fig.axes[0].get_lines():
            label = line.get_label()
            if "k=" in label:
                k = int(label.split("k=")[1].split()[0])
                assert to_hex(line.get_color()) == harmonic_colour(k), label
    styles = {line.get_label(): line.get_linestyle() for line in bode_figure(r).axes[0].get_lines()
              if "k=1" in line.get_label()}
    assert len(set(styles.values())) == 2  # the two drives told apart by line style


def test_summary_figures_are_marked() -> None:
    r = response()
    texts = [t.get_text() for t in bode_figure(r, summary=summarize_response(r)).axes[0].texts]
    bandwidth = summarize_response(r)[0].figure("bandwidth (-3 dB)").value
    assert f"BW {bandwidth:.3g} Hz" in texts


def test_sweep_plots_carry_the_configuration_title(tmp_path: Path) -> None:
    config = parse_config({
        "title": "Lag on the bench",
        "plant": {"model": "lag", "time_constant": 0.05},
        "excitation": {"amplitude": 1.0, "frequencies_hz": [0.5, 2.0, 8.0]},
        "analysis": {"tolerance_percent": 0.5, "steps_per_period": 32},
        "cases": {"slow": {}, "fast": {"plant": {"time_constant": 0.01}}},
    }, "lag.toml")
    titles: list[str] = []

    def record(response: FrequencyResponse, directory: Path, title: str, **_: object) -> list[Path]:
        titles.append(title)
        return []

    SweepProcedure(config, tmp_path, plots=record).run()
    assert titles == ["Lag on the bench: slow", "Lag on the bench: fast"]


def test_write_plots_draws_the_figures_asked_for(tmp_path: Path) -> None:
    """A pool draws a case's figures as separate tasks; each writes its own files, and together they are all."""
    r = response()
    assert write_plots(r, tmp_path / "one", "t", figures=("periods",)) == [tmp_path / "one" / "periods.png"]
    assert not (tmp_path / "one" / "bode.png").exists()
    both = write_plots(r, tmp_path / "all", "t", formats=("png", "svg"))
    assert sorted(p.name for p in both) == ["bode.png", "bode.svg", "periods.png", "periods.svg"]
    assert all(p.stat().st_size > 0 for p in both)
    with pytest.raises(ValueError, match="unknown figure 'nyquist'"):
        write_plots(r, tmp_path / "none", "t", figures=("nyquist",))


def test_plot_command_compares_results_directories(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    save_response(response("a"), tmp_path / "a")
    save_response(response("b", 20.0), tmp_path / "runs" / "b1")
    save_response(response("c", 30.0), tmp_path / "runs" / "b2")
    out = tmp_path / "cmp.png"
    assert main(["plot", str(tmp_path / "a"), str(tmp_path / "runs"), "--out", str(out), "--title", "A vs B"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "3 responses -> " in capsys.readouterr().out
    assert main(["plot", str(tmp_path / "a"), "--out", str(tmp_path / "cmp")]) == 2
    assert capsys.readouterr().err == (f"bodebench: {tmp_path / 'cmp'}: no file suffix to take the image format from "
                                       "(e.g. .png or .svg)\n")
    assert main(["plot", str(tmp_path / "a"), "--out", str(tmp_path / "cmp.jpg")]) == 2
    assert capsys.readouterr().err == (f"bodebench: {tmp_path / 'cmp.jpg'}: plot format jpg unknown; choose from png, "
                                       "svg, pdf\n")
    assert main(["plot", str(tmp_path / "nothing"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("nothing: not a directory") and "\n" not in err
