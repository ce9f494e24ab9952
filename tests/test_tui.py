"""The terminal UI: its pure parts against independent numbers, every key against the simulated drive on the
lockstep clock (Pilot), snapshots of the main screens, and the real command in tmux."""

from __future__ import annotations

import asyncio
import cmath
import dataclasses
import json
import math
import os
import shutil
import subprocess
import sys
import threading
import time
import unicodedata
import uuid
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from helpers import BusRecorder
from textual.widgets import Static
from textual.widgets._footer import FooterKey

from bodebench.analysis.reanalyse import reanalyse
from bodebench.apps.tui import BodeBenchApp
from bodebench.apps.tui.braille import Axis, BrailleCanvas, HLine, PlotError, Trace, auto_axis, render_plot
from bodebench.apps.tui.bridge import SessionBridge
from bodebench.apps.tui.dialogs import ChoiceDialog, ConfirmDialog, InputDialog, MessageDialog
from bodebench.apps.tui.model import (
    ALIASED,
    CAPPED,
    CONVERGED,
    DISTURBED,
    FAILED,
    INTEGRATING,
    NOISE_LIMITED,
    PENDING,
    SETTLING,
    SKIPPED,
    UNTIED,
    BusRates,
    SweepModel,
    format_duration,
    relative_error_percent,
    row_key,
)
from bodebench.apps.tui.status import StatusLine
from bodebench.apps.tui.widgets import PlotView, percent_cell
from bodebench.bench.events import PointProgress, PointStarted
from bodebench.core.autointegration import SeriesState
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.core.rules import Verdict
from bodebench.io.config import ExperimentConfig, load_config
from bodebench.io.results import load_response, save_response, sidecar_runs

ROOT = Path(__file__).resolve().parent.parent
FREQS = (3.0, 8.0, 20.0)

# ------------------------------------------------------------------------------------------- braille plots


def braille_dots(char: str) -> set[int]:
    """Dot numbers (1..8) of a braille character, from its Unicode name."""
    name = unicodedata.name(char)
    if name == "BRAILLE PATTERN BLANK":
        return set()
    prefix = "BRAILLE PATTERN DOTS-"
    assert name.startswith(prefix), name
    return {int(d) for d in name[len(prefix):]}


# the standard braille numbering: left column dots 1, 2, 3, 7 from the top, right column 4, 5, 6, 8
STANDARD_DOT = {(0, 0): 1, (0, 1): 2, (0, 2): 3, (0, 3): 7, (1, 0): 4, (1, 1): 5, (1, 2): 6, (1, 3): 8}


@pytest.mark.parametrize("px,py", sorted(STANDARD_DOT))
def test_each_dot_is_the_standard_braille_dot(px: int, py: int) -> None:
    canvas = BrailleCanvas(1, 1)
    canvas.dot(px, py, "red")
    [line] = canvas.lines()
    assert braille_dots(line.plain) == {STANDARD_DOT[(px, py)]}


def lit_dots(lines: list) -> set[tuple[int, int]]:
    """(px, py) of every dot set in canvas lines."""
    inverse = {n: xy for xy, n in STANDARD_DOT.items()}
    dots = set()
    for r, line in enumerate(lines):
        for c, ch in enumerate(line.plain):
            for n in braille_dots(ch):
                x, y = inverse[n]
                dots.add((2 * c + x, 4 * r + y))
    return dots


def test_lines_are_connected_and_reach_both_ends() -> None:
    canvas = BrailleCanvas(10, 3)
    canvas.line(0, 11, 19, 0, "white")
    dots = lit_dots(canvas.lines())
    assert (0, 11) in dots and (19, 0) in dots
    assert len({x for x, _ in dots}) == 20  # one column per x (shallow line), none skipped
    for x, y in dots:  # every dot within one dot of the ideal line
        assert abs(y - (11 - 11 * x / 19)) <= 1.0


def test_log_axis_positions_and_decade_ticks() -> None:
    axis = Axis(0.01, 100.0, log=True)
    assert axis.fraction(np.array([1.0]))[0] == pytest.approx(0.5)
    assert axis.fraction(np.array([0.1]))[0] == pytest.approx(0.25)
    assert np.isnan(axis.fraction(np.array([-1.0]))[0])
    assert axis.ticks(10) == pytest.approx([0.01, 0.1, 1.0, 10.0, 100.0])
    linear = Axis(-1.0, 1.0)
    ticks = linear.ticks(4)
    assert ticks[0] >= -1.0 and ticks[-1] <= 1.0 and 0.0 in ticks
    with pytest.raises(PlotError, match="lo > 0"):
        Axis(0.0, 1.0, log=True)
    with pytest.raises(PlotError, match="lo < hi"):
        Axis(1.0, 1.0)


def test_render_places_points_and_the_tolerance_line() -> None:
    """A point at the middle of both axes, a dashed line at 1/3 of a log axis, labels in the margin."""
    x_axis, y_axis = Axis(0.0, 2.0), Axis(0.01, 10.0, log=True)
    lines = render_plot([Trace(np.array([1.0]), np.array([math.sqrt(0.1)]), "cyan")], 30, 11, x_axis, y_axis,
                        [HLine(0.1, "red")])
    assert len(lines) == 11 and all(len(line) <= 30 for line in lines)
    margin = max(len(t) for t in ("0.01", "0.1", "1", "10"))
    body = [line[margin + 1:] for line in lines[:-1]]
    dots = lit_dots(body)
    width, height = 2 * (30 - margin - 1), 4 * 10
    point = (round(0.5 * (width - 1)), round(0.5 * (height - 1)))
    tolerance_row = round((1 - 1 / 3) * (height - 1))
    assert point in dots
    dashed = {x for x, y in dots if y == tolerance_row}
    assert dashed == {px for px in range(width) if px % 4 < 2}  # dashes: two dots on, two off
    assert lines[-1].plain.startswith(" " * margin + "└0")
    assert any(line.plain.lstrip().startswith("10┤") for line in lines)


