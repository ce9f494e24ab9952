"""The conversation with the bus worker: :class:`WorkerConversation`.

It starts the worker on a link, sends it commands, receives its messages (its faults and its end raised as
SessionError) and, whatever ends the conversation, asks it to stop, waits for its report of how it left the drive,
joins it and closes the link. Used as a context manager, that ending runs on every way out of the ``with`` block.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from types import TracebackType
from typing import TYPE_CHECKING, Any, TypeVar

from bodebench.bench.events import SessionEnded, SessionError
from bodebench.bench.worker import (
    MAX_SLEW_STEPS,
    Fault,
    FinishSine,
    Health,
    MessagePipe,
    Samples,
    Stop,
    Stopped,
    session_ended,
    start_worker,
    worker_spec,
)
from bodebench.drivers.scheduling import pacing_cpu_left_alone
from bodebench.drivers.stop_signals import StopSignal
from bodebench.status import FaultKind

if TYPE_CHECKING:
    from bodebench.bench.connection import LinkPlan
    from bodebench.io.tables import BenchConfig, SafetyConfig

__all__ = ["WorkerConversation", "ending_reason"]

Message = TypeVar("Message")

STOP_WAIT_S = 10.0
"""How long the worker may stay silent after the stop before it is given up on, and then how long it is given to
end (s). While it ramps out it reports its health, and each report gives it this long again; the slew to zero
under safety.max_rate, which reports nothing, is allowed for on top (two ticks' time a step: on the realtime clock
each step's sleep oversleeps)."""

DATING_WAIT_S = 5.0
"""How long after its ramp out a measured program waits for the driver to check the dating of its samples (s)."""


def dating_not_checked(what: str) -> SessionError:
    """The error where no check of the samples' dating came within :data:`DATING_WAIT_S` of the ramp out of
    ``what`` (a point's frequency, the overview)."""
    return SessionError(FaultKind.BUS, f"{what}: the dating of the samples by SYNC was not checked within "
                                       f"{DATING_WAIT_S:g} s of the ramp out (a gap in the TPDOs, and no SYNC "
                                       "answered since): nothing written from it")


def ending_reason(exc: BaseException) -> str:
    """The reason a run that ``exc`` ended gives: a trip's own text, the stop signal, or the error."""
    if isinstance(exc, SessionError):
        return str(exc)
    if isinstance(exc, KeyboardInterrupt):
        return f"interrupted ({exc.signame})" if isinstance(exc, StopSignal) else "interrupted"
    return f"error: {type(exc).__name__}: {exc}"


def _nothing(*_: object) -> None:
    """A hook that does nothing."""


class WorkerConversation:
    """The bus worker of one run on the drive ``plan`` reaches, with ``bench``'s pacing and ``safety``'s limits, in
    a process or a thread (``mode``; None: the bench's choice).

    finished: the reason given when the ``with`` block ends normally; reason_for: the reason given when an
    exception ends it (:func:`ending_reason`). on_fault (kind, text): told of a worker's fault before it is raised;
    on_health: told of each health report received; before_wait: called before each wait of :meth:`expect`, and
    by a caller's own receiving loop (it may raise to stop waiting); on_end: told how the run ended, on every way
    out. keep_off_pacing_cpu: on the realtime clock with the worker in a process of its own, this process keeps off
    the worker's CPU until the worker is joined."""

    def __init__(self, plan: LinkPlan, bench: BenchConfig, safety: SafetyConfig, mode: str | None = None, *,
                 finished: str, reason_for: Callable[[BaseException], str] = ending_reason,
                 on_fault: Callable[[FaultKind, str], None] = _nothing,
                 on_health: Callable[[Health], None] = _nothing, before_wait: Callable[[], None] = _nothing,
                 on_end: Callable[[SessionEnded], None] = _nothing, keep_off_pacing_cpu: bool = False) -> None:
        self.plan = plan
        self.bench = bench
        self.safety = safety
        self.mode = mode or bench.worker_mode()
        self.finished = finished
        self.reason_for = reason_for
        self.on_fault = on_fault
        self.on_health = on_health
        self.before_wait = before_wait
        self.on_end = on_end
        self.keep_off_pacing_cpu = keep_off_pacing_cpu and bench.clock == "realtime" and self.mode == "process"
        self.pipe: MessagePipe | None = None
        """The session's end of the pipe to the worker (None before :meth:`start`)."""
        self.last_health: Health | None = None
        self.stopped: Stopped | None = None
        """The worker's report of how it left the drive (None until it came)."""
        self.ended: SessionEnded | None = None
        """How the run ended (None until :meth:`close`)."""
        self._handle: Any = None  # the worker's process or thread
        self._cpu_kept_off = contextlib.ExitStack()

    def start(self) -> None:
        """Start the worker; it opens the link, enables the drive and sends Ready (ended again, by :meth:`close`,
        where what follows its start fails)."""
        self.stopped = None
        self.pipe, self._handle = start_worker(worker_spec(self.plan.open_link, self.bench, self.safety), self.mode)
        try:
            if self.keep_off_pacing_cpu:
                self._cpu_kept_off.enter_context(pacing_cpu_left_alone(self.bench.pacing_cpu))
        except BaseException as exc:
            self.close(self.reason_for(exc), completed=False)
            raise

    def send(self, message: object) -> None:
        """Send a command. A worker that has already ended (a trip between its last batch and this command) left its
        Fault and Stopped in the pipe: the SessionError raised is that fault's."""
        assert self.pipe is not None
        try:
            self.pipe.send(message)
        except OSError:
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                self.receive(0.1)  # raises on the worker's Fault, its Stopped, or the pipe's end
            raise SessionError(FaultKind.BUS, "the bus worker ended unexpectedly") from None

    def receive(self, timeout: float) -> object | None:
        """The worker's next message within ``timeout`` (s; None: none came). SessionError on its fault, its end, or
        the pipe's end."""
        assert self.pipe is not None
        try:
            if not self.pipe.poll(timeout):
                return None
            message = self.pipe.recv()
        except (EOFError, OSError):
            raise SessionError(FaultKind.BUS, "the bus worker ended unexpectedly") from None
        if isinstance(message, Fault):
            kind = FaultKind(message.kind)
            self.on_fault(kind, message.message)
            raise SessionError(kind, message.message)
        if isinstance(message, Stopped):
            self.stopped = message
            raise SessionError(FaultKind.BUS, f"the bus worker stopped: {message.reason}")
        if isinstance(message, Health):
            self.last_health = message
            self.on_health(message)
        return message

    def expect(self, kind: type[Message], timeout: float) -> Message:
        """The first message of type ``kind`` within ``timeout`` (s), others passed over; SessionError (timeout)
        when none came."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.before_wait()
            message = self.receive(0.1)
            if isinstance(message, kind):
                return message
        raise SessionError(FaultKind.TIMEOUT, f"no {kind.__name__} from the bus worker within {timeout:g} s")

    def dating_checked(self, ramp_out_s: float) -> bool:
        """Ramp the running program out and wait for a batch whose samples' dating the driver has checked on the
        idle ticks (``Samples.dating_unchecked`` false): True when one came within ``ramp_out_s`` (s) +
        :data:`DATING_WAIT_S` (else :func:`dating_not_checked` is the error to raise). SessionError where the check
        fails (the driver's fault)."""
        self.send(FinishSine())
        deadline = time.monotonic() + ramp_out_s + DATING_WAIT_S
        while time.monotonic() < deadline:
            self.before_wait()
            message = self.receive(0.1)
            if isinstance(message, Samples) and not message.dating_unchecked:
                return True
        return False

    def shutdown(self, reason: str, abort: bool) -> Stopped | None:
        """Ask the worker to stop (``abort``: slew straight to zero rather than ramp out) and wait for its report
        (None: it fell silent for longer than :data:`STOP_WAIT_S` and the slew allows, or the pipe ended)."""
        assert self.pipe is not None
        with contextlib.suppress(OSError, BrokenPipeError):
            self.pipe.send(Stop(reason, abort=abort))
        if self.stopped is not None:  # the worker had ended already, and said how
            return self.stopped
        silence = STOP_WAIT_S + (2.0 * MAX_SLEW_STEPS / self.bench.rate_hz if self.safety.max_rate is not None
                                 else 0.0)
        deadline = time.monotonic() + silence
        while time.monotonic() < deadline:
            try:
                if not self.pipe.poll(0.2):
                    continue
                message = self.pipe.recv()
            except (EOFError, OSError):
                return None
            if isinstance(message, Stopped):
                self.stopped = message
                return message
            if isinstance(message, Health):
                self.last_health = message
            deadline = time.monotonic() + silence  # the worker is still at work: a ramp out at a low frequency
        return None

    def close(self, reason: str, completed: bool) -> SessionEnded:
        """End the run: :meth:`shutdown` (aborting unless ``completed``), join the worker, give the pacing CPU back,
        close the link's resources; tells ``on_end`` how it ended and returns it."""
        self.shutdown(reason, abort=not completed)
        self._handle.join(timeout=STOP_WAIT_S)
        self._cpu_kept_off.close()
        self.plan.close()
        self.ended = session_ended(reason, completed, self.stopped, self.plan.layout)
        self.on_end(self.ended)
        return self.ended

    def __enter__(self) -> WorkerConversation:
        self.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close(self.finished if exc is None else self.reason_for(exc), completed=exc is None)
