"""Every way a sweep ends leaves the drive at zero and disabled where the bus still carries frames, and says what
was actually sent: read off a real python-can virtual bus and a real pty whose far end dies."""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from pathlib import Path

import pytest
from helpers import BusRecorder
from test_bench_e2e import SERIAL_FRAMES, config

from bodebench.bench.connection import plan_link
from bodebench.bench.events import PointProgress, SessionError
from bodebench.bench.session import BenchSession
from bodebench.bench.worker import Credit, MessagePipe, Stopped
from bodebench.io.config import parse_config
from bodebench.io.results import load_response


def _session(data: dict, out: Path | None, trigger) -> BenchSession:  # type: ignore[no-untyped-def]
    """A session whose listener calls ``trigger(session)`` once, two periods into the second point."""
    holder: dict[str, BenchSession] = {}
    fired: list[bool] = []

    def listener(event: object) -> None:
        if isinstance(event, PointProgress) and event.index == 1 and event.periods >= 2 and not fired:
            fired.append(True)
            trigger(holder["s"])

    case = parse_config(data, "exit.toml").cases[0]
    session = holder["s"] = BenchSession(case, plan_link(case), out, listener)
    return session


@pytest.mark.slow
def test_an_exception_in_the_session_zeroes_and_disables_and_is_not_called_complete(tmp_path: Path) -> None:
    recorder = BusRecorder("exit-listener")

    def fail(session: BenchSession) -> None:
        raise RuntimeError("display crashed")

    session = _session(config(can={"channel": "exit-listener"}), tmp_path, fail)
    with pytest.raises(RuntimeError, match="display crashed"):
        session.run()
    value, disabled = recorder.close()
    assert value == 0.0 and disabled
    ended = session.ended
    assert ended is not None and not ended.completed
    assert ended.reason == "error: RuntimeError: display crashed"
    assert ended.drive_state() == "drive left at setpoint 0, disabled"
    assert [p.frequency_hz for p in load_response(tmp_path).points] == [5.0, 5.0]


def _malformed_command(session: BenchSession) -> None:
    pipe = session._worker.pipe
    assert pipe is not None
    pipe.send(Credit(None))  # type: ignore[arg-type]  # the worker fails on it, zeroes, ends


def _command_after_the_worker_ended(session: BenchSession) -> None:
    _malformed_command(session)
    for thread in threading.enumerate():
        if thread.name == "bodebench-bus":
            thread.join(timeout=30)
    session._worker.send(Credit(10**9))  # finds the pipe closed


@pytest.mark.parametrize("trigger", [_malformed_command, _command_after_the_worker_ended])
def test_an_exception_in_the_bus_worker_zeroes_and_disables(trigger) -> None:  # type: ignore[no-untyped-def]
    """A malformed command reaches the worker (a TypeError inside its loop): it zeroes and disables, then ends.
    Whether the session hears of it at its next batch, or first sends another command into the closed pipe (the
    worker ended between a batch and the session's next credit), it reports the worker's fault, not the pipe."""
    channel = f"exit-{trigger.__name__.strip('_')}"
    recorder = BusRecorder(channel)
    session = _session(config(can={"channel": channel}), None, trigger)
    with pytest.raises(SessionError, match="TypeError"):
        session.run()
    value, disabled = recorder.close()
    assert value == 0.0 and disabled
    assert session.ended is not None and session.ended.drive_state() == "drive left at setpoint 0, disabled"


def test_a_worker_that_ended_with_only_its_report_still_says_how_it_left_the_drive() -> None:
    """The worker's report (Stopped) reaches the pipe without a fault before it, and the worker ends: the command
    that finds the pipe closed reads the report, and the shutdown still returns it (the drive's state is known)."""
    session = _session(config(can={"channel": "exit-report"}), None, lambda s: None)
    ours, theirs = multiprocessing.get_context("spawn").Pipe(duplex=True)
    report = Stopped("drive: quick stop", 0.0, True, zero_sent=True, frames_out=42)
    theirs.send(report)
    theirs.close()
    session._worker.pipe = MessagePipe(ours)
    with pytest.raises(SessionError, match="the bus worker stopped: drive: quick stop"):
        session._worker.send(Credit(10))
    assert session._worker.shutdown("test", abort=True) == report


@pytest.mark.slow
def test_a_serial_drive_that_dies_is_reported_as_not_zeroed_with_its_watchdog() -> None:
    """The drive's process is killed mid-sweep: its end of the pty is gone, so no zero setpoint can reach it. The
    session says so, with the last setpoint that did go out and what the drive's own watchdog does."""
    frames = {**SERIAL_FRAMES, "heartbeat": {"id": 0x20, "data": [5], "period_s": 0.1}, "drive_watchdog_s": 0.5}
    data = config(bench={"transport": "serial"}, can=None, serial={"framing": "binary"}, frames=frames)

    def kill_drive(session: BenchSession) -> None:
        os.kill(session.plan.resources[0].process.pid, signal.SIGKILL)

    session = _session(data, None, kill_drive)
    with pytest.raises(SessionError, match="bus"):
        session.run()
    ended = session.ended
    assert ended is not None and not ended.zero_sent and not ended.disabled and ended.frames_out > 0
    text = ended.drive_state()
    assert text.startswith("could not send the zero setpoint: the last setpoint that went out was ")
    assert "no disable frame sent" in text
    assert "the drive's watchdog zeroes and disables it 0.5 s after the last frame" in text


def test_a_port_that_does_not_exist_sends_nothing_and_says_so(tmp_path: Path) -> None:
    data = config(bench={"transport": "serial"}, can=None, simulator=None, frames=SERIAL_FRAMES,
                  serial={"framing": "binary", "port": str(tmp_path / "no-such-tty")})
    case = parse_config(data, "exit.toml").cases[0]
    session = BenchSession(case, plan_link(case), tmp_path / "out")
    with pytest.raises(SessionError, match="cannot open serial port"):
        session.run()
    assert session.ended is not None and session.ended.drive_state() == "nothing was sent to the drive"
    assert not (tmp_path / "out").exists()
