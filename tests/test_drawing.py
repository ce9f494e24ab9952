"""The process that draws an offline sweep's figures: a pool of forks of one process that imported the plotting
modules. Figures drawn there are the figures drawn here; two are drawn at once; an error, a figure process that
dies, a stop signal and a shutdown each end as a user would expect."""

from __future__ import annotations

import os
import signal
import sys
import time
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np
import pytest

from bodebench.apps.plots import DRAWING_MODULES, write_plots
from bodebench.bench.drawing import DRAWING_PROCESSES, ForkingDrawer, drawing_executor
from bodebench.core.response import FrequencyResponse, ResponsePoint

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="processes forked")


def _response() -> FrequencyResponse:
    """A first-order lag's first two harmonics at six frequencies, as a sweep writes them."""
    points = []
    for f in np.geomspace(0.5, 50.0, 6):
        z = 1.0 / (1.0 + 1j * f / 5.0)
        for k in (1, 2):
            c = z if k == 1 else 0.01 * z
            points.append(ResponsePoint(frequency_hz=float(f), harmonic=k, channel="y", amplitude=1.0, p=c.real,
                                        q=c.imag, periods=40 + k, converged=True, status="converged",
                                        uncertainty=1e-4, uncertainty_1d=8e-5, within_eps=True))
    return FrequencyResponse(points, config={"analysis": {"response": "system"}}, case="lag")


def _meet(directory: str, name: str, others: int, timeout_s: float) -> int:
    """Leave a file ``name`` in ``directory`` and wait until ``others`` more are there: returns this process's pid;
    TimeoutError if they never come (the calls were not run at once)."""
    Path(directory, name).write_text(str(os.getpid()))
    deadline = time.monotonic() + timeout_s
    while len(list(Path(directory).iterdir())) < others + 1:
        if time.monotonic() > deadline:
            raise TimeoutError(f"{name}: alone after {timeout_s} s")
        time.sleep(0.01)
    return os.getpid()


def _modules_loaded(names: tuple[str, ...]) -> list[bool]:
    return [name in sys.modules for name in names]


def _fail(message: str) -> None:
    raise ValueError(message)


def _die(code: int) -> None:
    os._exit(code)


def _sleep_then(seconds: float, value: int) -> int:
    time.sleep(seconds)
    return value


def test_the_figures_drawn_there_are_the_figures_drawn_here(tmp_path: Path) -> None:
    response = _response()
    here = write_plots(response, tmp_path / "here", "lag")
    with drawing_executor(DRAWING_MODULES) as drawer:
        assert isinstance(drawer, ForkingDrawer)
        futures = [drawer.submit(write_plots, response, tmp_path / "there", "lag", figures=(figure,))
                   for figure in ("bode", "periods")]
        there = [path for future in futures for path in future.result(timeout=120)]
    assert [p.name for p in there] == [p.name for p in here] == ["bode.png", "periods.png"]
    for a, b in zip(here, there, strict=True):
        assert b.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert a.read_bytes() == b.read_bytes()  # the same figure, pixel for pixel


def test_calls_run_side_by_side_in_processes_that_imported_the_modules(tmp_path: Path) -> None:
    drawer = ForkingDrawer(("json", "colorsys"))
    try:
        meeting = tmp_path / "meeting"
        meeting.mkdir()
        futures = [drawer.submit(_meet, str(meeting), f"call{i}", DRAWING_PROCESSES - 1, 60.0)
                   for i in range(DRAWING_PROCESSES)]
        pids = {future.result(timeout=120) for future in futures}
        assert len(pids) == DRAWING_PROCESSES and os.getpid() not in pids
        assert drawer.submit(_modules_loaded, ("json", "colorsys")).result(timeout=60) == [True, True]
    finally:
        drawer.shutdown()


def test_an_error_reaches_the_caller_and_the_drawer_goes_on(tmp_path: Path) -> None:
    with drawing_executor(()) as drawer:
        failed = drawer.submit(_fail, "no such figure")
        with pytest.raises(ValueError, match="no such figure"):
            failed.result(timeout=60)
        assert drawer.submit(_sleep_then, 0.0, 7).result(timeout=60) == 7


def test_a_figure_process_that_dies_fails_its_figure_and_nothing_waits_for_ever() -> None:
    drawer = ForkingDrawer(())
    try:
        died = drawer.submit(_die, 3)
        with pytest.raises(BrokenProcessPool, match="terminated abruptly"):
            died.result(timeout=60)
        later = drawer.submit(_sleep_then, 0.0, 1)
        with pytest.raises(BrokenProcessPool):  # the pool is broken: later figures fail at once rather than hang
            later.result(timeout=60)
    finally:
        drawer.shutdown()
    assert not drawer._process.is_alive()


def test_shutdown_draws_what_is_queued_and_no_call_is_taken_after_it() -> None:
    drawer = ForkingDrawer(())
    futures = [drawer.submit(_sleep_then, 0.2, i) for i in range(2 * DRAWING_PROCESSES)]
    drawer.shutdown(wait=True)
    assert all(future.done() for future in futures)
    assert [future.result() for future in futures] == list(range(2 * DRAWING_PROCESSES))
    with pytest.raises(RuntimeError, match="shut down"):
        drawer.submit(_sleep_then, 0.0, 0)


def test_an_argument_that_cannot_be_sent_fails_its_future_only() -> None:
    with drawing_executor(()) as drawer:
        unsendable = drawer.submit(_sleep_then, 0.0, lambda: 0)  # a lambda does not pickle
        with pytest.raises(Exception, match="pickle|lambda"):
            unsendable.result(timeout=60)
        assert drawer.submit(_sleep_then, 0.0, 2).result(timeout=60) == 2


@pytest.mark.skipif(not hasattr(signal, "SIGINT"), reason="POSIX signals")
def test_the_drawing_process_leaves_a_stop_signal_to_the_command() -> None:
    """Ctrl-C reaches the whole foreground group: the drawing process and its pool finish the figure they draw;
    the command ends them once it has said what it kept."""
    drawer = ForkingDrawer(())
    try:
        slow = drawer.submit(_sleep_then, 1.0, 5)
        time.sleep(0.3)
        assert drawer._process.pid is not None
        os.kill(drawer._process.pid, signal.SIGINT)
        assert slow.result(timeout=60) == 5
    finally:
        drawer.shutdown()
    assert drawer._process.exitcode == 0
