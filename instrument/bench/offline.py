"""The offline computational experiment: sweep a simulated plant with the sampler.

Each frequency starts from the plant at rest and is independent of the
others, so frequencies run in parallel on any ``concurrent.futures.Executor``
(a process pool by default).
"""

from __future__ import annotations

import os
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from dataclasses import asdict
from typing import Callable, Collection, Iterator, Sequence

import numpy as np

from bodebench.core.autointegration import Autointegrator
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.io.config import CaseConfig, PlantConfig
from bodebench.sim.models import plant_from_config
from bodebench.sim.plants import Plant

OUTPUT_CHANNEL = "position"
FIRST_BATCH_PERIODS = 8
MAX_BATCH_PERIODS = 256


def build_plant(plant: PlantConfig) -> Plant:
    """The simulated plant a ``[plant]`` table describes."""
    params = asdict(plant)
    return plant_from_config(params.pop("model"), **params)


def measure_frequency(case: CaseConfig, frequency_hz: float) -> list[ResponsePoint]:
    """Autointegrate one frequency of a case: the plant starts at rest, step h = 1/(K_f f).

    Periods are simulated in growing batches and handed to the sampler; the
    rule decides at every period, so the periods reported are exactly those a
    period-by-period run would need.
    """
    analysis = case.analysis
    settle = case.excitation.settle_at(frequency_hz)  # whole periods simulated before period 1
    plant = build_plant(case.plant)
    channel = plant.output_names.index(OUTPUT_CHANNEL)
    amplitude = case.excitation.amplitude_at(frequency_hz)
    steps = analysis.steps_per_period
    h = 1.0 / (steps * frequency_hz)
    sampler = Autointegrator(frequency_hz, amplitude, (OUTPUT_CHANNEL,), analysis, t0=settle / frequency_hz)
    state = plant.initial_state()
    sampler.feed(np.array([0.0]), np.zeros((1, 1)))
    step = 0
    batch = FIRST_BATCH_PERIODS
    while not sampler.done:
        periods = min(batch, analysis.max_periods - sampler.periods)
        n = periods * steps
        y = plant.run_sine(state, step * h, h, n, amplitude, frequency_hz)
        t = (step + 1 + np.arange(n)) * h
        sampler.feed(t, y[:, channel:channel + 1])
        step += n
        batch = min(2 * batch, MAX_BATCH_PERIODS)
    return sampler.points()


def default_executor(max_workers: int | None = None) -> ProcessPoolExecutor:
    """A process pool over the machine's cores (frequencies are CPU-bound and independent)."""
    return ProcessPoolExecutor(max_workers=max_workers or os.cpu_count() or 1)


def sweep(case: CaseConfig, executor: Executor | None = None,
          on_point: Callable[[list[ResponsePoint]], None] | None = None,
          measured: Sequence[ResponsePoint] = (), skip: Collection[float] = ()) -> FrequencyResponse:
    """Measure every frequency of a case; ``on_point`` gets each frequency's points as soon as they are done.

    executor: where frequencies run (None: in this process, in order); ``measured``: points of an interrupted
    sweep, kept; ``skip``: the frequencies (Hz) they complete, not measured again.
    """
    response = FrequencyResponse(measured, config=case.raw, case=case.name)
    for points in _run_all(case, executor, skip):
        for p in points:
            response.add(p)
        if on_point is not None:
            on_point(points)
    response.points.sort(key=lambda p: (p.channel, p.harmonic, p.frequency_hz))
    return response


def _run_all(case: CaseConfig, executor: Executor | None, skip: Collection[float] = ()
             ) -> Iterator[list[ResponsePoint]]:
    freqs = [f for f in case.excitation.frequencies_hz if f not in skip]
    if executor is None:
        for f in freqs:
            yield measure_frequency(case, f)
        return
    futures: list[Future[list[ResponsePoint]]] = [executor.submit(measure_frequency, case, f) for f in freqs]
    try:
        for fut in as_completed(futures):
            yield fut.result()
    finally:
        for fut in futures:
            fut.cancel()
