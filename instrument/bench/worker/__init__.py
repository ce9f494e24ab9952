"""The bus worker: paces setpoints, talks to the drive, enforces the safety limits.

It runs apart from the analysis (its own process on the realtime clock, with
the garbage collector frozen and timer slack lowered; a thread is enough on
the lockstep clock) and exchanges only small typed messages with the session
over a pipe: commands in, sample batches and bus health out. Whatever ends it
(a stop, an abort, a trip, an exception, Ctrl-C, the session vanishing), its
last act on the bus is a zero setpoint and, where the layout has one, the
disable frame.

Where each part lives:

- ``messages``: the commands and reports exchanged with the session, the limits and the worker's spec;
- ``sine``: the setpoint program, a sine with whole-period ramps, and the sine asked for next;
- ``pacing``: when setpoints go out (lockstep credit and reply wait, realtime tick schedule) and the pacing
  statistics;
- ``safety``: setpoint clamp and slew limit, feedback windows, the watchdog, the drive's heartbeat, and zero
  then disable on every way out;
- ``timebase``: each sample's session time from its counter, timestamp or receive time; time conflicts and
  counter anomalies;
- ``health``: round trips, the send-time histogram and the Health report;
- ``pipe``: the worker's end of the pipe to the session;
- ``loop``: the worker itself, the loop joining these, started in a thread or a process.
"""

from bodebench.bench.worker.health import RoundTrips, SendErrorHistogram
from bodebench.bench.worker.loop import BusWorker, start_worker, worker_main
from bodebench.bench.worker.messages import (
    Credit,
    Fault,
    Health,
    Limits,
    PacingStats,
    Ready,
    Samples,
    SineStarted,
    StartSine,
    Stop,
    Stopped,
    WorkerSpec,
)
from bodebench.bench.worker.pacing import MIN_SLEEP_S, SPIN_S, WORKER_PRIORITY
from bodebench.bench.worker.safety import Trip
from bodebench.bench.worker.sine import SineProgram

__all__ = [
    "MIN_SLEEP_S",
    "SPIN_S",
    "WORKER_PRIORITY",
    "BusWorker",
    "Credit",
    "Fault",
    "Health",
    "Limits",
    "PacingStats",
    "Ready",
    "RoundTrips",
    "Samples",
    "SendErrorHistogram",
    "SineProgram",
    "SineStarted",
    "StartSine",
    "Stop",
    "Stopped",
    "Trip",
    "WorkerSpec",
    "start_worker",
    "worker_main",
]