def test_non_finite_values_break_the_line() -> None:
    x = np.array([0.0, 1.0, 2.0, 3.0])
    y = np.array([0.0, 0.0, np.nan, 0.0])
    canvas_lines = render_plot([Trace(x, y)], 40, 5, Axis(0.0, 3.0), Axis(-1.0, 1.0))
    margin = len("-1")
    dots = lit_dots([line[margin + 1:] for line in canvas_lines[:-1]])
    width = 2 * (40 - margin - 1)
    xs = sorted(px for px, _ in dots)
    third = round((width - 1) / 3)
    # drawn from x=0 to x=1, then a lone dot at x=3: nothing between 1 and 3
    assert all(px <= third or px == width - 1 for px in xs)
    assert width - 1 in xs


def test_auto_axis_covers_data_and_included_values() -> None:
    axis = auto_axis([np.array([0.3, 7.0, np.nan, -1.0])], log=True, include=[0.05])
    assert (axis.lo, axis.hi) == (0.01, 10.0)
    lin = auto_axis(np.array([2.0, 4.0]))
    assert lin.lo < 2.0 and lin.hi > 4.0
    assert auto_axis(np.array([np.nan])) == Axis(-1.0, 1.0)


# -------------------------------------------------------------------------------------------------- model


def test_relative_error_and_durations() -> None:
    assert relative_error_percent(complex(3, 4), 0.05) == pytest.approx(1.0)
    assert math.isnan(relative_error_percent(complex(3, 4), math.nan))
    assert math.isnan(relative_error_percent(0j, 1.0))
    assert format_duration(3725) == "1:02:05" and format_duration(65.4) == "1:05" and format_duration(None) == "--"


def test_bus_rates_from_counter_differences() -> None:
    rates = BusRates(window_s=1.0)
    result = (math.nan, math.nan)
    for i in range(30):
        t = 0.1 * i
        result = rates.update(t, int(2000 * t), int(1000 * t))
    assert result == pytest.approx((2000.0, 1000.0), rel=1e-3)
    assert all(math.isnan(v) for v in BusRates().update(0.0, 5, 5))
    restarted = rates.update(3.1, 10, 10)  # counters of a new session: no negative rate
    assert all(math.isnan(v) for v in restarted)


def _state(harmonic: int, periods: int, z: complex, u: float, verdict: Verdict | None = None) -> SeriesState:
    return SeriesState("position", harmonic, periods, z, u, verdict, stop_width=u)


def _point(f: float, k: int, status: str = "converged", converged: bool = True) -> ResponsePoint:
    return ResponsePoint(f, k, "position", 0.01, 0.006, -0.008, 12, converged, status, 1e-6)


def test_sweep_model_follows_a_sweep_with_skip_and_remeasure() -> None:
    model = SweepModel(FREQS, (1, 3), ("position",))
    assert {r.state for r in model.rows.values()} == {PENDING}
    model.session_started(0.0)
    model.point_started(0, 3.0, 0.0, 0.1, "adaptive")
    assert model.rows[row_key(0, 1, "position")].state == SETTLING
    model.progress(0, 2, (_state(1, 2, 1 + 0j, 0.01), _state(3, 2, 0.1j, 0.01)), 0.5)
    assert model.rows[row_key(0, 1, "position")].state == INTEGRATING
    assert model.traces[0].rel_error == [pytest.approx(1.0)] and model.traces[1].rel_error == [pytest.approx(10.0)]
    model.point_finished(0, (_point(3.0, 1), _point(3.0, 3, "capped", False)), False, 1.0)
    assert model.rows[row_key(0, 1, "position")].state == CONVERGED
    assert model.rows[row_key(0, 3, "position")].state == "capped"
    assert model.rows[row_key(0, 1, "position")].gain_db == pytest.approx(20 * math.log10(0.01 / 0.01))
    model.point_started(1, 8.0, 1.0)
    model.point_finished(1, (), True, 1.5)
    assert model.rows[row_key(1, 3, "position")].state == SKIPPED
    model.point_started(2, 3.0, 1.5)  # a re-measure: new index, same frequency
    assert model.current == 0 and model.rows[row_key(0, 1, "position")].state == SETTLING
    model.point_finished(2, (_point(3.0, 1), _point(3.0, 3)), False, 2.0)
    assert model.done == 2
    # 20 Hz left, predicted at the 12 periods the 3 Hz point took, at the seconds per period measured: twice
    # 12 periods of 3 Hz in 1 s and 0.5 s (the session's timer knows no ramp), i.e. 1.5 s per 8 nominal s
    assert model.eta(2.0) == pytest.approx(1.5 / 8.0 * 12 / 20.0)
    model.point_started(3, 20.0, 2.0)
    model.session_ended(2.5)
    assert model.rows[row_key(2, 1, "position")].state == FAILED
    assert model.elapsed(99.0) == pytest.approx(2.5) and model.eta(3.0) is None
    with pytest.raises(ValueError, match="7 Hz"):
        model.position(7.0)


# ------------------------------------------------------------------------------------------- Pilot tests


def write_bench_config(tmp_path: Path, channel: str, *, freqs: tuple[float, ...] = FREQS, tolerance: float = 0.1,
                       simulator: bool = True, watchdog_s: float = 2.0, name: str = "bench",
                       worker: str = "thread") -> ExperimentConfig:
    """A small virtual-CAN bench config on its own channel, lockstep clock. The bus worker runs in a thread
    (quicker to start; and python-can's virtual bus lives in one process, so a recorder can only see it then);
    ``worker="auto"`` lets the UI choose (its own process)."""
    text = f"""
title = "TUI test bench"
[plant]
model = "coulomb"
mass = 2.533e-4
stiffness = 1.0
friction = 0.008
[excitation]
amplitude = 0.01
frequencies_hz = [{", ".join(repr(f) for f in freqs)}]
[analysis]
harmonics = [1, 3]
tolerance_percent = {tolerance!r}
fold_decay = 3
[bench]
transport = "can"
rate_hz = 1000
clock = "lockstep"
timebase = "counter"
worker = "{worker}"
[can]
interface = "virtual"
channel = "{channel}"
[safety]
max_amplitude = 0.02
max_rate = 5.0
watchdog_s = {watchdog_s!r}
""" + ("[simulator]\n" if simulator else "")
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return load_config(path)


def channel_name() -> str:
    return f"tui-{uuid.uuid4().hex[:10]}"


