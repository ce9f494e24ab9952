"""Pacing of setpoints on the realtime clock: send-time error at 1 kHz and 5 kHz.

Run: python benchmarks/bench_pacing.py [--quick]

A BenchSession sweeps the friction link of configs/sim_serial.toml, changed to the realtime clock: the simulated
drive runs in its own process behind a serial pseudo-terminal, ticking on the wall clock; the bus worker paces a
setpoint every 1/rate_hz s. Two-channel mode (reference_channel = "setpoint_echo"), tolerance 1 %, frequencies
2, 5, 10, 20 Hz. Each row is one whole sweep:

- "process": the worker in its own process (the default on the realtime clock), with or without a busy thread in
  the session's process: a Python loop of small numpy work and string formatting with no pause, like a UI
  redrawing as fast as it can, running from the session's start to its end.
- "thread": the same sweep with the worker as a thread of the session's process (BenchSession(...,
  worker_mode="thread")) next to the busy thread: the three share one interpreter lock.

Send-time error = when the worker actually sent a setpoint minus its schedule (PacingStats of the last BusStatus
event: every setpoint paced during the sweep). Overruns: setpoints late by more than one period. Figures are in
microseconds. Target: p99 < 50 us at 1 kHz with the worker in its own process. --quick runs a single short sweep
per row (frequencies 10 and 20 Hz). Prints figures only.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import threading
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from instrument.bus_worker import PacingStats  # noqa: E402
from instrument.config import parse_config  # noqa: E402
from instrument.links import plan_link  # noqa: E402
from instrument.session import BenchSession, BusStatus, PointFinished  # noqa: E402

CONFIG = ROOT / "configs" / "sim_serial.toml"
FREQUENCIES_HZ = [2.0, 5.0, 10.0, 20.0]
QUICK_FREQUENCIES_HZ = [10.0, 20.0]
RATES_HZ = (1000, 5000)
TARGET_P99_S = 50e-6
TARGET_RATE_HZ = 1000


def realtime_config(rate_hz: int, frequencies_hz: list[float]) -> dict[str, Any]:
    """configs/sim_serial.toml on the realtime clock at ``rate_hz``, two-channel mode, tolerance 1 %."""
    with open(CONFIG, "rb") as fh:
        data = tomllib.load(fh)
    data["title"] = f"Friction link on a simulated drive, serial line, realtime {rate_hz} Hz"
    data["bench"].update(clock="realtime", rate_hz=rate_hz, reference_channel="setpoint_echo")
    data["analysis"]["tolerance_percent"] = 1.0
    data["excitation"]["frequencies_hz"] = list(frequencies_hz)
    return data


class BusyUi:
    """A thread burning CPU in Python as a terminal UI redrawing without pause would: small numpy work on a
    scope-sized array and formatting of the figures into lines of text."""

    def __init__(self) -> None:
        self.stop = threading.Event()
        self.frames = 0
        self.thread = threading.Thread(target=self._run, name="busy-ui", daemon=True)

    def _run(self) -> None:
        rng = np.random.default_rng(1)
        trace = rng.standard_normal(512)
        while not self.stop.is_set():
            trace = np.roll(trace, 7) * 0.999 + 0.001 * rng.standard_normal(512)
            spectrum = np.abs(np.fft.rfft(trace))
            lines = [f"{i:4d} {v:10.4f} {'#' * int(min(40, v))}" for i, v in enumerate(spectrum[:48])]
            screen = "\n".join(lines)
            self.frames += len(screen) > 0

    def __enter__(self) -> BusyUi:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join()


@dataclass
class Row:
    rate_hz: int
    worker: str
    busy: bool
    pacing: PacingStats | None
    wall_s: float
    points: int
    converged: int
    ui_frames: int


def run(rate_hz: int, worker: str, busy: bool, frequencies_hz: list[float]) -> Row:
    """One sweep; the pacing figures of its last BusStatus event."""
    case = parse_config(realtime_config(rate_hz, frequencies_hz), str(CONFIG)).cases[0]
    last: list[PacingStats | None] = [None]
    points: list[Any] = []

    def listener(event: object) -> None:
        if isinstance(event, BusStatus) and event.health.pacing is not None:
            last[0] = event.health.pacing
        elif isinstance(event, PointFinished):
            points.extend(event.points)

    plan = plan_link(case, CONFIG)
    session = BenchSession(case, plan, listener=listener, worker_mode=worker)
    ui = BusyUi()
    start = time.perf_counter()
    if busy:
        with ui:
            session.run()
    else:
        session.run()
    wall = time.perf_counter() - start
    return Row(rate_hz, worker, busy, last[0], wall, len(points), sum(p.converged for p in points), ui.frames)


def us(seconds: float) -> str:
    return f"{seconds * 1e6:9.1f}"


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short sweeps (10 and 20 Hz)")
    args = parser.parse_args(argv)
    freqs = QUICK_FREQUENCIES_HZ if args.quick else FREQUENCIES_HZ
    print(f"config: {CONFIG.relative_to(ROOT)} on the realtime clock, frequencies {freqs} Hz, tolerance 1 %, "
          f"two-channel (setpoint_echo); {os.cpu_count()} CPUs")
    rows: list[Row] = []
    for rate in RATES_HZ:
        for worker, busy in (("process", False), ("process", True), ("thread", True)):
            row = run(rate, worker, busy, freqs)
            rows.append(row)
            print(f"  ran {rate} Hz, worker {worker}, busy thread {'yes' if busy else 'no'}: {row.wall_s:.1f} s",
                  flush=True)
    print()
    print("send-time error of paced setpoints (us)")
    print(f"{'rate':>6} {'worker':>8} {'busy':>5} {'p50':>9} {'p99':>9} {'max':>9} {'overruns':>9} {'samples':>8} "
          f"{'wall s':>7} {'points':>7} {'ui/s':>7}")
    for r in rows:
        p = r.pacing
        figures = (f"{us(p.p50)} {us(p.p99)} {us(p.max)} {p.overruns:9d} {p.count:8d}" if p is not None
                   else f"{'-':>9} {'-':>9} {'-':>9} {'-':>9} {'-':>8}")
        target = ""
        if r.rate_hz == TARGET_RATE_HZ and r.worker == "process" and p is not None:
            target = f"  target p99 < {TARGET_P99_S * 1e6:g} us: {'met' if p.p99 < TARGET_P99_S else 'NOT met'}"
        print(f"{r.rate_hz:6d} {r.worker:>8} {'yes' if r.busy else 'no':>5} {figures} {r.wall_s:7.1f} "
              f"{r.converged:3d}/{r.points:<3d} {r.ui_frames / r.wall_s if r.busy else math.nan:7.0f}{target}")


if __name__ == "__main__":
    main(sys.argv[1:])
