"""A stop signal ends a sweep through its safe shutdown, and never tears a message between the session and the bus
worker: a message cut half-way leaves every later one unreadable, the worker's report of how it left the drive
among them."""

from __future__ import annotations

import math
import os
import pickle
import signal
import struct
import threading
import time
from multiprocessing import Pipe
from pathlib import Path

import pytest

from bodebench.bench.worker import MessagePipe
from bodebench.core.response import ResponsePoint
from bodebench.drivers.stop_signals import StopSignal, signals_held, stop_on_signals
from bodebench.io.results import ResultsWriter, load_response

PIECES = 40
PIECE_BYTES = 1 << 16
PIECE_PAUSE_S = 0.01


def _slow_writer(fd: int, payload: bytes, after: bytes, interrupt_after: int = -1) -> None:
    """Write one message the way Connection.send frames it (a 4-byte big-endian length, then the pickle), in pieces
    with pauses, so that its reader is half-way through it for a while; then a whole second message. After
    ``interrupt_after`` pieces (if >= 0) it sends SIGINT to this process: the message is then surely incomplete,
    however busy the machine."""
    try:
        os.write(fd, struct.pack("!i", len(payload)))
        for piece, i in enumerate(range(0, len(payload), PIECE_BYTES)):
            if piece == interrupt_after:
                os.kill(os.getpid(), signal.SIGINT)
            os.write(fd, payload[i:i + PIECE_BYTES])
            time.sleep(PIECE_PAUSE_S)
        os.write(fd, struct.pack("!i", len(after)) + after)
    except BrokenPipeError:  # a torn stream's reader gave up and closed its end
        pass


def _interrupt_mid_message(held: bool) -> tuple[object, list[object]]:
    """SIGINT to this process while a long message is being read, through a MessagePipe (``held``) or a bare
    Connection; (what the read returned or raised, what the next two reads returned or raised: byte strings by
    their length)."""
    ours, theirs = Pipe(duplex=True)
    big = pickle.dumps(bytes(PIECES * PIECE_BYTES - 100))
    second = pickle.dumps("stopped: drive left at setpoint 0, disabled")
    writer = threading.Thread(target=_slow_writer, args=(theirs.fileno(), big, second, PIECES // 4), daemon=True)
    conn = MessagePipe(ours) if held else ours

    def read() -> object:
        got = conn.recv()
        return len(got) if isinstance(got, bytes) else got

    first: object
    with stop_on_signals():
        writer.start()
        try:
            first = read()
        except StopSignal as exc:
            first = exc
        # the signal is raised once: the safe shutdown's own reads go on
        following: list[object] = []
        while len(following) < 2 and conn.poll(5.0):
            try:
                following.append(read())
            except Exception as exc:  # noqa: BLE001 - what a torn stream gives
                following.append(exc)
                break
    ours.close()
    writer.join(5.0)
    theirs.close()
    return first, following


@pytest.mark.skipif(not hasattr(signal, "SIGINT") or os.name != "posix", reason="POSIX signals")
def test_a_stop_signal_waits_for_the_message_under_way_and_nothing_is_lost() -> None:
    first, following = _interrupt_mid_message(held=True)
    assert isinstance(first, StopSignal) and first.signame == "SIGINT"  # raised once the whole message was read
    # the message the signal interrupted is read next, whole, and then the one after it
    assert following == [PIECES * PIECE_BYTES - 100, "stopped: drive left at setpoint 0, disabled"]


@pytest.mark.skipif(not hasattr(signal, "SIGINT") or os.name != "posix", reason="POSIX signals")
def test_without_holding_the_signal_the_stream_is_torn() -> None:
    """The failure the held signal prevents, shown on a bare Connection: what follows is not the next message."""
    first, following = _interrupt_mid_message(held=False)
    assert isinstance(first, StopSignal)
    assert "stopped: drive left at setpoint 0, disabled" not in following


def test_signals_held_raises_once_at_the_end_of_the_block() -> None:
    done = []
    with stop_on_signals() as handler:
        with pytest.raises(StopSignal, match="SIGTERM"), signals_held():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)  # the handler runs here: the signal is held, not raised
            done.append("inside")
            with signals_held():  # nested: the outermost block raises
                os.kill(os.getpid(), signal.SIGHUP)
                time.sleep(0.05)
            done.append("after nested")
        assert done == ["inside", "after nested"]
        os.kill(os.getpid(), signal.SIGINT)  # later signals are ignored while the shutdown runs
        time.sleep(0.05)
        assert handler.ignored == 1


def test_signals_held_is_a_no_op_outside_a_stop_block_and_off_the_main_thread() -> None:
    seen: list[object] = []

    def off_main() -> None:
        with signals_held():
            seen.append("ran")

    with stop_on_signals():
        t = threading.Thread(target=off_main)
        t.start()
        t.join()
    with signals_held():
        seen.append("outside")
    assert seen == ["ran", "outside"]


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_a_stop_signal_during_an_append_leaves_every_row_on_disk(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """Points that converged are on disk whatever the moment of the signal: it arrives while a long append is being
    formatted (sent by the row formatter itself at the 100th row, so it lands mid-append however busy the machine),
    and is raised once they are written and synced."""
    from bodebench.io import results

    writer = ResultsWriter(tmp_path, "signal", {})
    points = [ResponsePoint(1.0 + i * 1e-3, 1, "position", 0.01, 1e-3 * math.cos(i), 1e-3 * math.sin(i), 20, True,
                            "converged", 1e-8) for i in range(5_000)]
    formatted = []
    row_of = results._point_row

    def row(point: ResponsePoint, style: object) -> str:
        formatted.append(point)
        if len(formatted) == 100:
            os.kill(os.getpid(), signal.SIGTERM)
        return row_of(point, style)  # type: ignore[arg-type]

    monkeypatch.setattr(results, "_point_row", row)
    with stop_on_signals(), pytest.raises(StopSignal, match="SIGTERM"):
        writer.append(points)
    assert len(formatted) == len(points)  # every row was made after the signal came
    assert len(load_response(tmp_path).points) == len(points)


def test_a_signal_during_start_up_is_one_line_and_the_signals_exit_status(monkeypatch: pytest.MonkeyPatch,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """A real SIGINT delivered while the command line is still being read (before any bus is opened): one line
    saying so on stderr, no traceback, exit status 128 + SIGINT, and nothing measured."""
    from bodebench.apps import cli

    build = cli.build_parser

    def interrupted_build():  # type: ignore[no-untyped-def]
        os.kill(os.getpid(), signal.SIGINT)
        return build()

    monkeypatch.setattr(cli, "build_parser", interrupted_build)
    status = cli.main(["ports"])
    err = capsys.readouterr().err
    assert status == 128 + signal.SIGINT
    assert err.count("\n") == 1 and err.startswith("bodebench: interrupted (SIGINT)") and "Traceback" not in err
