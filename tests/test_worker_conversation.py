"""The conversation with the bus worker (bodebench.bench.conversation): however its ``with`` block ends, the drive is
left at zero and disabled, as seen on a real python-can virtual bus, and the end is told once, with its reason."""

from __future__ import annotations

import contextlib
import time

import numpy as np
import pytest
from helpers import BusRecorder
from test_bench_e2e import config

from bodebench.bench.connection import plan_link
from bodebench.bench.conversation import WorkerConversation
from bodebench.bench.events import SessionEnded
from bodebench.bench.worker import Credit, Ready, Samples, SineStarted, StartSine
from bodebench.io.config import parse_config


class Crash(Exception):
    """An error of the code inside the ``with`` block."""


def _sine_running(worker: WorkerConversation) -> None:
    """Start a 10 Hz sine and let the lockstep clock run until a setpoint other than zero went out."""
    worker.expect(Ready, 60.0)
    worker.send(StartSine(10.0, 0.01, 1, 1))
    worker.expect(SineStarted, 60.0)
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        message = worker.receive(1.0)
        if isinstance(message, Samples):
            if np.any(np.asarray(message.setpoint) != 0.0):
                return
            worker.send(Credit(message.last_tick + 100))
    raise AssertionError("the sine never moved the setpoint")


@pytest.mark.parametrize("ending", [None, Crash("display crashed"), KeyboardInterrupt()],
                         ids=["completed", "exception", "interrupt"])
def test_every_way_out_of_the_with_block_leaves_the_drive_at_zero_and_disabled(ending: BaseException | None) -> None:
    channel = f"conversation-{type(ending).__name__}"
    recorder = BusRecorder(channel)
    case = parse_config(config(can={"channel": channel}), "conversation.toml").cases[0]
    told: list[SessionEnded] = []
    worker = WorkerConversation(plan_link(case), case.on_bench.bench, case.on_bench.safety, "thread",
                                finished="all done", reason_for=lambda exc: f"ended by {type(exc).__name__}",
                                on_end=told.append)
    with pytest.raises(type(ending)) if ending is not None else contextlib.nullcontext(), worker:
        _sine_running(worker)
        if ending is not None:
            raise ending
    value, disabled = recorder.close()
    assert value == 0.0 and disabled
    sent = [recorder.layout.setpoint.decode(bytes(m.data))["setpoint"] for m in recorder.frames
            if m.arbitration_id == recorder.layout.setpoint.id]
    assert any(u != 0.0 for u in sent)  # the drive was moving when the block ended
    assert told == [worker.ended] and worker.ended is not None
    assert worker.ended.completed == (ending is None)
    assert worker.ended.reason == ("all done" if ending is None else f"ended by {type(ending).__name__}")
    assert worker.ended.drive_state() == "drive left at setpoint 0, disabled"
    assert worker.stopped is not None and worker.stopped.reason == worker.ended.reason



def test_a_ramp_out_longer_than_the_stop_wait_is_waited_for_while_the_worker_reports(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Realtime clock, a 0.25 Hz sine ramped out over one period (4 s), the silence the stop waits for cut to
    1.5 s (the worker reports every 0.1 s) and no allowance for a slew: the worker reports its health while it
    ramps out, so the stop waits for its report and the drive is told to be left at zero and disabled, not
    "state unknown"."""
    import bodebench.bench.conversation as conversation

    monkeypatch.setattr(conversation, "STOP_WAIT_S", 1.5)
    monkeypatch.setattr(conversation, "MAX_SLEW_STEPS", 0)
    channel = "conversation-slow-ramp"
    recorder = BusRecorder(channel)
    case = parse_config(config(can={"channel": channel}, bench={"clock": "realtime"}), "ramp.toml").cases[0]
    worker = WorkerConversation(plan_link(case), case.on_bench.bench, case.on_bench.safety, "thread",
                                finished="all done", reason_for=lambda exc: f"ended by {type(exc).__name__}")
    with worker:
        worker.expect(Ready, 60.0)
        worker.send(StartSine(0.25, 0.01, 0, 1))
        worker.expect(SineStarted, 60.0)
        time.sleep(0.5)
        started = time.monotonic()
        stopped = worker.shutdown("all done", abort=False)
        waited = time.monotonic() - started
    value, disabled = recorder.close()
    assert stopped is not None and waited > 3.0  # it outlasted the silence it would have been given up after
    assert value == 0.0 and disabled
    assert worker.ended is not None and worker.ended.drive_state() == "drive left at setpoint 0, disabled"
