"""What the terminal UI costs the measurement.

Run: python benchmarks/bench_tui.py [--only lockstep|realtime]

1. Lockstep: the wall time of the sweep of configs/sim_can.toml (BenchSession.run, the simulated drive on a
   virtual CAN bus) without the UI (no listener) and with the UI open (the app headless via run_test, the
   sweep started with its start key; the time is that of session.run inside the app's worker thread).
   The UI runs the bus worker where [bench] says beside a UI (BenchConfig.worker_mode(beside_a_ui=True));
   without the UI the sweep is timed both that way and with the worker in a thread (what ``bodebench run`` does
   on the lockstep clock).
2. Realtime: the pacing error's p99 (Health.pacing, the bus worker in its own process) of a short realtime
   run over a serial pty - configs/sim_serial.toml with clock = "realtime", reference_channel =
   "setpoint_echo", tolerance 1 %, 2 frequencies, at most MAX_PERIODS_REALTIME periods each - without and with
   the UI, REPEATS_REALTIME of each. The p99 sits at the clock's floor (under 1 us) unless the machine stalls,
   so its cost is judged against the 50 us pacing target, not against that floor.

Runs alternate without/with, REPEATS of each; medians and minima are printed (other work on the machine
makes single runs vary a lot; the minimum is the least disturbed), and the CPU time the UI's thread used as a
share of the sweep's wall time (what the UI can take from the measurement at most). Target: the UI costs
under 10 % of either. Prints figures only.
"""

from __future__ import annotations

import asyncio
import copy
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bodebench.apps.tui import BodeBenchApp  # noqa: E402
from bodebench.bench.connection import plan_link  # noqa: E402
from bodebench.bench.session import BenchSession  # noqa: E402
from bodebench.io.config import ExperimentConfig, load_config, parse_config  # noqa: E402

REPEATS = 3
REPEATS_REALTIME = 7  # short runs whose p99 a single stall of the machine moves: more of them
PACING_TARGET_S = 50e-6  # p99 of the send-time error at 1 kHz (benchmarks/bench_pacing.py)
UI_SIZE = (160, 45)   # every panel on screen: the most drawing
TARGET = 0.10
MAX_PERIODS_REALTIME = 60  # bounds a realtime run whose points do not reach 1 % (jitter of a loaded machine)


def realtime_config() -> ExperimentConfig:
    """sim_serial.toml on the realtime clock, two-channel, 1 % tolerance, 2 frequencies."""
    import tomllib

    data: dict[str, Any] = tomllib.loads((ROOT / "configs" / "sim_serial.toml").read_text())
    data = copy.deepcopy(data)
    data["bench"]["clock"] = "realtime"
    data["bench"]["reference_channel"] = "setpoint_echo"
    data["analysis"]["tolerance_percent"] = 1.0
    data["excitation"]["frequencies_hz"] = [5.0, 20.0]
    data["analysis"]["max_periods"] = MAX_PERIODS_REALTIME
    return parse_config(data, str(ROOT / "configs" / "sim_serial_realtime.toml"))


def without_ui(config: ExperimentConfig, out: Path, worker_mode: str | None = None) -> tuple[float, float]:
    """(session wall time s, pacing p99 s or NaN) of a plain session (``worker_mode`` None: the config's)."""
    case = config.cases[0]
    session = BenchSession(case, plan_link(case), out, worker_mode=worker_mode)
    started = time.perf_counter()
    result = session.run()
    elapsed = time.perf_counter() - started
    pacing = result.health.pacing if result.health is not None else None
    return elapsed, pacing.p99 if pacing is not None else float("nan")


UI_CPU: list[float] = []  # the UI thread's CPU time as a fraction of the sweep's wall time, per run


