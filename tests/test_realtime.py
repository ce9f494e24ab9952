"""Scheduling helpers of the pacing loop: CPU affinity per thread and for the whole process, SCHED_FIFO."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from typing import Any

from bodebench.drivers.scheduling import keep_to, pacing_cpu, pacing_cpu_left_alone, request_fifo


def in_thread(fn: Callable[[], Any]) -> Any:
    """Run ``fn`` in a fresh thread (so its scheduling changes die with it); its result."""
    out: list[Any] = []
    t = threading.Thread(target=lambda: out.append(fn()))
    t.start()
    t.join()
    return out[0]


def thread_cpus() -> dict[int, set[int]]:
    """The CPUs each thread of this process may run on, for every thread alive while they are read (a thread of
    the test worker's that ends between the listing and its read is left out, as it no longer runs anywhere)."""
    out: dict[int, set[int]] = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            out[int(tid)] = os.sched_getaffinity(int(tid))
        except ProcessLookupError:
            continue
    return out


def test_pacing_cpu_is_the_last_allowed_one() -> None:
    cpus = os.sched_getaffinity(0)
    assert pacing_cpu() == (max(cpus) if len(cpus) > 1 else None)


def test_keep_to_moves_only_the_calling_thread() -> None:
    mine = os.sched_getaffinity(0)
    target = {min(mine)}
    got = in_thread(lambda: (keep_to(target), os.sched_getaffinity(0)))
    assert got == (True, target)
    assert os.sched_getaffinity(0) == mine
    assert in_thread(lambda: keep_to(set())) is False


def test_fifo_is_reported_as_granted_only_when_it_is() -> None:
    granted, policy = in_thread(lambda: (request_fifo(1), os.sched_getscheduler(0)))
    assert granted == (policy == os.SCHED_FIFO)
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the test's own thread is untouched


def test_every_thread_keeps_off_the_pacing_cpu_and_gets_its_cpus_back() -> None:
    before = thread_cpus()
    stop = threading.Event()
    early = threading.Thread(target=stop.wait)
    early.start()
    try:
        early_cpus = os.sched_getaffinity(early.native_id)
        with pacing_cpu_left_alone() as cpu:
            if cpu is None:  # one CPU: nothing to leave
                assert len(os.sched_getaffinity(0)) == 1
            else:
                inside = thread_cpus()
                assert all(cpu not in cpus and cpus for cpus in inside.values())
                # a thread started inside inherits the restriction
                assert cpu not in in_thread(lambda: os.sched_getaffinity(0))
        assert os.sched_getaffinity(early.native_id) == early_cpus
        after = thread_cpus()
        assert {tid: after[tid] for tid in before if tid in after} == {tid: before[tid] for tid in before
                                                                       if tid in after}
    finally:
        stop.set()
        early.join()


def test_a_chosen_cpu_is_left_alone_and_nothing_is_added_on_exit() -> None:
    """An explicit CPU (say one isolated from the scheduler) is taken out of every thread's set while inside; on
    exit a thread started inside gets its starter's former set, never the yielded CPU added to it."""
    mine = os.sched_getaffinity(0)
    chosen = min(mine)
    stop = threading.Event()
    started: list[threading.Thread] = []
    try:
        with pacing_cpu_left_alone(chosen) as cpu:
            assert cpu == chosen
            if len(mine) > 1:
                assert chosen not in os.sched_getaffinity(0)
            started.append(threading.Thread(target=stop.wait))
            started[0].start()
        assert os.sched_getaffinity(0) == mine
        assert os.sched_getaffinity(started[0].native_id) == mine
    finally:
        stop.set()
        for t in started:
            t.join()
