"""A real drive's configuration needs no [plant]: the drive is what is measured, and the saved configuration says
only what was measured. Here the "real" drive is the simulated controller serving on its own on a virtual CAN
channel, as ``bodebench sim-controller`` runs it, and the host's configuration knows nothing of its plant."""

from __future__ import annotations

import json
import uuid
from pathlib import Path
from typing import Any

import pytest

from bodebench.bench.connection import simulator_spec
from bodebench.bench.procedure import SweepProcedure
from bodebench.io.config import ConfigError, parse_config
from bodebench.io.results import SIDECAR_NAME
from bodebench.sim.serve import serve_can


def host(channel: str) -> dict[str, Any]:
    return {
        "excitation": {"amplitude": 0.01, "frequencies_hz": [4.0, 16.0]},
        "analysis": {"tolerance_percent": 0.1},
        "bench": {"transport": "can", "rate_hz": 1000.0, "clock": "lockstep"},
        "can": {"interface": "virtual", "channel": channel},
        "safety": {"max_amplitude": 0.02, "watchdog_s": 5.0},
    }


@pytest.mark.slow
def test_a_real_drive_is_measured_without_a_plant_table(tmp_path: Path) -> None:
    channel = f"real-{uuid.uuid4().hex[:8]}"
    config = parse_config(host(channel), "drive.toml")
    case = config.cases[0]
    assert case.plant is None and "plant" not in case.raw
    drive = parse_config({**host(channel), "plant": {"model": "lag", "time_constant": 0.01}, "simulator": {}},
                         "drive.toml").cases[0]
    serving = serve_can(simulator_spec(drive))  # the drive on the far side of the bus
    try:
        outcome = SweepProcedure(config, tmp_path).run()[0]
    finally:
        serving.close()
    assert [p.status for p in outcome.response] == ["converged", "converged"]
    saved = json.loads((tmp_path / SIDECAR_NAME).read_text())
    assert "plant" not in saved["config"] and "simulator" not in saved["config"]
    assert saved["config"]["can"]["channel"] == channel


def test_what_is_simulated_still_needs_its_plant() -> None:
    with pytest.raises(ConfigError, match=r"x.toml: plant: missing: an offline experiment needs a \[plant\] table"):
        parse_config({"excitation": {"amplitude": 1.0, "frequencies_hz": [1.0]}}, "x.toml")
    with pytest.raises(ConfigError, match=r"x.toml: plant: missing: a simulated drive \(\[simulator\]\) needs"):
        parse_config({**host("x"), "simulator": {}}, "x.toml")
