"""OS scheduling of loops paced on the wall clock (Linux): SCHED_FIFO priority where permitted, 1 ns timer slack,
and CPU pinning (the pacing loop keeps a CPU to itself, and every other thread keeps off it).

``sleep_until`` waits for a deadline as the paced loops need it (asleep most of the way, awake for the end): the bus
worker's ticks (bench.worker) and a CANopen check's late SYNC (drivers.canopen_link). All but
``pacing_cpu_left_alone`` act on the calling thread only. On other systems they do nothing (and report False where
they report).
"""

from __future__ import annotations

import ctypes
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress

__all__ = ["SPIN_S", "keep_to", "lower_timer_slack", "pacing_cpu", "pacing_cpu_left_alone", "request_fifo",
           "sleep_until"]

_PR_SET_TIMERSLACK = 29

SPIN_S = 2e-4
"""How long before a deadline ``sleep_until`` stops sleeping and busy-waits (s), since a sleep can end this late."""
MIN_SLEEP_S = 2e-5
"""Shorter sleeps are not worth their wake-up delay (s)."""


def sleep_until(deadline: float, spin_s: float = SPIN_S) -> None:
    """Return at ``time.perf_counter()`` = ``deadline``: asleep until ``spin_s`` before it (other threads run
    meanwhile, even beside a loop that has its CPU to itself under SCHED_FIFO), then busy-waiting the rest."""
    wait = deadline - time.perf_counter()
    if wait > spin_s + MIN_SLEEP_S:
        time.sleep(wait - spin_s)
    while time.perf_counter() < deadline:
        pass


def lower_timer_slack() -> None:
    """Ask for 1 ns timer slack, so sleeps of this thread end on time rather than up to 50 us late."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def request_fifo(priority: int) -> bool:
    """Run this thread under SCHED_FIFO at ``priority`` (1-99), so it preempts every normal task when it wakes;
    True when the OS granted it. A FIFO loop must sleep every period: one that never does is stopped for 50 ms a
    second by the kernel's realtime throttling."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError):
        return False
    return True


def pacing_cpu(chosen: int | None = None) -> int | None:
    """The CPU a bench's pacing loop keeps to itself: ``chosen`` when given (``bench.pacing_cpu``), else the last
    one this process may use (None with only one). A simulated drive on the same machine keeps off it, so its timer
    interrupts never land on the pacing loop."""
    if chosen is not None:
        return chosen
    try:
        cpus = os.sched_getaffinity(0)
    except (OSError, AttributeError):
        return None
    return max(cpus) if len(cpus) > 1 else None


def keep_to(cpus: set[int]) -> bool:
    """Run this thread on ``cpus`` only; True when the OS accepted it (False for an empty set)."""
    if not cpus:
        return False
    try:
        os.sched_setaffinity(0, cpus)
    except (OSError, AttributeError, ValueError):
        return False
    return True


@contextmanager
def pacing_cpu_left_alone(cpu: int | None = None) -> Iterator[int | None]:
    """While inside, every thread of this process, and every thread they start, keeps off ``cpu`` (default
    ``pacing_cpu()``; the CPU is yielded, None when there is nothing to leave): their timers would otherwise fire
    on the pacing loop's CPU and interrupt it. Start the pacing process before entering. On exit each thread gets
    its CPUs back."""
    cpu = pacing_cpu(cpu)
    tasks = _threads()
    if cpu is None or not tasks:
        yield None
        return
    everywhere = os.sched_getaffinity(0)  # for threads started inside: what their starter had before
    before: dict[int, set[int]] = {}
    for tid in tasks:
        try:
            before[tid] = os.sched_getaffinity(tid)
            if before[tid] - {cpu}:
                os.sched_setaffinity(tid, before[tid] - {cpu})
        except OSError:  # the thread ended meanwhile
            pass
    try:
        yield cpu
    finally:
        for tid in _threads():
            with suppress(OSError):
                os.sched_setaffinity(tid, before.get(tid, everywhere))


def _threads() -> list[int]:
    """Thread ids of this process (Linux), [] where /proc does not list them."""
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except (OSError, ValueError):
        return []
