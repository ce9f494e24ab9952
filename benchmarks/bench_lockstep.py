"""Throughput of a lockstep sweep through the whole instrument chain.

Run: python benchmarks/bench_lockstep.py [--profile]

Each config is swept once by a BenchSession exactly as ``bodebench run`` would (the simulated drive answers each
setpoint at once, so the sweep runs as fast as the chain carries frames):

- configs/sim_can.toml: python-can's virtual bus; the bus worker (a thread of the session's process) and the
  simulated drive (served from a thread of the same process) exchange frames through it.
- configs/sim_serial.toml: binary framing on a pseudo-terminal; the simulated drive in its own process.
- configs/sim_canopen.toml: CANopen on the virtual bus: an RPDO and a SYNC out, a TPDO back for each setpoint; the
  simulated CiA 402 drive answers from canopen's notifier thread in the same process.

Frames per second = (frames_in + frames_out of the worker's bus, from the last Health) / wall time of
BenchSession.run (worker start and bus opening included). Target: >= 10,000 frames/s for sim_can.

--profile: also run sim_can once under cProfile (every thread of this process: the session, the bus worker and
the simulated drive's server) and print the functions with the most own time. Prints figures only.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bodebench.bench.connection import plan_link  # noqa: E402
from bodebench.bench.session import BenchSession, SessionResult  # noqa: E402
from bodebench.io.config import load_config  # noqa: E402

CONFIGS = (ROOT / "configs" / "sim_can.toml", ROOT / "configs" / "sim_serial.toml",
           ROOT / "configs" / "sim_canopen.toml")
TARGET_FRAMES_PER_S = 10_000.0
PROFILE_LINES = 25


@dataclass
class Row:
    config: str
    wall_s: float
    frames_in: int
    frames_out: int
    samples: int
    points: int
    converged: int
    round_trip_s: float

    @property
    def frames_per_s(self) -> float:
        return (self.frames_in + self.frames_out) / self.wall_s


def sweep(path: Path) -> Row:
    """One whole sweep of the config at ``path``."""
    case = load_config(path).cases[0]
    plan = plan_link(case)
    session = BenchSession(case, plan)
    start = time.perf_counter()
    result: SessionResult = session.run()
    wall = time.perf_counter() - start
    health = result.health
    if health is None:
        raise RuntimeError(f"{path.name}: the session reported no bus health")
    points = result.response.points
    return Row(path.name, wall, health.bus.frames_in, health.bus.frames_out, health.tick, len(points),
               sum(p.converged for p in points), result.round_trip_s)


def profiled_sweep(path: Path) -> tuple[Row, str]:
    """A sweep with every thread of this process profiled (one cProfile per thread, merged); (row, the top of
    the merged profile by own time)."""
    profiles = [cProfile.Profile(time.thread_time)]

    def start_thread_profile(frame: object, event: str, arg: object) -> None:
        sys.setprofile(None)
        profile = cProfile.Profile(time.thread_time)
        profiles.append(profile)
        profile.enable()

    threading.setprofile(start_thread_profile)  # type: ignore[arg-type]
    profiles[0].enable()
    try:
        row = sweep(path)
    finally:
        profiles[0].disable()
        threading.setprofile(None)  # type: ignore[arg-type]
    text = io.StringIO()
    stats = pstats.Stats(profiles[0], stream=text)
    for profile in profiles[1:]:
        stats.add(profile)
    stats.sort_stats("tottime").print_stats(PROFILE_LINES)
    return row, text.getvalue()


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", action="store_true", help="profile the sim_can sweep (cProfile)")
    args = parser.parse_args(argv)
    rows = []
    for path in CONFIGS:
        rows.append(sweep(path))
        print(f"  swept {path.name}: {rows[-1].wall_s:.1f} s", flush=True)
    print()
    print(f"{'config':<17} {'wall s':>7} {'samples':>8} {'frames in':>10} {'frames out':>10} {'frames/s':>9} "
          f"{'round trip':>11} {'points':>7}")
    for r in rows:
        target = ""
        if r.config == CONFIGS[0].name:
            target = (f"  target >= {TARGET_FRAMES_PER_S:,.0f}/s: "
                      f"{'met' if r.frames_per_s >= TARGET_FRAMES_PER_S else 'NOT met'}")
        print(f"{r.config:<17} {r.wall_s:7.1f} {r.samples:8d} {r.frames_in:10d} {r.frames_out:10d} "
              f"{r.frames_per_s:9,.0f} {r.round_trip_s * 1e6:8.0f} us {r.converged:3d}/{r.points:<3d}{target}")
    if args.profile:
        row, text = profiled_sweep(CONFIGS[0])
        print()
        print(f"cProfile of {row.config} (all threads; {row.wall_s:.1f} s under the profiler, "
              f"{row.frames_per_s:,.0f} frames/s), by own time:")
        print(text)


if __name__ == "__main__":
    main(sys.argv[1:])
