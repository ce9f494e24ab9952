"""The offline computational experiment: sweep a simulated plant with the sampler.

Each frequency starts from the plant at rest and is independent of the
others, so frequencies run in parallel on any ``concurrent.futures.Executor``
(a process pool by default).
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
import signal
import socket
from collections.abc import Callable, Collection, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager, nullcontext
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from bodebench.core.autointegration import Autointegrator
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.io.config import CaseConfig, PlantConfig
from bodebench.io.samples import PointSamples
from bodebench.sim.models import plant_from_table
from bodebench.sim.plants import Plant

OUTPUT_CHANNEL = "position"
FIRST_BATCH_PERIODS = 8
MAX_BATCH_PERIODS = 256


def build_plant(plant: PlantConfig) -> Plant:
    """The simulated plant a ``[plant]`` table describes."""
    return plant_from_table(asdict(plant))


def measure_frequency(case: CaseConfig, frequency_hz: float) -> list[ResponsePoint]:
    """Autointegrate one frequency of a case: the plant starts at rest, step h = 1/(K_f f).

    Periods are simulated in growing batches and handed to the sampler; the
    rule decides at every period, so the periods reported are exactly those a
    period-by-period run would need.
    """
    return measure_point(case, frequency_hz)


def measure_point(case: CaseConfig, frequency_hz: float, samples_dir: str = "") -> list[ResponsePoint]:
    """:func:`measure_frequency`; with ``samples_dir`` (a results directory) the samples the sampler was fed are
    saved there first (:mod:`bodebench.io.samples`), by the process that measured them."""
    keep_samples = bool(samples_dir)
    analysis = case.analysis
    if case.plant is None:
        raise ValueError(f"case {case.name!r} of {case.source} has no [plant] to simulate")
    settle = case.excitation.settle_at(frequency_hz)  # whole periods simulated before period 1
    plant = build_plant(case.plant)
    channel = plant.output_names.index(OUTPUT_CHANNEL)
    amplitude = case.excitation.amplitude_at(frequency_hz)
    steps = analysis.steps_per_period
    h = 1.0 / (steps * frequency_hz)
    # the steps are the computation's own, one every h from t = 0: a grid that t0 (whole periods) lies on
    sampler = Autointegrator(frequency_hz, amplitude, (OUTPUT_CHANNEL,), analysis, t0=settle / frequency_hz,
                             grid_steps_per_period=steps)
    record = PointSamples(frequency_hz, amplitude, (OUTPUT_CHANNEL,), settle / frequency_hz, source="offline") \
        if keep_samples else None
    state = plant.initial_state()
    first_t, first_y = np.array([0.0]), np.zeros((1, 1))
    if record is not None:
        record.add(first_t, first_y)
    sampler.feed(first_t, first_y)
    step = 0
    batch = FIRST_BATCH_PERIODS
    while not sampler.done:
        periods = min(batch, sampler.max_periods - sampler.periods)
        n = periods * steps
        y = plant.run_sine(state, step * h, h, n, amplitude, frequency_hz)
        t = (step + 1 + np.arange(n)) * h
        if record is not None:
            record.add(t, y[:, channel:channel + 1])
        sampler.feed(t, y[:, channel:channel + 1])
        step += n
        batch = min(2 * batch, MAX_BATCH_PERIODS)
    points = sampler.points()
    if record is not None:
        record.save(samples_dir)
    return points


def default_executor(max_workers: int | None = None, models: Collection[str] = ()) -> ProcessPoolExecutor:
    """A process pool over the machine's cores (frequencies are CPU-bound and independent).

    models: plant models whose compiled step loops the workers run. Where workers are forks of this process
    (POSIX's default), the loops are loaded here, once, before the pool starts, and every worker has them from its
    first task; otherwise each worker loads them before its first task, one worker at a time, so that on a machine
    with no compiled copy yet they are compiled once (by the first worker, into numba's on-disk cache) rather than
    once per worker. A stop signal to the command's process group ends the workers at once, silently: the command
    itself says what was kept."""
    workers = max_workers or os.cpu_count() or 1
    context = multiprocessing.get_context()
    loaded = tuple(sorted(models))
    if context.get_start_method() == "fork":
        _load_kernels(None, loaded)
        return ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_set_stop_signals,
                                   initargs=(signal.SIG_DFL,))
    return ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_start_worker,
                               initargs=(context.Lock(), loaded))


def _set_stop_signals(handling: signal.Handlers) -> None:
    """In a pool's process: SIG_DFL (a stop signal ends it) or SIG_IGN (the command ends it) for the stop signals."""
    from bodebench.drivers.stop_signals import STOP_SIGNALS

    for signum in STOP_SIGNALS:
        signal.signal(signum, handling)


def _start_worker(lock: Any, models: tuple[str, ...]) -> None:
    _set_stop_signals(signal.SIG_DFL)
    _load_kernels(lock, models)


def _load_kernels(lock: Any, models: tuple[str, ...]) -> None:
    from bodebench.sim.models import load_kernels

    with lock if lock is not None else nullcontext():
        load_kernels(models)


class ExecutorError(Exception):
    """An executor asked for cannot be had (Dask not installed, no scheduler at the address)."""


@contextmanager
def offline_executor(jobs: int | None = None, scheduler: str | None = None,
                     models: Collection[str] = ()) -> Iterator[Executor | None]:
    """The executor an offline sweep runs on, shut down (queued work cancelled) when the block ends.

    scheduler: a Dask scheduler's address (``tcp://host:8786``), or "local" for a Dask cluster started here with
    ``jobs`` single-threaded worker processes; None: a process pool of ``jobs`` workers (None: one per core), or no
    executor at all for ``jobs == 1`` (this process, in order). models: plant models whose compiled step loops the
    workers load first (see :func:`default_executor`)."""
    if jobs is not None and jobs < 1:
        raise ExecutorError(f"--jobs must be >= 1, got {jobs}")
    if scheduler is None:
        if jobs == 1:
            yield None
            return
        pool = default_executor(jobs, models)
        try:
            yield pool
        finally:
            pool.shutdown(cancel_futures=True)
        return
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ExecutorError("a Dask executor needs dask.distributed: pip install 'bodebench[dask]'") from None
    cluster = None
    try:
        if scheduler == "local":
            cluster = LocalCluster(n_workers=jobs or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                                   dashboard_address=None)
            client = Client(cluster)
        else:
            _listening(scheduler)
            client = Client(scheduler, timeout=10)
    except (OSError, TimeoutError, ValueError) as exc:  # ValueError: not an address
        if cluster is not None:
            cluster.close()
        raise ExecutorError(f"no Dask scheduler at {scheduler}: {exc}") from None
    try:
        if models:  # compiled by one worker (into the shared on-disk cache) before the others load them
            client.submit(_load_kernels, None, tuple(sorted(models)), pure=False).result()
            client.run(_load_kernels, None, tuple(sorted(models)))
        executor = client.get_executor(pure=False)
        try:
            yield executor
        finally:
            executor.shutdown(wait=False)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _listening(address: str) -> None:
    """OSError at once where nothing listens at a tcp:// or tls:// scheduler ``address`` (a refused connection;
    Dask's client retries it until its timeout)."""
    from distributed.comm import parse_address, parse_host_port

    scheme, location = parse_address(address)
    if scheme in ("tcp", "tls"):
        with socket.create_connection(parse_host_port(location), timeout=10):
            pass


def sweep(case: CaseConfig, executor: Executor | None = None,
          on_point: Callable[[list[ResponsePoint]], None] | None = None,
          measured: Sequence[ResponsePoint] = (), skip: Collection[float] = (),
          samples_dir: str | Path = "") -> FrequencyResponse:
    """Measure every frequency of a case; ``on_point`` gets each frequency's points as soon as they are done.

    executor: where frequencies run (None: in this process, in order); ``measured``: points of an interrupted
    sweep, kept; ``skip``: the frequencies (Hz) they complete, not measured again; ``samples_dir``: the results
    directory whose ``samples/`` gets each frequency's samples before ``on_point`` gets its points ("": none).
    """
    response = FrequencyResponse(measured, config=case.raw, case=case.name)
    for _, points in measure_cases((case,), executor, (skip,), (str(samples_dir),)):
        for p in points:
            response.add(p)
        if on_point is not None:
            on_point(points)
    sort_points(response)
    return response


def sort_points(response: FrequencyResponse) -> None:
    """Order ``response``'s points by channel, harmonic and frequency (the order of a finished sweep's file)."""
    response.points.sort(key=lambda p: (p.channel, p.harmonic, p.frequency_hz))


def in_flight_limit(executor: Executor | None) -> int | None:
    """How many frequencies to keep submitted at once on ``executor``: twice its workers for a pool of this process
    (so that work submitted later, a finished case's plots, waits for at most that many), None (all at once) for
    one whose size is not known here (a Dask cluster schedules on its own)."""
    workers = getattr(executor, "_max_workers", None)  # concurrent.futures' process and thread pools
    return 2 * workers if isinstance(workers, int) and workers > 0 else None


def measure_cases(cases: Sequence[CaseConfig], executor: Executor | None = None,
                  skip: Sequence[Collection[float]] = (), samples_dirs: Sequence[str] = (),
                  in_flight: int | None = None) -> Iterator[tuple[int, list[ResponsePoint]]]:
    """Every frequency of every case, all on one executor: (case index, that frequency's points), in the order they
    are done (None: in this process, case by case, frequency by frequency).

    skip: per case, the frequencies (Hz) not to measure. samples_dirs: per case, the results directory whose
    ``samples/`` gets each frequency's samples, written by the process that measured them before its points are
    yielded ("" or absent: none). in_flight: at most this many frequencies submitted and not yet done, the next
    submitted as one is (None: all at once). Frequencies not yet started are cancelled when the caller stops
    iterating."""
    tasks = [(i, f) for i, case in enumerate(cases) for f in case.excitation.frequencies_hz
             if not (i < len(skip) and f in skip[i])]

    def where(i: int) -> str:
        return samples_dirs[i] if i < len(samples_dirs) else ""

    if executor is None:
        for i, f in tasks:
            yield i, measure_point(cases[i], f, where(i))
        return
    queued = iter(tasks)
    running: dict[Future[list[ResponsePoint]], int] = {}

    def submit(count: int) -> None:
        for i, f in itertools.islice(queued, count):
            running[executor.submit(measure_point, cases[i], f, where(i))] = i

    submit(len(tasks) if in_flight is None else max(1, in_flight))
    try:
        while running:
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in [f for f in running if f in done]:  # in the order submitted
                i = running.pop(fut)
                submit(1)
                yield i, fut.result()
    finally:
        for fut in running:
            fut.cancel()
