"""The offline computational experiment: sweep a simulated plant with the sampler.

Each frequency starts from the plant at rest and is independent of the
others, so frequencies run in parallel on any ``concurrent.futures.Executor``
(a process pool by default).
"""

from __future__ import annotations

import os
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path
from typing import Callable, Collection, Iterator, Sequence

import numpy as np

from bodebench.core.autointegration import Autointegrator
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.io.config import CaseConfig, PlantConfig
from bodebench.io.samples import PointSamples
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
    return measure_point(case, frequency_hz)


def measure_point(case: CaseConfig, frequency_hz: float, samples_dir: str = "") -> list[ResponsePoint]:
    """:func:`measure_frequency`; with ``samples_dir`` (a results directory) the samples the sampler was fed are
    saved there first (:mod:`bodebench.io.samples`), by the process that measured them."""
    keep_samples = bool(samples_dir)
    analysis = case.analysis
    if case.plant is None:
        raise ValueError(f"case {case.name!r} of {case.source} has no [plant] to simulate")
    plant = build_plant(case.plant)
    channel = plant.output_names.index(OUTPUT_CHANNEL)
    amplitude = case.excitation.amplitude
    steps = analysis.steps_per_period
    h = 1.0 / (steps * frequency_hz)
    sampler = Autointegrator(frequency_hz, amplitude, (OUTPUT_CHANNEL,), analysis)
    record = PointSamples(frequency_hz, amplitude, (OUTPUT_CHANNEL,), source="offline") if keep_samples else None
    state = plant.initial_state()
    first_t, first_y = np.array([0.0]), np.zeros((1, 1))
    if record is not None:
        record.add(first_t, first_y)
    sampler.feed(first_t, first_y)
    step = 0
    batch = FIRST_BATCH_PERIODS
    while not sampler.done:
        periods = min(batch, analysis.max_periods - sampler.periods)
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


def default_executor(max_workers: int | None = None) -> ProcessPoolExecutor:
    """A process pool over the machine's cores (frequencies are CPU-bound and independent)."""
    return ProcessPoolExecutor(max_workers=max_workers or os.cpu_count() or 1)


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
    for points in _run_all(case, executor, skip, str(samples_dir)):
        for p in points:
            response.add(p)
        if on_point is not None:
            on_point(points)
    response.points.sort(key=lambda p: (p.channel, p.harmonic, p.frequency_hz))
    return response


def _run_all(case: CaseConfig, executor: Executor | None, skip: Collection[float] = (), samples_dir: str = ""
             ) -> Iterator[list[ResponsePoint]]:
    freqs = [f for f in case.excitation.frequencies_hz if f not in skip]
    if executor is None:
        for f in freqs:
            yield measure_point(case, f, samples_dir)
        return
    futures: list[Future[list[ResponsePoint]]] = [executor.submit(measure_point, case, f, samples_dir)
                                                  for f in freqs]
    try:
        for fut in as_completed(futures):
            yield fut.result()
    finally:
        for fut in futures:
            fut.cancel()
