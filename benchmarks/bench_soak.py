"""Soak: a long realtime run of the simulated drive at 5 kHz feedback with the terminal UI open.

Prints memory (RSS of every process of the chain: the UI/session process, the bus worker, the simulated
drive) over time and its growth per minute, samples lost, the pacing error, the points the UI counted finished
against the rows of response.csv, and how the run record says the run ended. Targets: memory flat, no lost
samples, pacing p99 within target, the UI's count equal to the CSV's. No asserts.

    python benchmarks/bench_soak.py                 # 10 minutes, 5 kHz, UI open (headless Textual app)
    python benchmarks/bench_soak.py --seconds 3600  # an hour
    python benchmarks/bench_soak.py --seconds 60 --no-ui
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

CONFIG = """
title = "soak"
[plant]
model = "coulomb"
mass = 2.533e-4
stiffness = 1.0
friction = 0.008
[excitation]
amplitude = 0.01
frequencies_hz = {freqs}
[analysis]
harmonics = [1]
tolerance_percent = 0.5
max_periods = 400
[bench]
transport = "serial"
rate_hz = {rate}
clock = "realtime"
timebase = "counter"
reference_channel = "setpoint_echo"
[serial]
framing = "binary"
[frames.setpoint]
id = 1
signals = [{{ name = "setpoint", byte = 0, type = "float32" }}, {{ name = "counter", byte = 4, type = "uint16" }}]
[[frames.feedback]]
id = 0x81
signals = [{{ name = "position", byte = 0, type = "float32" }},
           {{ name = "setpoint_echo", byte = 4, type = "float32" }},
           {{ name = "counter", byte = 8, type = "uint16" }}]
[frames.enable]
id = 0x10
data = [1]
[frames.disable]
id = 0x10
data = [0]
[safety]
max_amplitude = 0.02
watchdog_s = 1.0
[simulator]
"""


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out


class Probe:
    """Samples RSS of this process and its children, and keeps the last bus health the session reports."""

    def __init__(self) -> None:
        self.rows: list[tuple[float, dict[int, float]]] = []
        self.health = None
        self.started = time.monotonic()

    def sample(self) -> None:
        pids = [os.getpid(), *children(os.getpid())]
        self.rows.append((time.monotonic() - self.started, {p: rss_mb(p) for p in pids}))

    def listener(self, inner):
        from bodebench.bench.events import BusStatus

        def wrapped(event: object) -> None:
            if isinstance(event, BusStatus):
                self.health = event.health
            inner(event)
        return wrapped


def patch_sessions(probe: Probe) -> None:
    """Route every session's events through the probe as well (the UI builds its own sessions)."""
    import bodebench.bench.session as session_module

    original = session_module.BenchSession.__init__

    def init(self, case, plan, out_dir=None, listener=None, **options):  # type: ignore[no-untyped-def]
        original(self, case, plan, out_dir, probe.listener(listener or (lambda e: None)), **options)

    session_module.BenchSession.__init__ = init  # type: ignore[method-assign]


def report_results(out: Path, ui_finished: int | None) -> None:
    """The points on disk against those the UI counted finished, and how the run record says the run ended."""
    from bodebench.io.results import ResultsError, load_response, sidecar_runs

    try:
        points = load_response(out).points
    except ResultsError as exc:
        print(f"results: {exc}")
        return
    frequencies = len({p.frequency_hz for p in points})
    shown = "" if ui_finished is None else f"; the UI counted {ui_finished} finished rows (target: the same)"
    print(f"response.csv: {len(points)} rows at {frequencies} frequencies{shown}")
    runs = sidecar_runs(out)
    print(f"run record: ended_by {runs[-1].get('ended_by', '(missing)')!r}" if runs else "run record: (none)")