async def wait_for(pilot, predicate: Callable[[], bool], what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        await pilot.pause(0.02)


def finished(app: BodeBenchApp) -> bool:
    return app.control is not None and app.control.done.is_set() and app.sweep_screen.status.state not in (
        "starting", "running", "paused", "aborting")


class Gate:
    """Holds the session's thread inside its listener at chosen moments - the first progress event at each
    (frequency_hz, periods or more), in turn - until the test opens the gate: keys pressed meanwhile act at a
    known point of the sweep, however fast the lockstep simulation runs."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, *conditions: tuple[float, int]) -> None:
        self.conditions = list(conditions)
        self.reached = threading.Event()
        self.release = threading.Event()
        self.started: list[tuple[int, float]] = []  # (run, frequency) of every point started
        gate = self

        class GatedBridge(SessionBridge):
            def __call__(self, event: object) -> None:
                super().__call__(event)
                if isinstance(event, PointStarted):
                    gate.started.append((self.run, event.frequency_hz))
                if (gate.conditions and isinstance(event, PointProgress)
                        and event.frequency_hz == gate.conditions[0][0] and event.periods >= gate.conditions[0][1]):
                    gate.conditions.pop(0)
                    gate.release.clear()
                    gate.reached.set()
                    gate.release.wait(30.0)

        monkeypatch.setattr("bodebench.apps.tui.app.SessionBridge", GatedBridge)

    async def wait(self, pilot, what: str) -> None:
        await wait_for(pilot, self.reached.is_set, what)
        self.reached.clear()
        await pilot.pause(0.3)  # a few refreshes of the screen

    def open(self) -> None:
        self.release.set()


def states(app: BodeBenchApp, frequency_hz: float) -> set[str]:
    return {r.state for r in app.sweep_screen.record.model.rows.values() if r.frequency_hz == frequency_hz}


def footer_keys(app: BodeBenchApp) -> set[str]:
    """The keys the footer shows (it is on the first screen, under any dialog)."""
    return {key.key for key in app.screen_stack[0].query(FooterKey)}


def footer_label(app: BodeBenchApp, key: str) -> str:
    """What the footer says the key ``key`` does (empty when it is not shown)."""
    return next((str(k.description) for k in app.screen_stack[0].query(FooterKey) if k.key == key), "")


async def expect_footer(pilot, app: BodeBenchApp, keys: set[str], timeout: float = 30.0) -> None:  # type: ignore[no-untyped-def]
    """The footer comes to show exactly ``keys`` (a loaded machine may take a while to lay it out)."""
    deadline = time.monotonic() + timeout
    while footer_keys(app) != keys and time.monotonic() < deadline:
        await pilot.pause(0.05)
    assert footer_keys(app) == keys


def table_states(app: BodeBenchApp) -> list[str]:
    """The state column as the table shows it (cells addressed by row and column keys)."""
    table = app.sweep_screen.table
    return [str(table.get_cell(key, "state")) for key in app.sweep_screen.record.model.rows]


@pytest.mark.slow
@pytest.mark.asyncio
async def test_start_runs_the_sweep_and_the_screen_follows(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    gate = Gate(monkeypatch, (3.0, 4))
    config = write_bench_config(tmp_path, channel_name(), worker="auto")  # the bus worker in its own process
    out = tmp_path / "out"
    app = BodeBenchApp(config, out)
    async with app.run_test(size=(80, 24)) as pilot:
        assert app.sweep_screen.status.state == "idle" and table_states(app) == [PENDING] * 6
        await pilot.press("s")
        await gate.wait(pilot, "the first point integrating")
        assert app.sweep_screen.status.state == "running" and table_states(app)[:2] == [INTEGRATING] * 2
        convergence = app.sweep_screen.live.query_one("#convergence", PlotView).traces
        assert len(convergence) == 2 and convergence[0].x[-1] >= 4  # relative error per period, both series
        scope = app.sweep_screen.live.query_one("#scope", PlotView).traces
        assert len(scope) == 2 and scope[0].x[-1] == pytest.approx(2 / 3.0, rel=0.02)  # the last two periods
        gate.open()
        await wait_for(pilot, lambda: finished(app), "the end of the sweep")
        await pilot.pause(0.3)
        assert app.sweep_screen.status.state == "done", app.worker_errors
        assert table_states(app) == [CONVERGED] * 6
        status = app.sweep_screen.status.text_view
        assert "3/3" in status.render().plain and "DONE" in status.render().plain
        live = app.sweep_screen.live
        assert len(live.query_one("#scope", PlotView).traces) == 2  # the last point's periods stay shown
        on_disk = load_response(out)
        assert sorted((p.frequency_hz, p.harmonic) for p in on_disk.points) == sorted(
            (f, k) for f in FREQS for k in (1, 3))
        assert (out / "bode.png").exists() and (out / "periods.png").exists()
        for p in on_disk.points:  # the table shows what is on disk
            row = app.sweep_screen.record.model.rows[row_key(FREQS.index(p.frequency_hz), p.harmonic, p.channel)]
            assert str(app.sweep_screen.table.get_cell(row_key(FREQS.index(p.frequency_hz), p.harmonic, p.channel),
                                                       "gain")) == f"{p.gain_db:+.2f}"
            assert row.periods == p.periods
            cell = str(app.sweep_screen.table.get_cell(row_key(FREQS.index(p.frequency_hz), p.harmonic, p.channel),
                                                       "thd"))
            assert cell == (percent_cell(p.thd) if p.harmonic == 1 else "--")
            assert str(app.sweep_screen.table.get_cell(row_key(FREQS.index(p.frequency_hz), p.harmonic, p.channel),
                                                       "coh")) == f"{p.coherence:.3f}"
        assert len(app.sweep_screen.bode.query_one("#bode-gain", PlotView).traces) == 1
        # the summary figures under the Bode plot: those of the sidecar, on one line
        (summary,) = json.loads((out / "response.json").read_text())["summary"]
        shown = str(app.sweep_screen.bode.query_one("#bode-summary", Static).render())
        for figure in summary["figures"]:
            short = {"bandwidth (-3 dB)": "BW", "resonance peak": "peak", "phase -90 deg": "-90°",
                     "phase -180 deg": "-180°"}[figure["name"]]
            sign = "+" if short == "peak" else ""
            assert (f"{short} {figure['value']:{sign}.3g}" if figure["found"] else f"{short} --") in shown
        await pilot.press("q")
    assert app.return_value == 0


@pytest.mark.slow
@pytest.mark.asyncio
async def test_pause_skip_and_remeasure_during_a_sweep(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    gate = Gate(monkeypatch, (3.0, 1), (8.0, 1))
    config = write_bench_config(tmp_path, channel_name())
    out = tmp_path / "out"
    app = BodeBenchApp(config, out)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.press("s")
        await gate.wait(pilot, "3 Hz integrating")
        assert states(app, 3.0) == {INTEGRATING}
        await pilot.press("p")
        assert (app.sweep_screen.status.state == "paused"
                and "PAUSED" in app.sweep_screen.status.text_view.render().plain)
        gate.open()
        await pilot.pause(0.3)
        held = app.bridge.latest_progress.periods
        await pilot.pause(0.5)
        assert app.bridge.latest_progress.periods == held, "periods went on while paused"
        await pilot.press("2")  # the sweep view; the cursor is on the first row (3 Hz)
        await pilot.press("r")  # measure 3 Hz again after this point
        await pilot.press("p")
        assert app.sweep_screen.status.state == "running"
        await gate.wait(pilot, "8 Hz integrating")
        await pilot.press("p")  # 3 Hz measured: the time left is known, and stands still while paused
        eta = app.sweep_screen.record.model.eta(time.monotonic())
        await pilot.pause(0.5)
        assert eta is not None and app.sweep_screen.record.model.eta(time.monotonic()) == eta, \
            "the ETA ran down while paused"
        await pilot.press("p")
        await pilot.press("n")  # skip 8 Hz
        gate.open()
        await wait_for(pilot, lambda: finished(app), "the end of the sweep")
        assert app.sweep_screen.status.state == "done", app.worker_errors
        assert states(app, 8.0) == {SKIPPED} and states(app, 3.0) == states(app, 20.0) == {CONVERGED}
        measured = [p.frequency_hz for p in app.control.procedure.current.session.response.points]
        assert measured.count(3.0) == 4 and 8.0 not in measured  # 3 Hz twice (2 harmonics each)
        on_disk = load_response(out)
        assert sorted(p.frequency_hz for p in on_disk.points) == [3.0, 3.0, 20.0, 20.0]  # the latest 3 Hz only


@pytest.mark.slow
@pytest.mark.asyncio
async def test_abort_leaves_a_zero_setpoint_and_keeps_the_measured_points(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    gate = Gate(monkeypatch, (8.0, 2))
    channel = channel_name()
    recorder = BusRecorder(channel)
    config = write_bench_config(tmp_path, channel)
    out = tmp_path / "out"
    app = BodeBenchApp(config, out)
    try:
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("s")
            await gate.wait(pilot, "8 Hz integrating")
            await pilot.press("a")
            gate.open()
            await wait_for(pilot, lambda: finished(app), "the end of the aborted sweep")
            assert app.sweep_screen.status.state == "aborted"
            assert states(app, 3.0) == {CONVERGED} and states(app, 8.0) == {FAILED}
            assert states(app, 20.0) == {PENDING}
            assert not isinstance(app.screen, MessageDialog)  # a user abort is a notice, not an error
            ended = app.sweep_screen.record.last_ended
            assert ended is not None and ended.last_setpoint == 0.0 and ended.disabled
    finally:
        value, disabled = recorder.close()
    assert value == 0.0 and disabled
    kept = load_response(out)
    assert sorted(p.frequency_hz for p in kept.points) == [3.0, 3.0]


@pytest.mark.slow
@pytest.mark.asyncio
async def test_resume_after_an_abort_measures_only_the_missing_frequencies(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    gate = Gate(monkeypatch, (8.0, 2))
    config = write_bench_config(tmp_path, channel_name())
    out = tmp_path / "out"
    app = BodeBenchApp(config, out)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.pause(0.1)
        await expect_footer(pilot, app, {"s", "t", "o", "q"})  # nothing measured: nothing to re-measure or save
        await pilot.press("s")
        await gate.wait(pilot, "8 Hz integrating")
        await expect_footer(pilot, app, {"a", "p", "n", "r", "t", "w", "o", "q"})  # running, 3 Hz measured
        assert footer_label(app, "p") == "pause"
        await pilot.press("p")
        await wait_for(pilot, lambda: footer_label(app, "p") == "resume", "the footer offering to resume")
        await pilot.press("p")
        await wait_for(pilot, lambda: footer_label(app, "p") == "pause", "the footer offering to pause again")
        await pilot.press("a")
        gate.open()
        await wait_for(pilot, lambda: finished(app), "the end of the aborted sweep")
        assert app.sweep_screen.status.state == "aborted"
        assert app.exit_line == (f"bodebench: bench: stopped: aborted by the user; 2 points kept in {out}; "
                                 "drive left at setpoint 0, disabled")
        kept = load_response(out)
        assert sorted(p.frequency_hz for p in kept.points) == [3.0, 3.0]
        await pilot.press("s")
        assert isinstance(app.screen, ChoiceDialog)
        await pilot.pause(0.1)
        assert "(1 of 3 frequencies measured)" in str(app.screen.query_one("#dialog-text").render())
        await pilot.press("r")  # resume
        await wait_for(pilot, lambda: app.control.run == 2 and finished(app), "the resumed sweep")
        assert app.sweep_screen.status.state == "done", app.worker_errors
        assert table_states(app) == [CONVERGED] * 6  # the kept 3 Hz rows as well as the new ones
        assert app.exit_line == ""
    assert [f for run, f in gate.started if run == 1] == [3.0, 8.0]
    assert [f for run, f in gate.started if run == 2] == [8.0, 20.0]  # only what the first run lacked
    final = load_response(out)
    assert sorted((p.frequency_hz, p.harmonic) for p in final.points) == [(f, k) for f in FREQS for k in (1, 3)]
    assert [p for p in final.points if p.frequency_hz == 3.0] == list(kept.points)  # kept as they were
    assert all(p.converged for p in final.points)
    runs = sidecar_runs(out)
    assert len(runs) == 2 and runs[1]["resumed"] is True


@pytest.mark.slow
@pytest.mark.asyncio
async def test_tolerance_remeasure_after_the_sweep_save_and_overlay(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # the overlay's directories typed relative to it: a key costs a redraw
    config = write_bench_config(tmp_path, channel_name(), freqs=(8.0, 20.0))
    out = tmp_path / "out"
    other = tmp_path / "other"
    reference = lag_response(tmp_path, (8.0, 20.0))
    save_response(reference, other)
    app = BodeBenchApp(config, out)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.press("t")
        assert isinstance(app.screen, InputDialog)
        await pilot.press("ctrl+a", "ctrl+k", *"abc", "enter")
        assert isinstance(app.screen, InputDialog)  # refused, with the reason
        assert "not a number" in str(app.screen.query_one("#dialog-error").render())
        await pilot.press("ctrl+a", "ctrl+k", *"0.2", "enter")
        assert not isinstance(app.screen, InputDialog) and app.sweep_screen.tolerance_percent == 0.2
        await pilot.press("s")
        await wait_for(pilot, lambda: finished(app), "the first sweep")
        assert app.sweep_screen.status.state == "done" and app.sweep_screen.record.model.tolerance_percent == 0.2
        first = {(p.frequency_hz, p.harmonic): p for p in load_response(out).points}
        # tighter tolerance, then re-measure the selected row (20 Hz) after the sweep
        await pilot.press("t", "ctrl+a", "ctrl+k", *"0.02", "enter")
        await pilot.press("2", "down", "down", "r")
        await wait_for(pilot, lambda: app.control.run == 2 and finished(app), "the re-measure")
        assert app.sweep_screen.status.state == "done", app.worker_errors
        second = {(p.frequency_hz, p.harmonic): p for p in load_response(out).points}
        assert second.keys() == first.keys()
        assert second[(8.0, 1)] == first[(8.0, 1)]  # untouched
        redone = second[(20.0, 1)]
        assert 100 * redone.uncertainty / redone.magnitude <= 0.02  # measured again to the new tolerance
        # harmonic 3 at 50 samples a period, its folds as large as 0.02 % of it: the bound keeps it from converging
        assert CONVERGED in states(app, 20.0) and states(app, 20.0) <= {CONVERGED, ALIASED}
        # each row records the tolerance it was measured to, whatever the configuration says
        assert {p.tolerance_percent for p in first.values()} == {0.2}
        assert redone.tolerance_percent == 0.02 and second[(8.0, 1)].tolerance_percent == 0.2
        # analysed again from the samples, each frequency to the tolerance it records: the same points
        again = {(p.frequency_hz, p.harmonic): p for p in reanalyse(out).response.points}
        assert again[(20.0, 1)] == redone and again[(8.0, 1)] == second[(8.0, 1)]
        # save: the plots come back
        (out / "bode.png").unlink()
        await pilot.press("w")
        await wait_for(pilot, lambda: (out / "bode.png").exists(), "bode.png written again", timeout=30)
        # overlay another run
        await pilot.press("o")
        assert isinstance(app.screen, InputDialog)
        await pilot.press("ctrl+a", "ctrl+k", *"nowhere", "enter")
        assert "not a directory" in str(app.screen.query_one("#dialog-error").render())
        await pilot.press("ctrl+a", "ctrl+k", *other.name, "enter")
        await pilot.pause(0.1)
        assert [label for label, _ in app.sweep_screen.bode.overlays] == ["lag"]
        traces = app.sweep_screen.bode.query_one("#bode-gain", PlotView).traces
        assert len(traces) == 2 and traces[0].style != traces[1].style
        np.testing.assert_allclose(traces[1].y, reference.select(harmonic=1).gain_db)


@pytest.mark.asyncio
async def test_quit_asks_while_a_sweep_runs_then_aborts_safely(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    gate = Gate(monkeypatch, (3.0, 1))
    channel = channel_name()
    recorder = BusRecorder(channel)
    config = write_bench_config(tmp_path, channel)
    app = BodeBenchApp(config, tmp_path / "out")
    try:
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("s")
            await gate.wait(pilot, "3 Hz integrating")
            await pilot.press("q")
            assert isinstance(app.screen, ConfirmDialog)
            await pilot.press("n")
            assert not isinstance(app.screen, ConfirmDialog) and app.running
            await pilot.press("q")
            await pilot.press("y")
            gate.open()
            await wait_for(pilot, lambda: not app.is_running, "the app to exit")
    finally:
        value, disabled = recorder.close()
    assert app.control.done.is_set()
    assert value == 0.0 and disabled


@pytest.mark.asyncio
async def test_q_in_the_quit_dialog_aborts_quits_and_says_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    gate = Gate(monkeypatch, (3.0, 1))
    channel = channel_name()
    recorder = BusRecorder(channel)
    config = write_bench_config(tmp_path, channel)
    app = BodeBenchApp(config, tmp_path / "out")
    try:
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("s")
            await gate.wait(pilot, "3 Hz integrating")
            await pilot.press("q")
            assert isinstance(app.screen, ConfirmDialog)
            await pilot.pause(0.1)
            await expect_footer(pilot, app, {"a", "q"})  # under the question: abort, and quit (= yes)
            await pilot.press("q")
            gate.open()
            await wait_for(pilot, lambda: not app.is_running, "the app to exit")
    finally:
        value, disabled = recorder.close()
    assert app.control.done.is_set()
    assert value == 0.0 and disabled
    assert app.return_value == 1
    assert app.exit_line == ("bodebench: bench: stopped: aborted by the user (quit); no point measured; "
                             "drive left at setpoint 0, disabled")


@pytest.mark.asyncio
async def test_a_fault_is_explained_in_a_dialog(tmp_path: Path) -> None:
    """No drive on the bus: the watchdog trips; the dialog says so and what was kept; the bus ends at zero."""
    channel = channel_name()
    recorder = BusRecorder(channel)
    config = write_bench_config(tmp_path, channel, simulator=False, watchdog_s=0.3)
    app = BodeBenchApp(config, tmp_path / "out")
    try:
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("s")
            await wait_for(pilot, lambda: finished(app), "the watchdog trip")
            await pilot.pause(0.1)
            assert app.sweep_screen.status.state == "failed" and isinstance(app.screen, MessageDialog)
            text = str(app.screen.query_one("#dialog-text").render())
            assert "watchdog" in text and "0 measured points kept" in text and "setpoint 0" in text
            await pilot.press("enter")
            await pilot.press("4")
            assert "TRIPPED" in str(app.sweep_screen.bus.render())
    finally:
        value, disabled = recorder.close()
    assert value == 0.0 and disabled


@pytest.mark.asyncio
@pytest.mark.parametrize("size,shown", [((80, 24), 1), ((160, 45), 4)])
async def test_layout_degrades_to_one_view_at_80x24(tmp_path: Path, size: tuple[int, int], shown: int) -> None:
    config = write_bench_config(tmp_path, channel_name())
    app = BodeBenchApp(config, tmp_path / "out")
    async with app.run_test(size=size) as pilot:
        await pilot.pause(0.1)
        panels = app.sweep_screen.views.panels().values()
        visible = [p for p in panels if p.display and p.region.width > 0 and p.region.height > 0]
        assert len(visible) == shown
        for panel in visible:
            assert panel.region.right <= size[0] and panel.region.bottom <= size[1] - 1  # above the footer
        if shown == 1:
            await pilot.press("3")
            assert [p.id for p in panels if p.display and p.region.height > 0] == ["bode"]


# ---------------------------------------------------------------------------------------------- snapshots

SNAP_FREQS = (3.0, 8.0, 20.0)
LAG_TIME_CONSTANT_S = 0.01


def lag_response(tmp_path: Path, freqs: tuple[float, ...], case: str = "lag") -> FrequencyResponse:
    """Points of G = 1 / (1 + j w T) (harmonic 3 at 1 % of it), as a finished sweep would hold them."""
    points = []
    for f in freqs:
        g = 1.0 / (1.0 + 1j * 2 * math.pi * f * LAG_TIME_CONSTANT_S)
        for k, scale in ((1, 1.0), (3, 0.01)):
            z = 0.01 * g * scale
            points.append(ResponsePoint(f, k, "position", 0.01, z.real, z.imag, 10 * k, True, "converged", 1e-7))
    return FrequencyResponse(points, config={"title": "lag"}, case=case)


def loaded_app(tmp_path: Path) -> BodeBenchApp:
    config = write_bench_config(tmp_path, "tui-snapshot", freqs=SNAP_FREQS)
    save_response(lag_response(tmp_path, SNAP_FREQS, case="bench"), tmp_path / "out")
    return BodeBenchApp(config, tmp_path / "out")


def test_a_finished_sweep_is_loaded_from_its_results_directory(tmp_path: Path) -> None:
    async def check() -> None:
        app = loaded_app(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.pause(0.1)
            assert app.sweep_screen.status.state == "loaded" and table_states(app) == [CONVERGED] * 6
            for i, f in enumerate(SNAP_FREQS):
                gain_db = 20 * math.log10(abs(1 / (1 + 1j * 2 * math.pi * f * LAG_TIME_CONSTANT_S)))
                phase = math.degrees(cmath.phase(1 / (1 + 1j * 2 * math.pi * f * LAG_TIME_CONSTANT_S)))
                assert str(app.sweep_screen.table.get_cell(row_key(i, 1, "position"), "gain")) == f"{gain_db:+.2f}"
                assert str(app.sweep_screen.table.get_cell(row_key(i, 1, "position"), "phase")) == f"{phase:.1f}"
            await expect_footer(pilot, app, {"s", "r", "t", "w", "o", "q"})  # no sweep runs: nothing to abort or pause
            await pilot.press("s")  # a new sweep would replace these results: asked first
            assert isinstance(app.screen, ChoiceDialog) and app.control is None
            await pilot.pause(0.1)
            text = str(app.screen.query_one("#dialog-text").render())
            assert "made with another configuration" in text and "cannot be resumed" in text  # not this config's
            await expect_footer(pilot, app, {"q"})  # under the dialog only q works
            await pilot.press("r")  # no resume offered: nothing happens
            assert isinstance(app.screen, ChoiceDialog) and app.control is None
            await pilot.press("c")
            assert app.control is None and app.sweep_screen.status.state == "loaded"
            assert not isinstance(app.screen, ChoiceDialog)
            await pilot.pause(0.1)
            await expect_footer(pilot, app, {"s", "r", "t", "w", "o", "q"})
            await pilot.press("s")
            await pilot.press("q")  # quits from the dialog: nothing runs
            await wait_for(pilot, lambda: not app.is_running, "the app to exit")
        assert app.return_value == 0 and app.control is None and app.exit_line == ""

    asyncio.run(check())


def test_a_point_not_converged_for_a_stated_reason_shows_that_reason(tmp_path: Path) -> None:
    """Each way a point ends unconverged is shown as itself: a disturbed or untied point is not a failure of the
    sweep, and the engineer needs to know which remedy applies (move the frequency, tie the phase)."""
    config = write_bench_config(tmp_path, "tui-status", freqs=SNAP_FREQS)
    reasons = ("capped", "noise_limited", "disturbed", "untied", "below_resolution", "converged")
    shown = {"capped": CAPPED, "noise_limited": NOISE_LIMITED, "disturbed": DISTURBED, "untied": UNTIED,
             "below_resolution": CONVERGED, "converged": CONVERGED}
    points = [dataclasses.replace(point, status=reasons[i % len(reasons)],
                                  converged=reasons[i % len(reasons)] in ("converged", "below_resolution"))
              for i, point in enumerate(lag_response(tmp_path, SNAP_FREQS).points)]
    save_response(FrequencyResponse(points, config={"title": "lag"}, case="bench"), tmp_path / "out")

    async def check() -> None:
        app = BodeBenchApp(config, tmp_path / "out")
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.pause(0.1)
            assert table_states(app) == [shown[point.status] for point in points]

    asyncio.run(check())


def test_under_an_input_dialog_keys_are_typed_and_ctrl_q_quits(tmp_path: Path) -> None:
    async def check() -> None:
        app = BodeBenchApp(write_bench_config(tmp_path, channel_name()), tmp_path / "out")
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("o")
            assert isinstance(app.screen, InputDialog)
            await pilot.pause(0.1)
            await expect_footer(pilot, app, set())  # q and a would be typed here: not shown
            await pilot.press("ctrl+a", "ctrl+k", "q", "a")
            assert isinstance(app.screen, InputDialog) and app.screen.query_one("#dialog-input").value == "qa"
            await pilot.press("ctrl+q")
            await wait_for(pilot, lambda: not app.is_running, "the app to exit")
        assert app.return_value == 0 and app.exit_line == ""

    asyncio.run(check())


@pytest.mark.parametrize("size,keys", [((80, 24), ("2",)), ((160, 48), ()), ((160, 45), ())])
def test_every_column_of_the_sweep_table_fits_its_panel(tmp_path: Path, size: tuple[int, int],
                                                        keys: tuple[str, ...]) -> None:
    """The table is no wider than its panel (no horizontal scroll bar drawn over its rows, no column cut)."""
    async def check() -> None:
        app = loaded_app(tmp_path)
        async with app.run_test(size=size) as pilot:
            await pilot.pause(0.1)
            for key in keys:
                await pilot.press(key)
            await pilot.pause(0.1)
            table = app.sweep_screen.table
            assert 0 < table.virtual_size.width <= table.scrollable_content_region.width
            assert not table.show_horizontal_scrollbar

    asyncio.run(check())


@pytest.mark.parametrize("size,keys", [((80, 24), ("2",)), ((80, 24), ("3",)), ((160, 45), ())],
                         ids=["sweep-80x24", "bode-80x24", "all-160x45"])
def test_snapshots_of_the_main_screens(snap_compare, tmp_path: Path, size: tuple[int, int],
                                       keys: tuple[str, ...]) -> None:
    assert snap_compare(loaded_app(tmp_path), press=keys, terminal_size=size)


# -------------------------------------------------------------------------------------------- the command


class TmuxTui:
    """``bodebench tui CONFIG --out OUT`` in a real terminal: a tmux session of its own (``width`` columns), read
    off its screen; ``EXIT=<status>`` is printed when the command ends."""

    def __init__(self, config: Path, out: Path, width: int) -> None:
        tmux = shutil.which("tmux")
        assert tmux is not None, "tmux is needed (apt-get install tmux)"
        script = Path(sys.executable).parent / "bodebench"
        command = str(script) if script.exists() else shutil.which("bodebench")
        assert command, "the bodebench command is not installed (pip install -e .)"
        self.base = [tmux, "-L", f"bodebench-test-{uuid.uuid4().hex[:8]}"]
        shell = f"cd {ROOT} && {command} tui {config} --out {out}; echo EXIT=$?; sleep 60"
        subprocess.run([*self.base, "new-session", "-d", "-s", "tui", "-x", str(width), "-y", "30", shell],
                       check=True, env={**os.environ, "TERM": "xterm-256color"})

    def screen(self) -> str:
        return subprocess.run([*self.base, "capture-pane", "-p", "-J", "-t", "tui"], capture_output=True, text=True,
                              check=True).stdout

    def wait(self, text: str, timeout: float) -> str:
        """The screen once it shows ``text``; AssertionError with the screen after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while True:
            shown = self.screen()
            if text in shown:
                return shown
            if time.monotonic() > deadline:
                raise AssertionError(f"{text!r} not on screen after {timeout:g} s:\n{shown}")
            time.sleep(0.2)

    def press(self, key: str) -> None:
        subprocess.run([*self.base, "send-keys", "-t", "tui", key], check=True)

    def close(self) -> None:
        subprocess.run([*self.base, "kill-server"], capture_output=True)


@pytest.mark.slow
def test_the_command_in_tmux(tmp_path: Path) -> None:
    config = write_bench_config(tmp_path, channel_name(), worker="auto")
    out = tmp_path / "results"
    tui = TmuxTui(config.path, out, 100)
    try:
        tui.wait("IDLE", 30)
        tui.press("s")
        shown = tui.wait("DONE", 60)
        assert "3/3" in shown
        tui.press("q")
        tui.wait("EXIT=0", 30)
    finally:
        tui.close()
    response = load_response(out)
    assert len(response.points) == 6 and all(p.converged for p in response.points)
    assert (out / "bode.png").exists()


@pytest.mark.slow
def test_abort_and_quit_in_tmux_prints_what_happened(tmp_path: Path) -> None:
    """The real command: q while a sweep runs, q again to confirm; the terminal gets one line saying what was
    kept where and how the drive was left, and the exit status is 1."""
    # a sweep long enough to be running when the keys arrive: many frequencies to a tight tolerance
    config = write_bench_config(tmp_path, channel_name(), freqs=tuple(float(f) for f in range(2, 40)),
                                tolerance=0.002)
    out = tmp_path / "results"
    tui = TmuxTui(config.path, out, 200)
    try:
        tui.wait("IDLE", 30)
        tui.press("s")
        tui.wait("RUNNING", 60)
        tui.press("q")
        tui.wait("Abort and quit", 30)
        tui.press("q")
        shown = tui.wait("EXIT=", 90)
    finally:
        tui.close()
    assert "EXIT=1" in shown, shown
    [line] = [text for text in shown.splitlines() if text.startswith("bodebench: ")]
    kept = load_response(out).points if (out / "response.csv").exists() else []
    where = f"{len(kept)} points kept in {out}" if kept else "no point measured"
    assert line == f"bodebench: bench: stopped: aborted by the user (quit); {where}; drive left at setpoint 0, " \
                   "disabled", shown


@pytest.mark.asyncio
async def test_sigterm_aborts_the_sweep_safely_and_quits(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A real SIGTERM to this process (what systemd or a closed SSH session sends, SIGHUP alike) while a sweep
    runs: the UI aborts it, the bus shows a zero setpoint and the disable frame, the app exits with 128 + 15."""
    import signal

    gate = Gate(monkeypatch, (3.0, 1))
    channel = channel_name()
    recorder = BusRecorder(channel)
    config = write_bench_config(tmp_path, channel)
    app = BodeBenchApp(config, tmp_path / "out")
    try:
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("s")
            await gate.wait(pilot, "3 Hz integrating")
            os.kill(os.getpid(), signal.SIGTERM)
            gate.open()
            await wait_for(pilot, lambda: not app.is_running, "the app to exit")
    finally:
        value, disabled = recorder.close()
    assert app.stopped_by == "SIGTERM" and app.return_value == 128 + signal.SIGTERM
    assert app.control.done.is_set()
    assert value == 0.0 and disabled


@pytest.mark.slow
@pytest.mark.asyncio
async def test_a_loop_sweep_fills_its_rows_named_by_the_mode(tmp_path: Path) -> None:
    """configs/sim_loop.toml measured as the loop gain in the UI: the table's rows are the mode's ("loop"), each
    ends converged, and the scope names the channel it shows (the effort)."""
    text = (Path(__file__).resolve().parent.parent / "configs" / "sim_loop.toml").read_text()
    text = text.replace("frequencies_hz = [1, 2, 3, 5, 7, 10, 14, 17, 20, 30, 50, 70]", "frequencies_hz = [10, 20]")
    text = text.replace('channel = "bodebench-loop"', f'channel = "{channel_name()}"')
    path = tmp_path / "loop.toml"
    path.write_text(text)
    app = BodeBenchApp(load_config(path), tmp_path / "out")
    async with app.run_test(size=(160, 48)) as pilot:
        assert [key.split(":")[2] for key in app.sweep_screen.record.model.rows] == ["loop", "loop"]
        await pilot.press("s")
        await wait_for(pilot, lambda: finished(app), "the end of the sweep")
        await pilot.pause(0.3)
        assert app.sweep_screen.status.state == "done", app.worker_errors
        assert table_states(app) == [CONVERGED] * 2
        assert "effort" in app.sweep_screen.live.query_one("#scope", PlotView).legend.plain


def lockstep_bench(max_amplitude: float) -> str:
    """The tables of a simulated drive on a virtual CAN bus of its own, 1 kHz lockstep, as TOML."""
    return f"""[bench]
transport = "can"
rate_hz = 1000
clock = "lockstep"
[can]
interface = "virtual"
channel = "{channel_name()}"
[safety]
max_amplitude = {max_amplitude!r}
watchdog_s = 5.0
[simulator]
"""


class StatusRecorder(StatusLine):
    """The status line, keeping every line it shows."""

    shown: list[str]

    def show(self, case_name: str, model: SweepModel, tolerance_percent: float, running: bool, now: float) -> bool:
        changed = super().show(case_name, model, tolerance_percent, running, now)
        self.__dict__.setdefault("shown", []).append(self.text_view.render().plain)
        return changed


@pytest.mark.slow
@pytest.mark.asyncio
async def test_the_overview_an_adaptive_plan_runs_first_shows_its_periods_in_the_status(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """from_overview, on the virtual bus: while the multisine runs the status line counts its periods, one more
    each time; once the points start it says so no more, and the rows the overview called for are in the table."""
    path = tmp_path / "seeded.toml"
    path.write_text(f"""
title = "overview first"
[plant]
model = "linear"
mass = {1 / (2 * math.pi * 7.3) ** 2!r}
stiffness = 1.0
damping_ratio = 0.03
[excitation]
amplitude = 0.01
[excitation.frequencies]
start_hz = 3
stop_hz = 30
per_decade = 2
[excitation.frequencies.adaptive]
figures = ["resonance"]
max_points = 7
from_overview = true
[analysis]
harmonics = [1]
tolerance_percent = 0.1
[overview]
start_hz = 3
stop_hz = 30
amplitude = 0.02
lines_per_decade = 6
tolerance_percent = 1
{lockstep_bench(0.03)}""")
    monkeypatch.setattr("bodebench.apps.tui.screen.StatusLine", StatusRecorder)
    app = BodeBenchApp(load_config(path), tmp_path / "out")
    status = app.sweep_screen.status
    assert isinstance(status, StatusRecorder)
    async with app.run_test(size=(160, 48)) as pilot:
        await pilot.press("s")
        await wait_for(pilot, lambda: finished(app), "the end of the sweep", timeout=300.0)
        await pilot.pause(0.3)
        assert app.sweep_screen.status.state == "done", app.worker_errors
    told = [int(line.split("overview first: ")[1].split()[0]) for line in status.shown if "overview first: " in line]
    assert told and told == sorted(told) and told[-1] > told[0]
    last = max(i for i, line in enumerate(status.shown) if "overview first: " in line)
    assert all("overview first" not in line for line in status.shown[last + 1:])
    assert "overview first" not in app.sweep_screen.status.text_view.render().plain
    on_disk = sorted(p.frequency_hz for p in load_response(tmp_path / "out").points)
    assert any(6.5 < f < 8.0 for f in on_disk) and len(app.sweep_screen.record.model.rows) == len(on_disk)


@pytest.mark.slow
@pytest.mark.asyncio
async def test_an_adaptive_plan_grows_in_the_table(tmp_path: Path) -> None:
    """A lightly damped oscillator on the virtual bus with an adaptive plan of two points a decade: the rows of
    the frequencies the plan adds appear in the table, in ascending frequency among the planned ones, and every
    row ends as the point on disk says."""
    path = tmp_path / "adaptive.toml"
    path.write_text(f"""
title = "adaptive plan in the UI"
[plant]
model = "linear"
mass = {1 / (2 * math.pi * 6.3) ** 2!r}
stiffness = 1.0
damping_ratio = 0.1
[excitation]
amplitude = 0.01
frequencies = {{ start_hz = 3, stop_hz = 30, per_decade = 2, adaptive = {{ figures = ["resonance"], max_points = 8 }} }}
[analysis]
harmonics = [1]
tolerance_percent = 0.1
{lockstep_bench(0.02)}""")
    out = tmp_path / "out"
    app = BodeBenchApp(load_config(path), out)
    async with app.run_test(size=(160, 48)) as pilot:
        assert len(app.sweep_screen.record.model.rows) == 3
        await pilot.press("s")
        await wait_for(pilot, lambda: finished(app), "the end of the sweep", timeout=600.0)
        await pilot.pause(0.3)
        assert app.sweep_screen.status.state == "done", app.worker_errors
        on_disk = sorted(p.frequency_hz for p in load_response(out).points)
        assert 3 < len(on_disk) <= 8
        table = app.sweep_screen.table
        shown = [float(str(table.get_cell(row.key.value, "f"))) for row in table.ordered_rows]
        assert shown == pytest.approx(on_disk, rel=1e-5)
        assert table_states(app) == [CONVERGED] * len(on_disk)
        assert f"{len(on_disk)}/{len(on_disk)}" in app.sweep_screen.status.text_view.render().plain