async def _with_ui(config: ExperimentConfig, out: Path) -> tuple[float, float]:
    app = BodeBenchApp(config, out)
    async with app.run_test(size=UI_SIZE) as pilot:
        cpu0 = time.thread_time()  # the app's event loop runs in this thread
        await pilot.press("s")
        while app.control is None or not app.control.done.is_set():
            await asyncio.sleep(0.1)  # not pilot.pause: its idle processing is test machinery, not the UI
        cpu = time.thread_time() - cpu0
        await pilot.pause(0.2)
        control = app.control
        if app.sweep_screen.status.state != "done":
            raise RuntimeError(f"the sweep in the UI ended {app.sweep_screen.status.state}: {app.worker_errors}")
    UI_CPU.append(cpu / control.session_s)
    pacing = control.health.pacing if control.health is not None else None
    return control.session_s, pacing.p99 if pacing is not None else float("nan")


def with_ui(config: ExperimentConfig, out: Path) -> tuple[float, float]:
    return asyncio.run(_with_ui(config, out))


def compare(label: str, config: ExperimentConfig, index: int, unit: str, scale: float,
            extra_thread_baseline: bool, repeats: int = REPEATS, budget: float | None = None) -> None:
    """Alternate runs without and with the UI; print the medians and the UI's cost: relative to the figure without
    the UI, or with ``budget`` relative to that (a p99 of a few us is the clock's floor, so 10 % of it means
    nothing; 10 % of the 50 us pacing target does)."""
    ui_mode = config.cases[0].on_bench.bench.worker_mode(beside_a_ui=True)
    variants: dict[str, list[float]] = {f"without UI (worker: {ui_mode})": []}
    if extra_thread_baseline:
        variants["without UI (worker: thread)"] = []
    variants["with UI"] = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            for name, values in variants.items():
                out = Path(tmp) / f"{len(values)}-{r}-{name.split()[0]}{len(name)}"
                if name == "with UI":
                    values.append(with_ui(config, out)[index])
                else:
                    values.append(without_ui(config, out, "thread" if "thread" in name else ui_mode)[index])
    print(label)
    for name, values in variants.items():
        print(f"  {name:<30} median {statistics.median(values) * scale:9.3f} {unit}  min {min(values) * scale:9.3f}"
              f" {unit}   runs {', '.join(f'{v * scale:.3f}' for v in values)}", flush=True)
    for stat in (statistics.median, min):
        ui = stat(variants["with UI"])
        for name, values in variants.items():
            if name != "with UI":
                cost = (ui - stat(values)) / (budget if budget is not None else stat(values))
                of = f"of the {budget * scale:g} {unit} target" if budget is not None else "of the time"
                print(f"  UI cost ({stat.__name__}s) against {name}: {cost * 100:+.1f} % {of}   (target < "
                      f"{TARGET * 100:.0f} %: {'met' if cost < TARGET else 'NOT met'})", flush=True)
    print(f"  UI thread CPU during the sweeps: {', '.join(f'{c * 100:.1f} %' for c in UI_CPU[-repeats:])} of the "
          f"sweep's wall time", flush=True)


def main(argv: list[str]) -> None:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=("lockstep", "realtime"), help="run one of the two comparisons")
    args = parser.parse_args(argv)
    if args.only != "realtime":
        lockstep = load_config(ROOT / "configs" / "sim_can.toml")
        case = lockstep.cases[0]
        print(f"lockstep: {lockstep.path.name}, {len(case.excitation.frequencies_hz)} frequencies, "
              f"tolerance {case.analysis.tolerance_percent:g} %, UI size {UI_SIZE[0]}x{UI_SIZE[1]}, "
              f"median of {REPEATS}", flush=True)
        compare("lockstep sweep wall time", lockstep, 0, "s", 1.0, True)
    if args.only != "lockstep":
        realtime = realtime_config()
        print(f"\nrealtime: sim_serial.toml on the realtime clock, frequencies "
              f"{list(realtime.cases[0].excitation.frequencies_hz)} Hz, tolerance 1 %, median of "
              f"{REPEATS_REALTIME}", flush=True)
        compare("realtime pacing error p99", realtime, 1, "us", 1e6, False, REPEATS_REALTIME, PACING_TARGET_S)


if __name__ == "__main__":
    main(sys.argv[1:])
