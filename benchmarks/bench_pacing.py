"""Pacing of setpoints on the realtime clock: send-time error at 1 kHz and 5 kHz.

Run: python benchmarks/bench_pacing.py [--quick]

A BenchSession sweeps the friction link of configs/sim_serial.toml, changed to the realtime clock: the simulated
drive runs in its own process behind a serial pseudo-terminal, ticking on the wall clock (under SCHED_FIFO below the
worker where the OS permits, off the worker's CPU, as a drive on its own hardware would); the bus worker paces a
setpoint every 1/rate_hz s. Two-channel mode (reference_channel = "setpoint_echo"), tolerance 1 %, frequencies
2, 5, 10, 20 Hz, at most 16 periods a point (so a sweep lasts about 16 s whether or not the points converge: the
drive's clock and the worker's are not locked, and the friction link's response to that jitter is noisy). A
sweep still running after 20 s (a session or a drive starved of CPU) is aborted there; its pacing figures stand.
Each row is one sweep:

- "process": the worker in its own process (the default on the realtime clock), with or without a busy thread in
  the session's process: a Python loop of small numpy work and string formatting with no pause, like a UI
  redrawing as fast as it can, running from the session's start to its end.
- "thread": the same sweep with the worker as a thread of the session's process (BenchSession(...,
  worker_mode="thread")) next to the busy thread: the three share one interpreter lock.

Send-time error = when the worker actually sent a setpoint minus its schedule (PacingStats of the last BusStatus
event: every setpoint paced during the sweep, binned at 1 us). Overruns: setpoints late by more than one period.
Figures are in microseconds. Target: p99 < 50 us at 1 kHz with the worker in its own process. The worker asks
for SCHED_FIFO and a CPU of its own where the OS permits (the "granted" column says what it got). The figures depend
on what else the machine runs: the header prints the load average. --quick: frequencies 10 and 20 Hz only. Prints
figures only.
"""

from __future__ import annotations

import argparse
import gc
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

from bodebench.bench.connection import plan_link  # noqa: E402
from bodebench.bench.events import (  # noqa: E402
    BusStatus,
    PacingStats,  # noqa: E402
    PointFinished,
    SessionError,
)
from bodebench.bench.session import BenchSession  # noqa: E402
from bodebench.drivers.driver import BusHealth  # noqa: E402
from bodebench.io.config import parse_config  # noqa: E402

CONFIG = ROOT / "configs" / "sim_serial.toml"
FREQUENCIES_HZ = [2.0, 5.0, 10.0, 20.0]
QUICK_FREQUENCIES_HZ = [10.0, 20.0]
MAX_PERIODS = 16
CAP_S = 20.0  # a sweep still running after this long is aborted (its pacing figures stand)
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
    data["analysis"]["max_periods"] = MAX_PERIODS
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
    error: str
    points: int
    converged: int
    ui_frames: int
    feedback_ratio: float  # feedback frames received per setpoint sent: below 1, the drive fell behind


def run(rate_hz: int, worker: str, busy: bool, frequencies_hz: list[float]) -> Row:
    """One sweep; the pacing figures of its last BusStatus event."""
    case = parse_config(realtime_config(rate_hz, frequencies_hz), str(CONFIG)).cases[0]
    last: list[PacingStats | None] = [None]
    bus: list[BusHealth | None] = [None]
    points: list[Any] = []

    def listener(event: object) -> None:
        if isinstance(event, BusStatus) and event.health.pacing is not None:
            last[0] = event.health.pacing
            bus[0] = event.health.bus
        elif isinstance(event, PointFinished):
            points.extend(event.points)

    plan = plan_link(case)
    session = BenchSession(case, plan, listener=listener, worker_mode=worker)
    ui = BusyUi()
    error = ""
    cap = threading.Timer(CAP_S, session.controls.request_abort)
    cap.daemon = True
    start = time.perf_counter()
    cap.start()
    try:
        if busy:
            with ui:
                session.run()
        else:
            session.run()
    except SessionError as exc:  # the pacing so far is still worth printing
        error = f"aborted at the {CAP_S:g} s cap" if exc.kind == "abort" else f"SessionError: {exc}"
    except ValueError as exc:
        error = f"ValueError: {exc}"
    finally:
        cap.cancel()
        if worker == "thread":  # the worker froze and disabled the collector of this process for its loop
            gc.unfreeze()
            gc.enable()
    wall = time.perf_counter() - start
    feedback = bus[0].frames_in / bus[0].frames_out if bus[0] is not None and bus[0].frames_out else math.nan
    return Row(rate_hz, worker, busy, last[0], wall, error, len(points), sum(p.converged for p in points),
               ui.frames, feedback)


def us(seconds: float) -> str:
    return f"{seconds * 1e6:9.1f}"


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short sweeps (10 and 20 Hz)")
    args = parser.parse_args(argv)
    freqs = QUICK_FREQUENCIES_HZ if args.quick else FREQUENCIES_HZ
    print(f"config: {CONFIG.relative_to(ROOT)} on the realtime clock, frequencies {freqs} Hz, tolerance 1 %, "
          f"at most {MAX_PERIODS} periods a point, two-channel (setpoint_echo)")
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"machine: {os.cpu_count()} CPUs, load average {load}")
    rows: list[Row] = []
    for rate in RATES_HZ:
        for worker, busy in (("process", False), ("process", True), ("thread", True)):
            row = run(rate, worker, busy, freqs)
            rows.append(row)
            print(f"  ran {rate} Hz, worker {worker}, busy thread {'yes' if busy else 'no'}: {row.wall_s:.1f} s"
                  + (f" (ended early: {row.error})" if row.error else ""), flush=True)
    print()
    print("send-time error of paced setpoints (us)")
    print(f"{'rate':>6} {'worker':>8} {'busy':>5} {'p50':>9} {'p99':>9} {'max':>9} {'overruns':>9} {'samples':>8} "
          f"{'wall s':>7} {'points':>7} {'fb/sp':>6} {'ui/s':>7}  granted")
    for r in rows:
        p = r.pacing
        figures = (f"{us(p.p50)} {us(p.p99)} {us(p.max)} {p.overruns:9d} {p.count:8d}" if p is not None
                   else f"{'-':>9} {'-':>9} {'-':>9} {'-':>9} {'-':>8}")
        target = ""
        if r.rate_hz == TARGET_RATE_HZ and r.worker == "process" and p is not None:
            target = f"  target p99 < {TARGET_P99_S * 1e6:g} us: {'met' if p.p99 < TARGET_P99_S else 'NOT met'}"
        ui = f"{r.ui_frames / r.wall_s:7.0f}" if r.busy else f"{'-':>7}"
        early = "  (capped)" if r.error.startswith("aborted") else "  (failed)" if r.error else ""
        granted = p.scheduling if p is not None else "-"
        print(f"{r.rate_hz:6d} {r.worker:>8} {'yes' if r.busy else 'no':>5} {figures} {r.wall_s:7.1f} "
              f"{r.converged:3d}/{r.points:<3d} {r.feedback_ratio:6.2f} {ui}  {granted}{target}{early}")
    print("samples: setpoints paced; points: converged/measured (16 periods at most a point); fb/sp: feedback "
          "frames per setpoint\n(below 1: the simulated drive fell behind); ui/s: redraws a "
          "second of the busy thread")


if __name__ == "__main__":
    main(sys.argv[1:])
