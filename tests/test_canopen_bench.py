"""Sweeps over CANopen agree with the offline experiment: the simulated CiA 402 drive on python-can's virtual bus
(RPDO, SYNC, TPDO) against the offline :func:`bodebench.bench.offline.sweep` of the same plant, within the bounds
``tests/test_bench_vs_offline.py`` holds the frame-layout transports to; and the realtime clock against lockstep.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_bench_vs_offline import EPS_PERCENT, PLANTS, RATE_HZ, assert_bench_agrees_with_offline

from bodebench.bench.connection import plan_link
from bodebench.bench.procedure import SweepProcedure
from bodebench.bench.session import BenchSession
from bodebench.io.config import load_config, parse_config
from bodebench.io.results import load_response
from bodebench.status import PointStatus

CANOPEN = {"node_id": 7, "mode": "csp", "setpoint_scale": 1e-9, "actual": {"position": "0x6064", "counter": "0x2000"},
           "actual_scale": {"position": 1e-9}, "heartbeat_ms": 50, "heartbeat_timeout_s": 1.0}


def canopen_bench(base: dict[str, Any], clock: str = "lockstep") -> dict[str, Any]:
    return {**base, "bench": {"transport": "canopen", "rate_hz": RATE_HZ, "clock": clock},
            "can": {"interface": "virtual", "channel": f"co-{uuid.uuid4().hex[:8]}"}, "canopen": dict(CANOPEN),
            "safety": {"max_amplitude": 0.02, "watchdog_s": 3.0}, "simulator": {}}


@pytest.mark.slow
@pytest.mark.parametrize("plant", sorted(PLANTS))
def test_a_sweep_over_canopen_measures_what_the_offline_experiment_computes(tmp_path: Path, plant: str) -> None:
    table, num, den = PLANTS[plant]
    base = {"plant": table, "excitation": {"amplitude": 0.01, "frequencies_hz": [5.0, 12.0]},
            "analysis": {"tolerance_percent": EPS_PERCENT, "steps_per_period": 400}}
    outcomes = SweepProcedure(parse_config(canopen_bench(base), "canopen.toml"), tmp_path).run()
    assert_bench_agrees_with_offline(tmp_path, outcomes[0].response, base, num, den, [5.0, 12.0])


@pytest.mark.slow
def test_the_realtime_clock_over_canopen_agrees_with_lockstep() -> None:
    """SYNC paced by the host on the wall clock: the drive samples on each SYNC and each sample is dated by the SYNC
    it answers, so the response is the lockstep one. The bus worker runs in a process of its own, as on a bench;
    the simulated drive answers from a thread of that process, so the rate is a modest 250 Hz. Loose bounds: a
    busy machine delays SYNCs, which the simulated drive, stepping one period a SYNC, does not see."""
    table, _, _ = PLANTS["lag"]
    base = {"plant": table, "excitation": {"amplitude": 0.01, "frequencies_hz": [5.0, 10.0]},
            "analysis": {"harmonics": [1], "tolerance_percent": 0.2, "max_periods": 60}}
    responses = []
    for clock in ("lockstep", "realtime"):
        data = canopen_bench(base, clock)
        data["bench"].update(worker="thread" if clock == "lockstep" else "process", rate_hz=250.0)
        case = parse_config(data, "canopen.toml").cases[0]
        result = BenchSession(case, plan_link(case)).run()
        assert result.completed
        responses.append(result.response)
    lockstep, realtime = responses
    assert np.max(np.abs(realtime.gain_db - lockstep.gain_db)) <= 0.05
    assert np.max(np.abs(realtime.phase_deg - lockstep.phase_deg)) <= 0.2


def test_the_shipped_canopen_config_loads_with_the_simulated_drive_eds() -> None:
    case = load_config(Path(__file__).parent.parent / "configs" / "sim_canopen.toml").cases[0]
    setup = case.canopen_setup
    assert setup is not None and Path(setup.eds).is_file() and setup.eds.endswith("cia402_sim.eds")
    assert (setup.setpoint.index, setup.setpoint.type) == (0x607A, "int32")
    assert [(name, ref.index) for name, ref, _ in setup.actual] == [("position", 0x6064)]  # standard objects only
    assert setup.timebase == "sync"


def _command() -> list[str]:
    exe = shutil.which("bodebench")
    return [exe] if exe else [sys.executable, "-m", "bodebench"]


@pytest.mark.slow
def test_bodebench_run_sweeps_the_shipped_canopen_config_and_says_how_it_left_the_drive(tmp_path: Path) -> None:
    cfg = Path(__file__).resolve().parents[1] / "configs" / "sim_canopen.toml"
    small = tmp_path / "sim_canopen_small.toml"
    small.write_text(cfg.read_text().replace("frequencies_hz = [5, 10, 20]", "frequencies_hz = [10, 20]"))
    proc = subprocess.run(_command() + ["run", str(small), "--out", str(tmp_path / "out")], capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    last = next(line for line in proc.stdout.splitlines() if "drive left at" in line)  # its summary follows
    assert "drive left at setpoint 0, seen disabled: quick stop (controlword 0x0002)" in last, last
    assert "(switch on disabled); NMT pre-operational sent" in last, last
    response = load_response(tmp_path / "out")
    assert sorted({p.frequency_hz for p in response.points}) == [10.0, 20.0]
    # harmonic 3 at 20 Hz, 50 samples a period: what the rate folds onto it (0.4 x eps against a fine grid) and the
    # bound on it do not both fit 0.05 %, and it may end alias_limited; every other point converges
    assert all(p.converged for p in response.points if (p.frequency_hz, p.harmonic) != (20.0, 3))
    assert all(p.converged or p.status == PointStatus.ALIAS_LIMITED for p in response.points)


def test_sim_controller_serves_the_simulated_cia402_drive() -> None:
    cfg = Path(__file__).resolve().parents[1] / "configs" / "sim_canopen.toml"
    proc = subprocess.run(_command() + ["sim-controller", str(cfg), "--seconds", "1"], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert "CiA 402 drive, CANopen node 5, on python-can virtual channel bodebench-canopen" in lines[0]
    assert lines[-1].endswith("disabled")