def report(probe: Probe, seconds: float, rate: float, ui: bool) -> None:
    print(f"soak: {seconds:.0f} s requested, realtime clock, {rate:g} Hz feedback, UI {'open' if ui else 'closed'}")
    if not probe.rows:
        print("no samples")
        return
    warm = [r for r in probe.rows if r[0] >= min(60.0, seconds / 4)] or probe.rows
    first, last = warm[0], probe.rows[-1]
    minutes = max(1e-9, (last[0] - first[0]) / 60.0)
    pids = sorted(set(first[1]) & set(last[1]))
    print(f"processes of the chain running at the start and at the end: {len(pids)} (the session, the "
          f"multiprocessing resource tracker, the simulated drive, the bus worker)")
    marks = [r for r in probe.rows if r is first or r is last or int(r[0] // 60) != int((r[0] - 5.0) // 60)]
    print(f"{'RSS MB at':>12} " + " ".join(f"{r[0]:7.0f} s" for r in marks) + f" {'slope MB/min':>13} (from "
          f"{first[0]:.0f} s)")
    for pid in pids:
        label = "session" if pid == os.getpid() else f"pid {pid}"
        a, b = first[1][pid], last[1][pid]
        print(f"{label:>12} " + " ".join(f"{r[1].get(pid, float('nan')):9.1f}" for r in marks)
              + f" {(b - a) / minutes:13.3f}")
    h = probe.health
    if h is None:
        print("no bus health reported")
        return
    bus = h.bus
    print(f"samples in {bus.frames_in}, setpoints out {bus.frames_out}, lost {bus.lost_samples}, "
          f"incomplete {bus.incomplete_samples}, duplicates {bus.duplicates}, errors {bus.errors}, "
          f"dropped times {h.time_conflicts}")
    if h.pacing is not None:
        p = h.pacing
        print(f"pacing send-time error: p50 {p.p50 * 1e6:.1f} us, p99 {p.p99 * 1e6:.1f} us, max {p.max * 1e6:.1f} us "
              f"over {p.count} setpoints, {p.overruns} overruns (target p99 < 50 us at 1 kHz)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--rate", type=float, default=5000.0)
    parser.add_argument("--no-ui", action="store_true")
    args = parser.parse_args(argv)

    from bodebench.io.config import load_config

    freqs = [round(2.0 + 0.1 * i, 1) for i in range(981)]  # 2 to 100 Hz: a sweep longer than the soak (~1.6 s a point)
    tmp = Path(tempfile.mkdtemp(prefix="bodebench-soak-"))
    cfg = tmp / "soak.toml"
    cfg.write_text(CONFIG.format(freqs=freqs, rate=args.rate))
    config = load_config(cfg)
    probe = Probe()
    patch_sessions(probe)

    if args.no_ui:
        from bodebench.bench.connection import plan_link
        from bodebench.bench.session import BenchSession

        case = config.cases[0]
        session = BenchSession(case, plan_link(case), tmp / "out")
        runner = threading.Thread(target=lambda: _run_quietly(session), daemon=True)
        runner.start()
        end = time.monotonic() + args.seconds
        while time.monotonic() < end and runner.is_alive():
            probe.sample()
            time.sleep(5.0)
        session.controls.request_abort()
        runner.join(30)
    ui_finished = None
    if not args.no_ui:
        ui_finished = asyncio.run(_with_ui(config, tmp / "out", probe, args.seconds))
    report(probe, args.seconds, args.rate, not args.no_ui)
    report_results(tmp / "out", ui_finished)
    return 0


def _run_quietly(session) -> None:  # type: ignore[no-untyped-def]
    from bodebench.bench.events import SessionError

    with contextlib.suppress(SessionError):
        session.run()


async def _with_ui(config, out: Path, probe: Probe, seconds: float) -> int:  # type: ignore[no-untyped-def]
    """Runs the sweep in the UI for ``seconds``, then aborts it; the rows the UI's table shows measured."""
    from bodebench.apps.tui.app import BodeBenchApp
    from bodebench.apps.tui.model import ACTIVE_STATES, FAILED, PENDING, SKIPPED

    app = BodeBenchApp(config, out)
    async with app.run_test(size=(120, 40)) as pilot:
        await pilot.press("s")
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            probe.sample()
            await asyncio.sleep(5.0)
        await pilot.press("a")
        await asyncio.sleep(2.0)
        unwritten = (PENDING, SKIPPED, FAILED, *ACTIVE_STATES)  # a failed row is the point the abort cut short
        return sum(row.state not in unwritten for row in app.sweep_screen.record.model.rows.values())


if __name__ == "__main__":
    sys.exit(main())
